// Settings of the impact analyzer (core/pipeline/impact_analyzer.hpp): band, Morlet eta0, windows,
// damping estimator and the status rules. Part of PipelineConfig (stream_processor.hpp); its own header
// so that the analyzer does not include its composer.
#pragma once

#include "core/dsp/damping.hpp"

namespace ridgewatch::pipeline {

struct ImpactAnalyzerConfig {
  double f_expected_hz = 854.0;  ///< expected natural frequency of the gear pair, Hz
  double band_rel = 0.3;         ///< ridge searched within f_expected * (1 +- band_rel), (0, 0.9)
  double eta0 = 7.0;             ///< Morlet eta0 (Eq. 4), [5, 50]
  double pretrigger_s = 0.002;   ///< samples kept before the detected onset, s (>= 0)
  /// Longest decay window analysed after the onset, s (> 0). Each window ends where the decay reaches
  /// the noise floor (StreamProcessor: trigger-band power at most twice the floor between impacts, or
  /// 40 dB below its peak), at the next impact, or at this maximum, whichever comes first: zeta from
  /// 1e-4 to 0.1 needs no tuning as long as the maximum covers the decay (1 s: 7 time constants of
  /// zeta = 1.3e-3 at 900 Hz). The key's old meaning (a fixed window) is the same maximum.
  double window_s = 1.0;
  dsp::DampingMethod method = dsp::DampingMethod::ml;
  double min_snr_db = 20.0;      ///< below: status low_snr
  /// An ok event's 95 % interval spans at most this ratio hi / lo (1.25: about +-11 %); wider: low_snr
  /// (ok promises a usable number). > 1.
  double max_ci_ratio = 1.25;
  /// |x| >= clip_level inside the window: clipped (signal units; 0.999 suits data scaled to a full
  /// scale of 1.0). NaN: no clipping check (float data in physical units have no converter limit).
  /// The configuration file's default, null, takes it from the source's format (cli:
  /// resolve_format_defaults(): 0.999 of an integer format's full scale, none for float).
  double clip_level = 0.999;
  /// ml: DFT bins within f_d * (1 +- ml_band_rel) are fitted, (0, band_rel]. The default 0.12 keeps
  /// the paper rig's mesh lines (550/1100 Hz, and 550 Hz + 20 % under a speed ramp) well outside the
  /// fit of an 860 Hz mode while leaving >= 6 DFT bins for a 30 ms segment (measured on replay-data:
  /// 0.15 lets a line at 640 Hz bias an ok event by 10 %, 0.10 starves cut windows of bins).
  double ml_band_rel = 0.12;
};

}  // namespace ridgewatch::pipeline
