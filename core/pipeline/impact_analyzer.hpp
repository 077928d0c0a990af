// Analysis of one impact-triggered window: band CWT -> ridge near the expected natural frequency ->
// frequency and damping with the foundation's estimators -> status.
//
//  0. Half-rate copy (when the rate allows it): steps 1-4 read only frequencies up to the top row's
//     kept band, f_hi (1 + c / eta0) with f_hi = f_expected (1 + band_rel) and c = 5.26 (the
//     band-limited truncation, 1e-6), and the ML band's top f_hi (1 + ml_band_rel), which is lower.
//     When that is at most fs / 8 (1.95 kHz for the defaults: rates >= 15.6 kHz), the CWT and the ML
//     fit can run on y[m] = (x[2m-1] + 2 x[2m] + x[2m+1]) / 4 (dsp::decimate_half_121; y[m] is at the
//     time of x[2m]) at fs / 2. Its response H(f) = cos^2(pi f / fs) is >= 0.85 up to fs / 8 and is
//     divided out of the CWT's filter gains (MorletCwtConfig::half_rate_121_input, so |W| stays the
//     envelope of x); the image folded onto f from fs/2 - f is attenuated by sin^2(pi f / fs)
//     (<= 0.15 at fs / 8 where the Gaussian is already 1e-6, 2.8e-3 at 860 Hz and 51.2 kHz). The
//     rows' noise gains refer to white noise of x at fs (the row noise E|W|^2 = gain * sigma^2 is
//     unchanged: the copy's in-band noise is H^2 sigma^2 / 2 at fs / 2, the compensated half-rate
//     filter's sum of squares is 2 / H^2 times the full-rate one). The ML fit sees the same damped
//     sinusoid (the taps of a damped mode z give (z + 2 + 1/z) / 4 times it: same sigma and omega) on the
//     copy samples from the segment start on, with the same bin spacing (N/2 samples at fs/2), its
//     amplitude divided by H(f). The peak/clipping check reads the full-rate samples.
//     The copy is used only when it keeps the full-rate grids: an even CWT decimation (the same column
//     times) and an even complete-window ML segment (the same DFT bins). The estimates of misspecified
//     decays depend on both grids: at 25.6 kHz (decimation 15, segment 883 samples) the copy's grids
//     (decimation 7, 441 samples) moved replay-data sim-second-mode's median |zeta error| from 1.5 % to
//     20 % and sim-transmission-error's from 0.6 % to 1.0 %, and made a 20 dB sim-nuisance event
//     ok with a 33 % error. At 51.2 kHz (30 -> 15, 1766 -> 883) the estimates agree with the full-rate
//     ones to 1e-6 (sim-tacho). Otherwise (25.6 kHz, 8 kHz, ...) everything runs at full rate.
//     (Speed of the half-rate path: docs/performance.md, "Impact analyzer".)
//  1. Band-limited Morlet CWT (core/dsp/morlet_cwt.hpp, Eq. 1-7 with the amplitude normalisation that
//     makes |W| the envelope of Eq. 12) of the window [onset - pretrigger, onset + window) on rows
//     log-spaced over f_expected (1 +- band_rel), 3 eta0 rows per unit of ln f (adjacent rows overlap
//     to within 1/(3 eta0) of a filter sd; 2 eta0 rows moved replay-data sim-second-mode's median
//     |zeta error| from 1.5 % to 26 %).
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
//     the phase is unwrapped around the row frequency). Envelope row at f_d (the f_ridge row itself
//     when f_d is within 2 % of a filter sd of it: a constant envelope factor >= 0.9998); the
//     foundation's window choice, two-point (Eq. 17-19) and ridge least-squares estimates.
//  4. ml (default): SpectralModeFitter with one mode in f_d (1 +- ml_band_rel, default 12 %) on the segment from
//     onset + 0.5 ms (the 0.15 ms force pulse and the onset's uncertainty are over) to the end of the
//     usable window (half rate: the copy's samples, fitters made with (len / 2, fs / 2)), started from
//     the ridge-LS estimate (Eq. 15-16 in the DFT domain, ml_fit.hpp). The in-band fit ignores the
//     mesh lines at 550/1100 Hz of the paper rig (outside 860 Hz +- 12 %) and hum, except for their
//     leakage through the segment's ends, a slope across the band that two residual terms take up
//     (MlStep: on short segments one term left zeta 2 % low beside such lines). Segment lengths are quantised to
//     eighths of the full window so the FFT plans can be made in the constructor.
//     A steady line near the mode (a mesh harmonic sweeping through the band during a speed ramp, a
//     hum harmonic) that the one-mode model does not explain widens the fit's interval. When the
//     interval fails the precision rule (max_ci_ratio), a second fit adds a nearly undamped component
//     started at the line: the strongest local maximum of the segment's DFT at least 1.5 bins from the
//     mode, searched over the fit band and half its width beyond it on each side (the band widened to
//     hold the line), or, without one (the line merged with the mode's peak), 1.25 bins below and
//     above the mode (the one with the smaller residual kept); residual terms as the bins allow. Its
//     mode estimate replaces the first only when its interval passes the precision rule, the mode
//     moved less than a bin, the two components are at least a bin apart (closer, the segment does
//     not resolve them: on the independent nuisance records such fits were up to 10.9 % off with
//     intervals of +-3 %) and the line is real: the fit with it lowers the residual of the one-mode fit
//     on the same bins beyond what noise does at the 1 % level (F test of the 4 added parameters;
//     without it, a line term fitted to noise on a 10 dB record left 4-6 residual degrees of freedom
//     and 2 of the 4 ok intervals it produced missed the true zeta). The SNR for the status rule then uses the fit's residual noise when that
//     is below the gaps' floor (which holds the line). A real second mode (sim-second-mode) is fitted
//     the same way; the cross-check below still marks such events when ridge-ls, which sees both
//     modes, disagrees. (tests/test_pipeline_indep.cpp, 3 seeds, 861 impacts: largest |zeta error| of
//     an ok event 6.1 %.) The 95 % intervals use Student's t quantile for the fit's residual degrees
//     of freedom (ml_fit.hpp, student_t95): a short segment has few DFT bins and its s^2 few degrees
//     of freedom, where the normal 1.96 covers only ~90 %.
//     A one-mode fit that passes the precision rule can still hide a steady line within a bin of the
//     mode (the two look like one damped sinusoid over the segment): MlStep::unresolved_component
//     fits it with a line 1.25 bins either side; when the line is significant, unresolved, steady and
//     moves zeta outside the one-mode interval, the estimate is inconsistent.
//  5. Cross-check of ml against ridge-ls (core/dsp/cross_check.hpp, shared with `ridgewatch modes`,
//     the analyzer's limits): more than 4 combined standard uncertainties apart (plus a 1 % / 1e-4
//     allowance) -> inconsistent.
//
// Where each step lives: 0, 1, 3 and the status rule in impact_analyzer.cpp (window_peak,
// envelope_estimates, report); 2 in ridge_track.hpp (find_ridge, follow_ridge -> RidgeTrack); 4 in
// ml_step.hpp (MlStep); 5 in core/dsp/cross_check.hpp.
//
// Noise: the caller gives the in-band power of the samples between impacts (pre-trigger samples);
// it is converted to the white-noise variance the CWT rows' noise gains refer to. Where decays overlap
// the next impact (the detector in innovation mode) that power holds the previous impact's ringing
// (12-16 dB over the noise at 854 Hz, 25 / s, zeta 0.002), which made every event after the first
// low_snr. The caller then also gives the innovation's power over the same span (the band envelope
// minus the ringing's one-pole continuation: ImpactDetector::innovation_noise_power; with the energy
// trigger the same continuation at the pole of the earlier events' mode,
// ImpactDetector::ringing_free_noise_power), and the analysis
// uses it (the smaller of the two) when the window after the onset holds at least 9 DFT bins of the
// ML fit band, T * 2 ml_band_rel f_expected >= 9 (StreamProcessor's rule for the shortest decay
// window). The ringing itself does not bias zeta: the
// previous decay is the same mode with the same pole, and the sum of two such decays is one decay.
// But the floor with the ringing also holds the lines near the mode, which the innovation follows
// almost as it follows the ringing, and on shorter windows it is what keeps them from ok: there the
// fit kept one residual term, a constant, which did not take up the slope of a nearby line's leakage
// (854 Hz, 25 / s, 32 ms: the impact-locked 550 / 1100 Hz mesh lines put zeta 2-3 % high on every
// event), and it cannot resolve a line within its bins (2.5 kHz, 120 / s, 4.7 ms: the
// 2640 Hz mesh line, zeta a median 31 % low with +-2-8 % intervals). The fit keeps two terms on every
// segment now (MlStep); re-measured, below 9 bins the innovation's floor still lets wrong numbers
// through as ok, also with no line near (300 Hz, 2.3 bins: intervals too narrow, 10 % miss).
// README, survey, "decays that overlap".
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
#include "core/pipeline/ml_step.hpp"
#include "core/pipeline/ridge_track.hpp"

namespace ridgewatch::pipeline {

struct ImpactAnalyzerConfig;

/// Why the window is shorter than configured.
enum class WindowEnd : std::uint8_t {
  complete,     ///< the full configured window (the maximum: the decay had not reached the floor)
  decayed,      ///< ends where the decay reached the noise floor (StreamProcessor): a whole decay
  next_impact,  ///< cut before the next impact's onset
  gap,          ///< cut by a data gap or the end of the stream
};

struct ImpactWindow {
  /// From onset - pretrigger (or the segment start) on, in single precision as acquired (the
  /// analysis widens the samples it needs in double: the ML segment, the half-rate copy).
  std::span<const float> samples;
  std::size_t onset_offset = 0;     ///< index of the onset inside `samples`
  WindowEnd end = WindowEnd::complete;
  double noise_var = NAN;           ///< white-equivalent noise variance of the samples (from the gaps)
  /// The same without the previous impacts' ringing (StreamProcessor: the innovation's power with
  /// detector.trigger_innovation, else the ringing of the earlier events' mode removed; header
  /// comment, "Noise"); NaN before any measurement.
  double innovation_noise_var = NAN;
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
  /// Length of the CWT's forward FFT (StreamProcessor picks maxima whose length is even: FFTW's odd
  /// real transforms allocate work space on every execution).
  std::size_t fft_length() const { return fft_len_; }
  /// 2 when the CWT and the ML fit run on the half-rate copy of the window, 1 at full rate.
  std::size_t input_decimation() const { return in_dec_; }
  /// The rate bound of the half-rate copy: the highest frequency the analysis reads (the top CWT row's
  /// kept band, f_hi (1 + c / eta0), c = 5.26 the band-limited truncation width, and the ML band's top)
  /// is at most fs / 8. The constructor also requires the copy to keep the full-rate grids (header
  /// comment, step 0); input_decimation() tells the outcome.
  static bool decimates(const ImpactAnalyzerConfig& config, double sample_rate_hz);

  /// Sizes only: the constructor computes the CWT's layout (MorletCwt::layout: whether the half-rate
  /// copy keeps the full-rate grids, the FFT length) and the ML segment lengths, without plans or
  /// buffers. prepare() makes the transform, the analysis buffers and the ML fitters and runs every
  /// FFT plan once (FFTW allocates work space on a plan's first execution); analyze() calls it on its
  /// first use. After it, analyze() allocates nothing.
  /// (StreamProcessor keeps one analyzer per maximum window and prepares only those its decays use:
  /// preparing every window length costs tens of ms and MB, docs/performance.md.)
  void prepare();
  bool prepared() const { return prepared_; }

  /// Analyses one window (prepare() on the first call); the event's alarm state is left default (the
  /// caller adds it).
  ImpactEvent analyze(const ImpactWindow& window);

 private:
  double fs_ = 0;
  double fs_a_ = 0;                              // analysis rate: fs_ / in_dec_
  std::size_t in_dec_ = 1;                       // 2: CWT and ML fit on the half-rate copy
  double f_expected_ = 0, band_rel_ = 0, ml_band_rel_ = 0, eta0_ = 7, min_snr_db_ = 20, clip_ = 0.999;
  double max_ci_ratio_ = 1.25;
  dsp::DampingMethod method_ = dsp::DampingMethod::ml;
  std::size_t n_pre_ = 0, n_win_ = 0, n_ml_margin_ = 0;
  std::vector<double> rows_hz_;
  std::vector<double> row_gain_;                 // cwt_->noise_gain(rows_hz_[r]), computed once
  std::vector<std::uint8_t> near_;               // rows x rows: |ln(f_r / f_q)| <= 1 / eta0
  dsp::MorletCwtConfig cwt_cfg_;                 // the transform prepare() makes (full or half rate)
  std::size_t fft_len_ = 0;                      // its FFT length (MorletCwt::layout)
  std::unique_ptr<dsp::MorletCwt<float>> cwt_;
  std::vector<float> xf_;                        // the half-rate copy in float (CWT input at half rate)
  std::vector<double> xd_;                       // the ML input in double: half-rate copy or the segment
  std::vector<std::complex<float>> wf_;          // one row as computed
  std::vector<std::complex<float>> grid_;        // the grid rows (rows x cols)
  std::vector<double> power_;                    // rows x cols |W|^2
  std::vector<std::complex<double>> w_;          // one row
  std::vector<double> scratch_;                  // median of a row (select_kth_nonnegative's scratch)
  std::vector<double> row_median_;               // each row's median |W|^2 over the window
  bool prepared_ = false;                        // prepare() has run
  std::unique_ptr<MlStep> ml_;                   // step 4: the ML fitters
  dsp::EnvelopeWorkspace envelope_ws_;           // line-fit scratch, reserved for max columns
  dsp::EnvelopeFitWeights fit_weights_;          // the line fits' weights of the current row (step 3)

  /// White-noise variance gain of the band-limited row at f (noise_gain), from the nearest grid row:
  /// the discrete filter's gain is proportional to f (4 sqrt(pi) f / (eta0 fs), the Gaussian spans
  /// ~6 bins per sd, so the sampled sum equals the integral to rounding).
  double gain_at(double f_hz) const;

  // The steps of analyze() (impact_analyzer.cpp; the header comment's numbering).
  struct Frame;
  struct Envelope;
  double window_peak(const Frame& fr);
  void load_row(double f_hz, std::size_t cols);
  RidgeTrack track_ridge(const Frame& fr, std::size_t onset_col, std::size_t last_col);
  Envelope envelope_estimates(const Frame& fr, const RidgeTrack& track);
  dsp::DampingEstimate ml_estimate(const Frame& fr, const RidgeTrack& track, const Envelope& env,
                                   double& snr_status_db);
};

}  // namespace ridgewatch::pipeline
