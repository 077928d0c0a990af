// The rig file as the default source of the pipeline's frequency settings (config key `rig`, or
// `ridgewatch analyze --rig`): when the configuration does not give them,
//   pipeline.analyzer.f_expected_hz = the model's damped natural frequency f_d = f0 sqrt(1 - ζ²),
//     f0 = sqrt(c0 / m_red) / 2π (paper Appendix B: 859-860 Hz for the paper rig), the function
//     `compare`/`diagnose`/`simulate` use (model::RigParameters::damped_frequency_hz());
//   pipeline.detector.band_lo_hz/band_hi_hz = f_d ± B between the mesh lines k·f_z and (k+1)·f_z
//     that bracket f_d (f_z = z1 × pinion shaft frequency, Eq. B1): B = 0.15 f_d (the width of the
//     shipped default band), narrowed so that both lines lie at least 1.776 B from f_d, where the
//     detector's 8th-order band-pass attenuates them by 20 dB (|H| = 1/sqrt(1 + (df/B)^8),
//     core/pipeline/impact_detector.hpp; 99^(1/8) = 1.776). Never below 0.05 f_d: a mode within
//     ~9 % of a mesh line cannot be separated by the trigger band, which `note` then says.
// Keys the configuration file gives explicitly always win.
#pragma once

#include <string>

#include "app/config_yaml.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::app {

struct RigBand {
  double f_d_hz = 0;      ///< model damped natural frequency, Hz
  double mesh_hz = 0;     ///< mesh frequency f_z, Hz
  double lo_hz = 0, hi_hz = 0;  ///< proposed trigger band, Hz
  std::string note;       ///< non-empty when the band could not keep the mesh lines 20 dB down
};

/// Pure: the model frequency and trigger band of a rig (rules above).
RigBand rig_band(const model::RigParameters& rig);

/// Loads `rig_path` (UsageError naming `key` and the file when it cannot be read or is invalid) and
/// overlays its defaults on the keys of `config` that are not in `config.given`; records what it did
/// in `config.rig_model`.
void apply_rig_defaults(RidgewatchConfig& config, const std::string& rig_path, const std::string& key);

/// Running mean of the measured f of `ok` events against the model f_d, for summary and status lines:
/// "measured f 861.2 Hz (mean of 12 ok events) vs model f_d 859.8 Hz: +0.16 %".
class ModelGap {
 public:
  explicit ModelGap(double model_f_hz) : model_(model_f_hz) {}
  void add_ok(double f_hz) {
    if (f_hz > 0) {
      sum_ += f_hz;
      ++n_;
    }
  }
  std::size_t count() const { return n_; }
  double mean_hz() const { return n_ ? sum_ / static_cast<double>(n_) : 0.0; }
  double gap_rel() const { return n_ ? mean_hz() / model_ - 1.0 : 0.0; }
  std::string text() const;

 private:
  double model_;
  double sum_ = 0;
  std::size_t n_ = 0;
};

}  // namespace ridgewatch::app
