// Impact detection on a sample stream: spike removal -> complex demodulation and decimation ->
// narrow-band envelope energy STA/LTA with a "rise" reference and hold-off -> confirmation -> onset
// refinement (50 % crossing of the envelope, calibrated on a model decay).
//
// Blocks and runs: push() only stores a sample. The spike stage works on blocks of ~0.4 ms (a whole
// number of decimation steps D, 20 samples at 51.2 kHz and the default 250 Hz wide band), and its
// scale is updated once per block; blocks are processed in runs of ~1.6 ms (4 blocks, 80 samples):
// every run, stage 1 runs on its blocks one after the other, then stages 2-5 on the run's band
// samples (each band sample sees the scale as of its own block, as if the blocks ran one at a time;
// the run only delays the decisions). Blocks and runs are aligned to the segment start, so the output
// does not depend on how the caller splits the stream (bit-identical for any push pattern; tested).
// All state is preallocated; push() never allocates (tested). Speed and its history:
// docs/performance.md, section "Impact detector".
//
// Where each stage lives (one file per stage; the hot loops are named kernels in core/dsp/kernels/,
// each with a scalar reference `<name>_generic` and an exactness test in tests/test_kernels_detector.cpp):
//   impact_detector.cpp   construction (block, run and window sizes), push/finish, runs, band_power
//   detector_spike.cpp    stage 1 (kernels spike_residual, clipped_sum)
//   detector_band.cpp     stage 2 and the energy windows of stage 3 (kernels fir_steps,
//                         phasor_rotate, iq_lowpass, ring_sum)
//   detector_trigger.hpp  stage 3's LTA update and stage 4's trigger test, each written once
//   detector_trigger.cpp  stage 4: trigger, start-up reference, confirmation
//   detector_onset.cpp    stage 5: onset model calibration and refinement
// tests/test_reference_detector.cpp holds a slow sample-by-sample implementation of this comment that
// the fast detector must match on every bundled and generated record.
//
//  1. Spikes (isolated outliers). Residual of the 4-neighbour cubic interpolation
//        r[n] = x[n] - (-x[n-2] + 4 x[n-1] + 4 x[n+1] - x[n+2]) / 6
//             = x[n] + (x[n-2] + x[n+2]) / 6 - (x[n-1] + x[n+1]) 2/3   (computed so, in float),
//     which is ~theta^4/6 of the amplitude for a sinusoid of theta rad/sample (3e-4 for 854 Hz at
//     25.6 kHz) and 1.39 sigma for white noise. Sample n is a spike when |r[n]| exceeds spike_mad
//     robust-MAD units and a quarter of its neighbours' magnitude (a sampled force-pulse kink leaves
//     ~5 % of the amplitude at 25.6 kHz; at 0.5 % noise 12 MAD alone flagged 15 of 50 impact onsets),
//     AND its neighbours are normal once x[n] is replaced by the interpolation
//     (their residuals corrected for x[n]'s contribution, -2/3 r[n] at n+-1 and +1/6 r[n] at n+-2,
//     stay below the same limit). A fast impact onset or a burst changes several samples and is not
//     isolated. A spike is counted, recorded, and replaced by the interpolation for the later stages,
//     so it can never trigger. Per block the residuals are computed in one vectorisable pass and only
//     blocks holding a residual above spike_mad MAD (rare: spikes and sharp impact onsets) run the
//     sequential isolation test. When the blocks are whole vectors of four (51.2 kHz at the defaults)
//     and the scale is warm, the residuals, clipped sums and maxima of a run's blocks are computed in
//     one pass, then tested and applied in order (after a block with a candidate, the rest of the run
//     block by block: its spike test may correct the next block's first residuals).
//     The MAD is a winsorised running mean of |r| (time constant lta_s, updated once per block with
//     the block's mean of min(|r|, 3 mean)), converted with the Gaussian
//     ratios MAD = 0.6745 sd, E|r| = 0.7979 sd. The winsorisation limit 3 mean is taken once per run
//     (as of the run's start, once the scale is warm): the blocks' clipped sums then do not wait for
//     each other's scale updates (no serial chain through the scale); it lags the scale by
//     at most 1.2 ms against its time constant lta_s. The spike threshold uses the current scale.
//     Decision delay: 12 samples (the isolation test reads residuals up to n + 10).
//     Samples and residuals are float: the input is float32 already, and the residual's rounding
//     error (~1e-7 of the neighbours' magnitude) is far below both limits (12 MAD of any real noise,
//     a quarter of the neighbours).
//
//  2. Trigger band [band_lo_hz, band_hi_hz] by complex demodulation at f_c = (band_lo + band_hi) / 2
//     with half-width B = (band_hi - band_lo) / 2, in two stages:
//       a) anti-alias FIR and decimation by D = floor(fs / (40 B)): a triangular (2nd-order CIC)
//          low-pass of 2D - 1 taps h[k] applied to the demodulated signal, evaluated once per D
//          samples as
//              z_m = e^{-i w j} sum_k h[k] e^{+i w k} x[j - k],   w = 2 pi f_c / fs, j = step end,
//          i.e. a dot product of the samples with a precomputed complex tap table (the band-pass
//          FIR h[k] e^{i w k}) and one phasor rotation per band sample, in float: the phasor of band
//          sample m is a double base for each group of 16 band samples (advanced by e^{-i w D 16} and
//          renormalised per group, a function of m only) times a float table e^{-i w D (m mod 16)},
//          computed four band samples at a time apart from the recursive part (rounding ~1e-7 of the
//          band content, like the float FIR). Its nulls sit on the multiples
//          of the decimated rate fs_d = fs / D (>= 40 B, 5120 Hz at the defaults); what aliases into
//          the +-B band is attenuated by >= 60 dB (|sin(pi f D / fs) / (D sin(pi f / fs))|^2 at
//          f = fs_d - B). Float taps and sums: the rounding error (~20 taps x 6e-8 of the largest
//          input content) stays > 100 dB below that content, far below any noise floor.
//       b) a 4th-order Butterworth low-pass (two biquads, Q = 0.5412 and 1.3066, bilinear transform
//          with pre-warping at fs_d, double precision, transposed direct form II) with cut-off B on
//          I and Q: with a) an 8th-order band-pass with a flat top.
//     e = I^2 + Q^2 is the squared envelope, free of carrier ripple, one value per D samples. With the
//     default 730-980 Hz (854 Hz +- 15 %) the paper rig's mesh lines are attenuated by 30 dB (550 Hz) and
//     23 dB (1100 Hz): |H| = 1/sqrt(1 + (df/B)^8). With a 500-1500 Hz band the transmission-error lines
//     of sim-nuisance (25 % and 18 % of the impact peak) stand only 10 dB below the impact.
//     Decimating is safe because the envelope of a +-B band is band-limited to 2B: at fs_d >= 40 B the
//     STA/LTA, the trigger logic and the onset interpolation see it 20-fold oversampled. (fs_d = 20 B
//     was tried: the bilinear frequency warping at fs_d then makes the stop band 15 % (energy) deeper
//     at the mesh-line offsets than the per-sample filter was, which moved the noise estimates that
//     StreamProcessor takes from band_power() and one sim-nuisance event past the 10 % acceptance
//     limit; at 40 B it is 5 %.)
//
//  3. Energy e. STA = boxcar mean over sta_s (rounded to band samples); STA and PRE (stage 4) are
//     running sums, re-summed from the history once per pre-window (41 band samples at the defaults) in
//     four interleaved partial sums, so their rounding cannot accumulate. Band samples that are armed,
//     with full windows and a running LTA (most of them) take a short path chosen once per chunk of
//     band samples that skips the start-up and confirmation bookkeeping; it uses the same window
//     update, LTA update and trigger test (detector_trigger.hpp). LTA = exponential mean (time
//     constant lta_s; a cumulative mean at the start) of min(e, 3 LTA), frozen from a trigger to the end
//     of its hold-off: an impact can raise it only slowly. For Gaussian noise the capped mean is 0.857
//     of the power (E min(z^2, 3) = 0.857), which is divided out.
//     Innovation mode (trigger_innovation): stages 3-5 run on q = |z[m] - p z[m - k]|^2 instead of e,
//     z = I + iQ the band's complex envelope. A free decay of one mode in the band is z[m] = c a^m
//     (a = r e^{i (w - w_c) / fs_d}, r = e^{-sigma / fs_d}), so z[m] = a^k z[m - k] exactly: the mode's
//     own past predicts it. p is the least-squares fit of z[m] on z[m - k], sum z[m] conj(z[m - k]) /
//     sum |z[m - k]|^2 as exponential means over lta_s (|p| <= 1), frozen like the LTA (and over 2 k
//     after a trigger, so an impact's own rise does not enter it); for noise alone p ~ 0 and q ~ e.
//     An impact at random phase on a ringing that still holds most of its amplitude raises e by
//     (1 + |A / R|^2) on average (R the ringing's amplitude; 1.56x at 66 % left per period), but q by
//     |A|^2 over the noise floor, whatever the phase. The lag k is the model's peak time + 1 ms in band
//     samples (stage 5): the innovation of a new decay follows the model envelope to its maximum, so
//     the onset refinement applies unchanged, and falls back once z[m - k] holds the new decay too.
//     band_power() and lta() stay those of e (lta(): of q in this mode, >= the band's noise power).
//
//  4. Trigger when STA > trigger_ratio * max(LTA, PRE), PRE = the mean of e over the pre-window just
//     before the STA window (one correlation time 1/B of the band's envelope, 8 ms at the defaults).
//     The PRE term makes the detector respond to a *rise*: the decaying tail of the previous impact
//     (still 10-30x above the noise after 30 ms on the paper rig), a beat between that tail and a
//     residual line, or the slow fluctuation of narrow-band noise never rise 8-fold within 0.5 ms;
//     a new impact on top of them does. (A reference made of the lowest STA since the last trigger,
//     tried first, is fooled by beat nulls.) Confirmation: the mean energy over the next 4 STA
//     windows (2 ms) must also exceed trigger_ratio * reference. No trigger within holdoff_s after one.
//     Start of a segment. The filters start from rest, so stationary input gives E[e] = E_inf g(m)
//     (the fill-up curve, from the chain's impulse response); e is divided by g, and triggers wait
//     until g >= 1/4. The LTA, which can grow only slowly, is raised at that point to the white-noise
//     band power implied by the spike stage's MAD (a start transient or a line leaves almost no
//     interpolation residual), so it starts near the noise floor instead of far below it. A rig that
//     is switched on with the record rings at its natural frequency (the simulator's mesh effects do:
//     ~40 % of an impact's amplitude), and an early impact sits on that decaying ring: PRE, a mean over
//     8 ms, lags the decay and hid the first impact. So until the first impact of the segment and at
//     most lta_s after the warm-up, the rise reference is the smaller of PRE and the mean of e over
//     2 ms ending one model peak time earlier, scaled by the model's energy decay over that distance
//     (floored at the white-noise band power): a decaying ring, of any damping down to a steady tone,
//     stands at most exp(2 sigma_0 lag) = 7.2 times above it (lag 7.6 ms at the defaults), below the
//     trigger ratio 8, while an impact rises from it 10-fold and more (the simulated first impacts).
//     Noise floor (trigger_noise_ratio > 0; off by default): the reference is also at least
//     trigger_noise_ratio / trigger_ratio x the white-noise band power the spike stage implies (its MAD
//     as of the band sample's block, white_band_power()), so STA and confirmation must exceed
//     trigger_noise_ratio x that power. Where the band holds noise only, its envelope energy is
//     exponentially distributed (P(e > r x mean) = e^-r) and, in a band narrower than ~500 Hz, keeps
//     its value longer than the 2 ms confirmation (correlation time ~1/B), so noise alone reaches
//     several times its mean: 4.9x in 5 s of a 257 Hz band, more over longer streams. A ratio lowered
//     for decays that fill the interval (their LTA far above the noise) then needs this floor where
//     the band holds noise only (before the first impact). The decays themselves leave almost no
//     interpolation residual (theta^4 / 6 of their amplitude), so the floor follows the noise, not them.
//
//  5. Onset: the trigger band's envelope is insensitive to the mesh lines but rises slowly (group
//     delay of the low-pass ~ 2.6 / (2 pi B) = 3.3 ms at B = 125 Hz). Its response to a free decay
//     starting at t0 is a fixed shape: the constructor runs the same chain over a step-started decaying
//     tone at f_c (zeta = 0.024, the paper rig), at each of the D positions relative to the band-sample
//     grid, and measures when that envelope crosses half its maximum (t50 = 3.7 ms, the mean over the
//     positions) and when it peaks (6.6 ms). Per impact: the envelope maximum after the trigger, the
//     last crossing of half that maximum before it (linear interpolation between band samples; the
//     spread of t50 over the grid positions is < 0.1 sample, t50_spread_samples()), minus t50.
//     Amplitude-independent, and the lines stay 23-30 dB down. (An Akaike change point on the raw
//     signal, tried first, is 4 ms late when transmission-error lines as large as the impact interfere
//     destructively with its first cycles.) The onset is decided as soon as the running maximum is
//     final: when it has not grown for 1 ms, or when the onset it implies lies the model's peak time +
//     1 ms in the past; never before the confirmation. Worst-case delay from an onset to its report:
//     report_delay_samples(), 11.1-11.3 ms at the defaults; measured up to 8.5 ms. Measured onsets on
//     the simulated rig: within 0.1-0.2 ms of the start of the 0.15 ms force pulse (up to 0.34 ms for an impact on
//     the start-up ring).
#pragma once

#include <array>
#include <complex>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/dsp/kernels/iq_lowpass.hpp"
#include "core/pipeline/detector_config.hpp"

namespace ridgewatch::pipeline {

class ImpactDetector {
 public:
  /// history_samples: how far back band powers and spike indices stay available for
  /// noise estimates (input samples).
  ImpactDetector(const ImpactDetectorConfig& config, double sample_rate_hz, std::size_t history_samples);
  // Holds pointers into its own buffers: not copyable (moving keeps the buffers).
  ImpactDetector(const ImpactDetector&) = delete;
  ImpactDetector& operator=(const ImpactDetector&) = delete;
  ImpactDetector(ImpactDetector&&) = default;
  ImpactDetector& operator=(ImpactDetector&&) = default;

  /// Starts a new contiguous segment at absolute index `first_index` (stream start or after a gap).
  /// Pending triggers are dropped; call finish() first to keep them.
  void restart(std::uint64_t first_index);

  /// Feeds the raw sample of absolute index next_index() (consecutive). Stores it; every
  /// decimation() samples one block is processed.
  void push(float x) {
    *wp_ = x;
    if (++wp_ == due_p_) process_block();
  }
  /// Feeds consecutive samples (same result as pushing them one by one): copied in runs up to the
  /// next block.
  void push(std::span<const float> xs);
  /// Samples to push until the next block runs (>= 1). Onsets are reported only by the push that
  /// completes a block, so a caller may push that many samples at once and then check has_onset().
  std::size_t until_block() const { return static_cast<std::size_t>(due_p_ - wp_); }
  /// End of the segment: decides the delayed samples and resolves a trigger under confirmation with
  /// what has been seen.
  void finish();

  std::uint64_t next_index() const { return base_ + static_cast<std::uint64_t>(wp_ - buf_x_.data()); }

  /// Onsets found, in order; the caller takes them with pop_onset().
  bool has_onset() const { return onset_count_ > 0; }
  std::uint64_t pop_onset();

  /// Trigger-band power over [begin, end) absolute indices: the time average of e from the stored
  /// history, one e per band sample (blk / D per block), band sample m stamped at seg_start + m D (the
  /// end of its decimation step minus the FIR's group delay D - 1) and interpolated linearly between
  /// band samples; only band samples after the chain's fill-up are used. NaN when the range is shorter
  /// than 8 samples or its overlap with those stored band samples is.
  double band_power(std::uint64_t begin, std::uint64_t end) const;
  /// Innovation mode: the band's noise power over [begin, end) without the ringing of earlier
  /// impacts, from the trigger statistic q = |z[m] - p z[m - k]|^2 (stage 3): its time average (as
  /// band_power() averages e) divided by q's white-noise gain relative to e, 1 + |p|^2 -
  /// 2 Re(conj(p) rho_k) (rho_k the band's noise correlation at the lag, p the current predictor).
  /// A free decay of the band's mode leaves nothing in q, so between overlapping decays this is the
  /// noise (and what the one-pole prediction does not follow: lines, other modes) where band_power()
  /// holds the previous impact's ringing. NaN in energy mode or where band_power() is NaN.
  double innovation_noise_power(std::uint64_t begin, std::uint64_t end) const;
  /// Either mode: the band's noise power over [begin, end) without the ringing of a known mode, the
  /// time average of q = |z[m] - p z[m - k]|^2 with the predictor p = exp(k D (-sigma + i (w - w_c)) /
  /// fs) of a free decay at f_hz with damping ratio zeta (w = 2 pi f_hz, sigma = zeta w / sqrt(1 -
  /// zeta^2), w_c the band's centre: z's demodulation), divided by q's white-noise gain relative to e
  /// (as innovation_noise_power()). For decays that overlap less than the innovation trigger needs
  /// (energy mode): the pole comes from the analysis of earlier impacts, which all ring in the same
  /// mode. NaN for a pole outside the band or where band_power() is NaN.
  double ringing_free_noise_power(std::uint64_t begin, std::uint64_t end, double f_hz, double zeta) const;
  bool innovation_mode() const { return innov_; }
  /// Robust noise floor: LTA (bias-corrected) of the band power (with trigger_innovation: of the
  /// innovation energy, the trigger statistic, which for noise alone is the band power).
  double lta() const { return band_.lta / kCapBias; }
  /// E[e] for unit-variance white input (the squared impulse responses of the whole chain, summed
  /// over the block positions): divides a band power into the white-equivalent variance of the samples.
  double band_noise_gain() const { return band_noise_gain_; }

  /// True if a spike was found in [begin, end).
  bool spike_in(std::uint64_t begin, std::uint64_t end) const;
  std::uint64_t spikes_seen() const { return spikes_; }

  /// How far before its trigger (the raw sample that completed the block whose STA crossed) an onset
  /// can lie, in samples.
  std::size_t lookback_samples() const { return lookback_; }
  /// The rest of the worst-case report delay: an onset o is reported (has_onset()) at the latest when
  /// sample o + lookback_samples() + decision_delay_samples() has been pushed, so a caller waiting that
  /// long after a sample knows every onset at or before it.
  std::size_t decision_delay_samples() const { return report_delay_ - lookback_; }
  /// Worst-case delay from an onset to its report, in samples (= lookback + decision delay):
  /// max(model peak time + 1 ms, look-back + confirmation) + one run + the spike delay. 11.1-11.3 ms
  /// at the defaults (25.6 and 51.2 kHz); tested by feeding impacts and counting samples.
  std::size_t report_delay_samples() const { return report_delay_; }

  /// Decimation factor D (input samples per trigger-band sample; blocks are whole multiples of it).
  std::size_t decimation() const { return dec_; }
  /// Model: 50 % rise time of the envelope after an onset, and its spread (max - min) over the D
  /// positions of the onset relative to the block grid, in input samples.
  double t50_samples() const { return t50_samples_; }
  double t50_spread_samples() const { return t50_spread_; }
  /// Model: time from the onset to the envelope maximum, input samples.
  double peak_samples() const { return peak_samples_; }

 private:
  static constexpr double kCapBias = 0.857;  // E min(z^2, 3) for z ~ N(0, 1)
  static constexpr double kCap = 3.0;
  static constexpr std::size_t kSpikeDelay = 12;  // the spike test reads x[n + 12] (isolation, right side)
  // decide_block() reads up to 2 samples and writes residuals up to the position of the sample that
  // completes a block (its vectors of four run past the block): the buffer is shifted when fewer than
  // this many slots follow that position.
  static constexpr std::size_t kReadAhead = 4;
  static constexpr std::size_t kMaxOnsets = 16;
  static constexpr std::size_t kSpikeRing = 256;
  static constexpr std::uint64_t kMadWarmup = 32;
  static constexpr double kBlockS = 0.0004;  // spike-stage block length, s (whole decimation steps)
  static constexpr double kRunS = 0.0016;    // processing run length, s (whole blocks)
  static constexpr std::size_t kMaxRunBlocks = 8;
  static constexpr double kModelZeta = 0.024;  // damping ratio of the onset model (the paper rig)

  /// The trigger band's running state: stage 2b's filter, the demodulation phasor, stage 3's sums and
  /// LTA. Worked on in place (a local copy per run did not pay: docs/performance.md).
  struct BandState {
    dsp::kernels::IqLowPass4State lp;     // I/Q low-pass states
    std::complex<double> phasor{1.0, 0.0};  // demodulation phasor base of band sample m's group
    std::uint64_t m = 0;                  // band samples in this segment (decimated index of the next one)
    double sta_sum = 0, pre_sum = 0;      // running sums of e over the STA window and the pre-window
    std::size_t resum_left = 1;           // band samples until the sums are re-summed from the history
    double lta = 0;                       // capped running mean of e (stage 3), not bias-corrected
    std::uint64_t lta_count = 0;          // band samples the LTA has seen
  };

  // construction steps (impact_detector.cpp, detector_band.cpp, detector_onset.cpp)
  void design_band(double fc_hz, double bw_hz);
  void set_windows(const ImpactDetectorConfig& cfg, double bw_hz);
  void measure_fill_up(double bw_hz, std::vector<std::complex<double>>& responses);
  void set_onset_timing(double fc_hz);
  void allocate(std::size_t history_samples);

  void process_block();
  void decide_blocks(std::uint64_t b, std::size_t count);
  void decide_block(std::uint64_t b, std::size_t len, std::size_t n_res, bool test_spikes);
  void band_blocks(std::uint64_t b, std::size_t count);
  void demodulate(const float* x, std::size_t n, std::size_t i0, std::complex<double>& phasor);
  bool band_sample_steady(BandState& s, double e);
  double innovation(const BandState& s, std::complex<double> z, double e);
  bool band_sample_general(BandState& s, double& e, std::size_t sub);
  void push_energy(BandState& s, double e);
  void resum(BandState& s) const;
  bool steady(const BandState& s) const;
  // detector_trigger.hpp: the LTA update and the trigger test, shared by every path.
  double lta_next(double lta, double e, std::uint64_t count) const;
  double trigger_reference(double lta, double rise_ref) const;
  bool fires(double sta_sum, double lta, double rise_ref) const;
  bool confirms(double mean_e) const;
  double full_pre_mean(double pre_sum) const;
  void spike_test(std::uint64_t n, double t_mad);
  void decide_band_sample(std::uint64_t m, double e, double mad);
  void refine_and_emit(std::uint64_t trigger, std::uint64_t end);
  std::uint64_t onset_estimate(std::uint64_t trigger, std::uint64_t k_peak, double* onset_d) const;
  std::uint64_t search_floor(std::uint64_t trigger) const;  // oldest band sample the onset search reads
  std::uint64_t dec_end_index(double m) const;  // absolute input index of decimated sample m's end
  void calibrate(double fc_hz);
  void run_chain(const std::vector<double>& x, std::vector<std::complex<double>>& y) const;
  void shift_buffer();
  double white_band_power(double mad) const;
  /// Time average over [begin, end) of a band-sample history (e_hist_ or q_hist_): band_power()'s rule.
  double history_power(const std::vector<double>& hist, std::uint64_t begin, std::uint64_t end) const;
  /// The same time average of any per-band-sample value, value(m) for band sample m.
  template <class Value>
  double history_average(const Value& value, std::uint64_t begin, std::uint64_t end) const;
  void measure_lag_correlation(const std::vector<std::complex<double>>& responses);  // innov_rho_ at lag k
  void note_scale(std::size_t k);  // keeps the spike stage's scale after block k of a run
  void start_run_scale();          // fixes the winsorisation limit of the run's blocks
  /// Winsorisation limit 3 mean |r| of the scale update: as of the start of the run once the scale is
  /// warm (so the blocks' clipped sums do not wait for each other's updates), else the current one.
  float block_clip() const {
    return run_clip_ready_ ? run_clip_ : static_cast<float>(3.0 * mad_sum_ + 1e-30);
  }

  // configuration (input samples unless named _d: decimated samples)
  double fs_ = 0, fs_d_ = 0;
  double ratio_ = 8;
  double noise_floor_ = 0;              // trigger_noise_ratio / trigger_ratio (stage 4's noise floor), 0 = off
  double fc_hz_ = 0;                    // centre of the trigger band (z's demodulation frequency), Hz
  double spike_k_ = 12;
  std::size_t dec_ = 1;                 // decimation factor D
  std::size_t blk_ = 1;                 // samples per spike-stage block (a multiple of D)
  double inv_blk_ = 1;
  std::size_t subs_ = 1, run_ = 1;      // blocks and samples per processing run
  std::size_t taps_ = 2;                // FIR length L = 2 D
  std::vector<std::uint8_t> sub_of_;    // band sample j of a run -> its block, j / (blk / D)
  std::vector<float> g_re_, g_im_;      // band-pass FIR h[k] e^{+i w k}, stored reversed (oldest first)
  std::complex<double> rot_d_{1.0, 0.0};  // e^{-i w D}
  static constexpr std::size_t kGroup = 16;  // band samples per demodulation phasor base
  std::array<float, kGroup + 4> pw_re_{}, pw_im_{};  // e^{-i w D k}, k < kGroup (zero-padded)
  std::complex<double> rot_g_{1.0, 0.0};  // e^{-i w D kGroup}
  // band_blocks() scratch: FIR outputs and demodulated values of a chunk (padded for vectors of four,
  // zeroed once: the vectors read past a chunk's end)
  std::array<float, kGroup + 4> fir_re_{}, fir_im_{}, z_re_{}, z_im_{};
  std::size_t sta_d_ = 1, lta_d_ = 1, holdoff_d_ = 0, confirm_d_ = 1, pre_d_ = 1;
  double inv_sta_d_ = 1, inv_pre_d_ = 1;
  std::size_t warmup_d_ = 1;            // band samples before triggers are allowed
  std::vector<double> fill_;            // fill-up g(m) after a restart
  std::size_t lag_d_ = 1, lagw_d_ = 1;  // start-up rise reference: lag and window
  double lag_decay_ = 1;                // model energy decay over the lag
  std::size_t startup_end_d_ = 1;       // start-up rule ends here (or at the first impact)
  std::size_t search_back_d_ = 1;       // crossing search floor before the trigger
  std::size_t hold_d_ = 1;              // a running maximum that has not grown for this long is final
  std::size_t cap_d_ = 1;               // decision at the latest this long after the trigger
  double t50_samples_ = 0, t50_spread_ = 0, peak_samples_ = 0;
  std::size_t lookback_ = 1, report_delay_ = 1;
  double lta_alpha_ = 0, lta_keep_ = 1, lta_cap_alpha_ = 0, mad_beta_ = 0;
  double band_noise_gain_ = 1;
  dsp::kernels::BiquadCoefs lp1_, lp2_;  // the 4th-order Butterworth low-pass's two stages

  // input buffer: sample n at buf_[n - base_] (unsigned, wraps consistently)
  std::vector<float> buf_x_, buf_r_;    // raw (then cleaned) samples and their residuals (float: see 1.)
  std::size_t hist_ = 0;                // samples kept before a block when the buffer is shifted
  std::uint64_t base_ = 0;

  // segment state
  std::uint64_t seg_start_ = 0, next_block_ = 0;
  float* wp_ = nullptr;     // where the next pushed sample goes (in buf_x_)
  float* due_p_ = nullptr;  // the block starting at next_block_ runs when wp_ reaches this
  double mad_sum_ = 0;           // running winsorised mean |r|
  std::uint64_t mad_count_ = 0;
  float run_clip_ = 0;          // block_clip() of the current run
  bool run_clip_ready_ = false;
  std::array<double, kMaxRunBlocks> scale_at_{};  // mad_sum_ after each block of the current run
  std::array<bool, kMaxRunBlocks> scale_ready_{};  // ... and whether it had seen kMadWarmup samples
  BandState band_;

  std::vector<double> e_hist_;   // trigger-band power history, by decimated index & mask
  // Innovation mode (stage 3): the trigger statistic's history (q; e_hist_ itself in energy mode),
  // the running least-squares sums of the predictor p = c / w. Both modes: the band's complex
  // envelope z by decimated index & mask and the lag k (ringing_free_noise_power()).
  double* th_ = nullptr;
  bool innov_ = false;
  std::vector<double> q_hist_;
  std::vector<std::complex<double>> z_hist_;
  std::size_t innov_lag_d_ = 1;
  std::size_t freeze_extra_d_ = 0;  // LTA (and predictor) freeze after a trigger beyond hold-off and confirmation
  std::complex<double> innov_c_{0.0, 0.0};
  double innov_w_ = 0.0;
  std::complex<double> innov_rho_{0.0, 0.0};  // white noise's band correlation at lag k, E[n[m] conj(n[m - k])] / E|n|^2
  std::uint64_t e_mask_ = 0;
  bool lta_raised_ = false;  // the start-up raise to the white-noise band power has been done
  std::uint64_t holdoff_end_ = 0, lta_frozen_until_ = 0;
  bool confirming_ = false;
  std::uint64_t trigger_ = 0, peak_at_ = 0, peak_since_ = 0;
  static constexpr std::uint64_t kNoPeak = ~std::uint64_t{0};
  std::uint64_t est_peak_ = kNoPeak, est_floor_ = 0;  // running maximum and search floor of est_onset_d_
  double est_onset_d_ = 0;
  double trigger_ref_ = 0, confirm_sum_ = 0;
  std::size_t confirm_seen_ = 0;
  bool confirmed_ = false;
  bool startup_ = true;  // no impact yet in this segment and within the start-up period

  std::array<std::uint64_t, kMaxOnsets> onsets_{};
  std::size_t onset_head_ = 0, onset_count_ = 0;
  std::array<std::uint64_t, kSpikeRing> spike_idx_{};
  std::size_t spike_head_ = 0, spike_count_ = 0;
  std::uint64_t spikes_ = 0;
};

}  // namespace ridgewatch::pipeline
