// Analysis of one impact-triggered window: band CWT -> ridge near the expected natural frequency ->
// frequency and damping with the foundation's estimators -> status.
//
//  1. Band-limited Morlet CWT (core/dsp/morlet_cwt.hpp, Eq. 1-7 with the amplitude normalisation that
//     makes |W| the envelope of Eq. 12) of the window [onset - pretrigger, onset + window) on rows
//     log-spaced over f_expected (1 +- band_rel), 3 eta0 rows per unit of ln f (adjacent rows overlap
//     to within 1/(3 eta0) of a filter sd).
//  2. Ridge, on |W|^2 minus each row's median over the window (removes stationary lines): the largest
//     value after the onset (not in the last 4 kernel widths, which see the window
//     end) and its continuation column by column, moving at most one row per column (continuity),
//     while |W|^2 stays 20 dB above the row's noise. The ridge is lost when its maximum lies on a
//     band-edge row (the mode is outside the band), when it touches an edge row, or when it strays
//     more than one filter sd (f/eta0) from the starting row. Ridge frequency: parabola in ln f of
//     the ridge's time-integrated energy over the three rows around the maximum.
//     A free response can stop before the window ends (dry friction: the motion sticks once the
//     amplitude is small; replay-data sim-coulomb-friction stops ~5 ms after the impact). The
//     transform then shows its response to the stop: the mode row's power falls like the kernel's
//     Gaussian, and the lower rows (longer kernels) hold it longest, so the maximum walks down the band
//     and used to mark the whole impact ridge_lost. Now an accelerating decay that does not recover,
//     or a stray after the power fell 15 dB, ends the ridge instead: the envelope estimators treat the
//     ridge's end as the record end, the ML segment ends 2 kernel widths before it, and the estimate is
//     the equivalent viscous one over that shorter window (ok when the estimators accept it; the
//     cross-check flags inconsistent when the decay is visibly non-exponential). When the stop leaves
//     no envelope window between the edge skips (10 kernel widths, 13 ms at 860 Hz), the status is
//     too_short.
//  3. Damped frequency from the phase slope of W (unbiased, README "Frequency"; rows are decimated, so
//     the phase is unwrapped around the row frequency). Envelope row at f_d; the foundation's window
//     choice, two-point (Eq. 17-19) and ridge least-squares estimates.
//  4. ml (default): SpectralModeFitter with one mode in f_d (1 +- ml_band_rel, default 12 %) on the segment from
//     onset + 0.5 ms (the 0.15 ms force pulse and the onset's uncertainty are over) to the end of the
//     usable window, started from the ridge-LS estimate. The in-band fit ignores the mesh lines at
//     550/1100 Hz of the paper rig (outside 860 Hz +- 12 %) and hum. Segment lengths are quantised to
//     eighths of the full window so the FFT plans can be made in the constructor.
//  5. Cross-check of ml against ridge-ls (as in `ridgewatch modes`): more than 4 combined standard
//     uncertainties apart (plus a 1 % / 1e-4 allowance) -> inconsistent.
//
// Noise: the caller gives the in-band power of the samples between impacts (pre-trigger samples);
// it is converted to the white-noise variance the CWT rows' noise gains refer to.
#pragma once

#include <complex>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/dsp/damping.hpp"
#include "core/dsp/ml_fit.hpp"
#include "core/dsp/morlet_cwt.hpp"
#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::pipeline {

struct ImpactAnalyzerConfig;

/// Why the window is shorter than configured.
enum class WindowEnd : std::uint8_t {
  complete,     ///< the full configured window
  next_impact,  ///< cut before the next impact's onset
  gap,          ///< cut by a data gap or the end of the stream
};

struct ImpactWindow {
  std::span<const double> samples;  ///< from onset - pretrigger (or the segment start) on
  std::size_t onset_offset = 0;     ///< index of the onset inside `samples`
  WindowEnd end = WindowEnd::complete;
  double noise_var = NAN;           ///< white-equivalent noise variance of the samples (from the gaps)
  bool spike = false;               ///< a detected spike lies inside the window
  std::uint64_t onset_index = 0;    ///< absolute onset index (event sample_index)
};

class ImpactAnalyzer {
 public:
  ImpactAnalyzer(const ImpactAnalyzerConfig& config, double sample_rate_hz);
  ~ImpactAnalyzer();
  ImpactAnalyzer(const ImpactAnalyzer&) = delete;
  ImpactAnalyzer& operator=(const ImpactAnalyzer&) = delete;

  /// Longest window (pretrigger + window samples).
  std::size_t max_samples() const { return n_pre_ + n_win_; }
  std::size_t pretrigger_samples() const { return n_pre_; }
  std::size_t window_samples() const { return n_win_; }

  /// Analyses one window; the event's alarm state is left default (the caller adds it).
  ImpactEvent analyze(const ImpactWindow& window);

 private:
  double fs_ = 0;
  double f_expected_ = 0, band_rel_ = 0, ml_band_rel_ = 0, eta0_ = 7, min_snr_db_ = 20, clip_ = 0.999;
  dsp::DampingMethod method_ = dsp::DampingMethod::ml;
  std::size_t n_pre_ = 0, n_win_ = 0, n_ml_margin_ = 0;
  std::vector<double> rows_hz_;
  std::vector<double> row_gain_;                 // cwt_->noise_gain(rows_hz_[r]), computed once
  std::unique_ptr<dsp::MorletCwt<float>> cwt_;
  std::vector<float> xf_;                        // the window in single precision (CWT input)
  std::vector<std::complex<float>> wf_;          // one row as computed
  std::vector<std::complex<float>> grid_;        // the grid rows (rows x cols)
  std::vector<double> power_;                    // rows x cols |W|^2
  std::vector<std::complex<double>> w_;          // one row
  std::vector<double> scratch_, scratch2_;       // median of a row (select_kth's two buffers)
  std::vector<double> row_median_;               // each row's median |W|^2 over the window
  std::vector<std::size_t> fitter_len_;          // segment lengths of the ML fitters
  std::vector<std::unique_ptr<dsp::SpectralModeFitter>> fitters_;
  dsp::EnvelopeWorkspace envelope_ws_;           // line-fit scratch, reserved for max columns
  dsp::MlFitResult ml_result_;                   // reused: modes reserved for one guess

  /// White-noise variance gain of the band-limited row at f (noise_gain), from the nearest grid row:
  /// the discrete filter's gain is proportional to f (4 sqrt(pi) f / (eta0 fs), the Gaussian spans
  /// ~6 bins per sd, so the sampled sum equals the integral to rounding).
  double gain_at(double f_hz) const;
};

}  // namespace ridgewatch::pipeline
