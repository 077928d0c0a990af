#include "core/pipeline/impact_analyzer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "core/dsp/cross_check.hpp"
#include "core/pipeline/analyzer_config.hpp"
#include "core/pipeline/ridge_track.hpp"

namespace ridgewatch::pipeline {

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

// DFT bins across the ML fit band (2 ml_band_rel f_expected) the window after the onset must hold for
// the innovation's noise floor to stand in for the floor between impacts (header comment, "Noise").
constexpr double kFloorBins = 9.0;

ImpactStatus from_estimate(dsp::EstimateStatus s) {
  switch (s) {
    case dsp::EstimateStatus::ok: return ImpactStatus::ok;
    case dsp::EstimateStatus::too_short: return ImpactStatus::too_short;
    case dsp::EstimateStatus::low_snr: return ImpactStatus::low_snr;
    case dsp::EstimateStatus::not_decaying: return ImpactStatus::not_decaying;
    case dsp::EstimateStatus::fit_failed: return ImpactStatus::fit_failed;
    case dsp::EstimateStatus::inconsistent: return ImpactStatus::inconsistent;
  }
  return ImpactStatus::fit_failed;
}

// Highest frequency the analysis reads: the top CWT row's kept band (band-limited truncation width
// c = sqrt(2 ln 1e6) = 5.26 filter sds above it) or the ML band's top, whichever is higher.
double analysis_top_hz(const ImpactAnalyzerConfig& cfg) {
  const double c = std::sqrt(2.0 * std::log(1.0 / dsp::MorletCwtConfig::kBandLimitedTruncation));
  const double f_hi = cfg.f_expected_hz * (1.0 + cfg.band_rel);
  return std::max(f_hi * (1.0 + c / cfg.eta0), f_hi * (1.0 + cfg.ml_band_rel));
}

}  // namespace

bool ImpactAnalyzer::decimates(const ImpactAnalyzerConfig& cfg, double fs) {
  return analysis_top_hz(cfg) <= fs / 8.0;
}

ImpactAnalyzer::ImpactAnalyzer(const ImpactAnalyzerConfig& cfg, double fs) {
  fs_ = fs;
  f_expected_ = cfg.f_expected_hz;
  band_rel_ = cfg.band_rel;
  ml_band_rel_ = cfg.ml_band_rel;
  eta0_ = cfg.eta0;
  min_snr_db_ = cfg.min_snr_db;
  max_ci_ratio_ = cfg.max_ci_ratio;
  clip_ = cfg.clip_level;
  method_ = cfg.method;
  n_pre_ = static_cast<std::size_t>(std::llround(cfg.pretrigger_s * fs));
  n_win_ = static_cast<std::size_t>(std::llround(cfg.window_s * fs));
  n_ml_margin_ = static_cast<std::size_t>(std::ceil(0.0005 * fs));
  const std::size_t full_len = n_win_ > n_ml_margin_ ? n_win_ - n_ml_margin_ : 0;  // full-rate ML segment

  const double lo = f_expected_ * (1.0 - band_rel_), hi = f_expected_ * (1.0 + band_rel_);
  const auto rows = std::max<std::size_t>(
      3, static_cast<std::size_t>(std::ceil(std::log(hi / lo) * 3.0 * eta0_)) + 1);
  rows_hz_ = dsp::make_frequency_grid(lo, hi, rows, dsp::GridSpacing::log);
  dsp::MorletCwtConfig cc;
  cc.sample_rate_hz = fs;
  cc.eta0 = eta0_;
  cc.frequencies_hz = rows_hz_;
  cc.max_samples = max_samples();
  cc.band_limited = true;
  // Only the layouts here (the transform and its plans are made by prepare()).
  const auto full_layout = dsp::MorletCwt<float>::layout(cc);
  cwt_cfg_ = cc;
  fft_len_ = full_layout.fft_length;
  in_dec_ = 1;
  // Half rate (header comment, step 0) when the rate bound holds and the copy keeps the full-rate
  // grids: the CWT's column step (an even full-rate decimation) and the complete window's ML segment
  // (an even length whose half the copy holds with the onset at the pretrigger), so that the same
  // columns and DFT bins are analysed.
  if (decimates(cfg, fs) && full_layout.decimation % 2 == 0 && full_len % 2 == 0 &&
      (n_pre_ + n_win_) / 2 >= (n_pre_ + n_ml_margin_ + 1) / 2 + full_len / 2) {
    dsp::MorletCwtConfig hc = cc;
    hc.sample_rate_hz = fs / 2.0;
    hc.max_samples = (max_samples() + 1) / 2;
    hc.half_rate_121_input = true;
    const auto half_layout = dsp::MorletCwt<float>::layout(hc);
    if (2 * half_layout.decimation == full_layout.decimation) {
      cwt_cfg_ = hc;
      fft_len_ = half_layout.fft_length;
      in_dec_ = 2;
    }
  }
  fs_a_ = fs / static_cast<double>(in_dec_);
  // Rows within one filter sd (1/eta0 in ln f) of each other, for the ridge follow-up's stray and
  // recovery tests (computed once: no logarithm per column).
  near_.resize(rows * rows);
  for (std::size_t r = 0; r < rows; ++r)
    for (std::size_t q = 0; q < rows; ++q)
      near_[r * rows + q] = std::abs(std::log(rows_hz_[r] / rows_hz_[q])) <= 1.0 / eta0_ ? 1 : 0;
  // ML fitters for segments of k/8 of the full decay window (MlStep): only the lengths here (cheap);
  // the buffers, the fitters and the FFTW warm-up wait for prepare().
  ml_ = std::make_unique<MlStep>(full_len, in_dec_, fs_, ml_band_rel_, rows_hz_.back(), max_ci_ratio_);
}

void ImpactAnalyzer::prepare() {
  if (prepared_) return;
  const std::size_t rows = rows_hz_.size();
  cwt_ = std::make_unique<dsp::MorletCwt<float>>(cwt_cfg_);
  // The ridge follow-up asks for a row's noise gain at every column; noise_gain() integrates the
  // filter each time, so the rows' gains are kept.
  row_gain_.resize(rows);
  for (std::size_t r = 0; r < rows; ++r) row_gain_[r] = cwt_->noise_gain(rows_hz_[r]);
  // CWT input length: the window, or its half-rate copy (ceil(n / 2) samples).
  const std::size_t max_in = (max_samples() + in_dec_ - 1) / in_dec_;
  const std::size_t max_cols = (max_in + cwt_->decimation() - 1) / cwt_->decimation() + 1;
  power_.assign(rows * max_cols, 0.0);
  w_.assign(max_cols, {});
  wf_.assign(max_cols, {});
  grid_.assign(rows * max_cols, {});
  if (in_dec_ == 2) xf_.assign(max_in, 0.0f);
  xd_.assign(max_in, 0.0);
  scratch_.assign(2 * max_cols, 0.0);
  row_median_.assign(rows, 0.0);
  envelope_ws_.reserve(max_cols, max_cols);
  fit_weights_.reserve(max_cols);
  ml_->prepare();
  // Warm-up: FFTW allocates work space on a plan's first execution, so every plan runs once here
  // (the CWT's forward and inverse transforms; MlStep::prepare: each fitter's bin evaluation at its
  // largest band): after prepare(), analyze() allocates nothing.
  {
    std::fill(xf_.begin(), xf_.end(), 0.0f);
    std::vector<float> zeros(max_in, 0.0f);
    cwt_->load(zeros);
    cwt_->grid_rows(std::span<std::complex<float>>(grid_.data(), rows * cwt_->columns()));
    cwt_->row(f_expected_, std::span<std::complex<float>>(wf_.data(), cwt_->columns()));
  }
  prepared_ = true;
}

ImpactAnalyzer::~ImpactAnalyzer() = default;

double ImpactAnalyzer::gain_at(double f_hz) const {
  // rows_hz_ is log-spaced: the nearest row in ln f.
  const double pos = std::log(f_hz / rows_hz_.front()) / std::log(rows_hz_.back() / rows_hz_.front()) *
                     static_cast<double>(rows_hz_.size() - 1);
  const auto r = static_cast<std::size_t>(std::clamp(std::lround(pos), 0L, static_cast<long>(rows_hz_.size() - 1)));
  return row_gain_[r] * f_hz / rows_hz_[r];
}


// The values of one window that the steps share.
struct ImpactAnalyzer::Frame {
  std::span<const float> x;  // the window's samples, the first n used
  std::size_t n = 0;         // samples analysed (at most max_samples())
  std::size_t n_a = 0;       // CWT input samples: n, or the half-rate copy's ceil(n / 2)
  std::size_t o = 0;         // onset index in x
  double onset_s = 0;        // onset time from the window start, s
  double kernel_s = 0;       // the Morlet kernel's time sd at f_expected, s
  double noise_var = 0;      // white-equivalent noise variance of x (floored, > 0)
  std::size_t cols = 0;      // CWT columns
  double dt = 0;             // CWT column step, s
};

// Step 3's results.
struct ImpactAnalyzer::Envelope {
  dsp::EnvelopeWindow window;      // on the envelope row at f_d
  double f_d = NAN, f_sd = NAN;    // damped frequency from the phase slope (f_ridge when unusable), Hz
  bool lost = false;               // the phase slope's frequency lies outside the band
  dsp::DampingEstimate two, rls;   // two-point (only when selected) and ridge least squares
};

// Step 0: the peak |x| of the window for the clipping check. At full rate the window itself is the
// CWT input: one pass of four running maxima (one would be a serial chain of compare-selects). At half
// rate the pass that makes the copy (into xd_ and xf_) also returns max |x| (dsp::decimate_half_121).
double ImpactAnalyzer::window_peak(const Frame& fr) {
  float pk[4] = {0.0f, 0.0f, 0.0f, 0.0f};
  if (in_dec_ == 1) {
    std::size_t i = 0;
    for (; i + 4 <= fr.n; i += 4) {
      for (std::size_t j = 0; j < 4; ++j) {
        const float a = std::abs(fr.x[i + j]);
        pk[j] = a > pk[j] ? a : pk[j];
      }
    }
    for (; i < fr.n; ++i) {
      const float a = std::abs(fr.x[i]);
      pk[0] = a > pk[0] ? a : pk[0];
    }
  } else {
    pk[0] = static_cast<float>(dsp::decimate_half_121(fr.x.first(fr.n), std::span<double>(xd_.data(), fr.n_a),
                                                      std::span<float>(xf_.data(), fr.n_a)));
  }
  return static_cast<double>(std::max(std::max(pk[0], pk[1]), std::max(pk[2], pk[3])));
}

// The CWT row at f (float, as computed) widened into w_.
void ImpactAnalyzer::load_row(double f_hz, std::size_t cols) {
  cwt_->row(f_hz, std::span<std::complex<float>>(wf_.data(), cols));
  for (std::size_t c = 0; c < cols; ++c) w_[c] = std::complex<double>(wf_[c]);
}

// Step 2: the ridge on the power grid (core/pipeline/ridge_track.hpp). Requires onset_col < last_col.
RidgeTrack ImpactAnalyzer::track_ridge(const Frame& fr, std::size_t onset_col, std::size_t last_col) {
  const std::size_t rows = rows_hz_.size(), cols = fr.cols;
  cwt_->grid_rows(std::span<std::complex<float>>(grid_.data(), rows * cols));
  const RidgeStart start = find_ridge(std::span<const std::complex<float>>(grid_.data(), rows * cols), rows, cols,
                                      onset_col, last_col, power_, row_median_, scratch_);
  const RidgeGrid grid{std::span<const double>(power_.data(), rows * cols), row_median_, rows, cols};
  RidgeFollowInputs in;
  in.rows_hz = rows_hz_;
  in.row_gain = row_gain_;
  in.near = near_;
  in.noise_var = fr.noise_var;
  in.width_cols = std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(fr.kernel_s / fr.dt)));
  in.last_col = last_col;
  return follow_ridge(grid, start, in);
}

// Step 3: phase slope at the ridge frequency, then the envelope row at f_d and its estimators. The
// line fits' weights are computed once per row and window and passed to both fits that use them.
ImpactAnalyzer::Envelope ImpactAnalyzer::envelope_estimates(const Frame& fr, const RidgeTrack& track) {
  Envelope e;
  const double f_ridge = track.f_hz;
  dsp::EnvelopeOptions env;
  env.onset_s = fr.onset_s;
  // A stopped free response: the envelope estimators see the row up to the ridge's end as if the
  // record ended there (choose_window skips the edge_widths kernel widths before it, which hold the
  // transform's response to the stop).
  const std::span<const std::complex<double>> w(w_.data(), fr.cols);
  dsp::EnvelopeRow row{w.first(track.end_col), fr.dt, f_ridge, eta0_, fr.noise_var * gain_at(f_ridge)};
  row.phase_reference_hz = f_ridge;
  load_row(f_ridge, fr.cols);
  e.window = dsp::choose_window(row, env);
  dsp::envelope_fit_weights(row, e.window, dsp::kPhaseSlopeStride, fit_weights_, envelope_ws_);
  e.f_d = dsp::phase_slope_frequency(row, e.window, e.f_sd, fit_weights_, envelope_ws_);
  if (!std::isfinite(e.f_d) || e.f_d < rows_hz_.front() || e.f_d > rows_hz_.back()) {
    e.lost = std::isfinite(e.f_d);
    e.f_d = f_ridge;
    e.f_sd = NAN;
  }
  // The envelope row at f_d. Within 2 % of a filter sd (f / eta0) of f_ridge the row at f_ridge stands
  // for it: the Gaussian filter's gain differs by exp(-(eta0 df / f)^2 / 2) >= 0.9998, a constant
  // factor of the envelope (no effect on its decay), so the row, its window and its noise stay those
  // of f_ridge and only the damping conversion uses f_d.
  bool moved = false;
  if (!(std::abs(e.f_d - f_ridge) <= 0.02 * f_ridge / eta0_)) {
    moved = true;
    row.f_row_hz = e.f_d;
    row.phase_reference_hz = e.f_d;
    row.noise_power = fr.noise_var * gain_at(e.f_d);
    load_row(e.f_d, fr.cols);
    e.window = dsp::choose_window(row, env);
  }
  // The two-point estimate (Eq. 17-19) only when it is the selected method: nothing else uses it.
  if (method_ == dsp::DampingMethod::two_point) e.two = dsp::estimate_two_point(row, e.window, e.f_d);
  // The phase slope's weights serve the ridge LS when the row and the stride are the same.
  const std::size_t stride = dsp::ridge_ls_stride(row);
  if (moved || stride != dsp::kPhaseSlopeStride)
    dsp::envelope_fit_weights(row, e.window, stride, fit_weights_, envelope_ws_);
  e.rls = dsp::estimate_ridge_ls(row, e.window, e.f_d, fit_weights_, envelope_ws_);
  e.two.f_sd_hz = e.rls.f_sd_hz = e.f_sd;
  return e;
}

// Step 4: the ML fit on the decay segment (MlStep), started from the ridge-LS estimate. snr_status_db
// receives the SNR the status rule uses when the fit modelled a steady line (header comment).
dsp::DampingEstimate ImpactAnalyzer::ml_estimate(const Frame& fr, const RidgeTrack& track, const Envelope& env,
                                                 double& snr_status_db) {
  dsp::DampingEstimate ml;
  ml.method = dsp::DampingMethod::ml;
  ml.status = dsp::EstimateStatus::too_short;
  // The segment ends with the window, or for a stopped free response 2 kernel widths before the
  // ridge's end (the ridge strays 1-2 widths after the stop, when the longer kernels of the lower rows
  // hold more of the response than the mode's row).
  const std::size_t seg0 = fr.o + n_ml_margin_;
  std::size_t seg_end = fr.n;
  if (track.ended) {
    const auto back = static_cast<std::size_t>(std::ceil(2.0 * fr.kernel_s * fs_));
    const std::size_t stop = track.end_col * cwt_->decimation() * in_dec_;
    seg_end = std::min(fr.n, stop > back ? stop - back : 0);
  }
  if (method_ != dsp::DampingMethod::ml || seg0 >= seg_end) return ml;
  // At half rate: copy samples m from the first at or after seg0 (2m >= seg0; its first tap is at
  // most one sample, 20 us at 51.2 kHz, before the margin's end) to the last whose taps lie in the
  // window (2m + 1 < seg_end): m0 = ceil(seg0 / 2), m_end = floor(seg_end / 2). The segment's sample
  // m is at t = 2m / fs like x[2m].
  std::size_t a0 = seg0, a_end = seg_end;
  if (in_dec_ == 2) {
    a0 = (seg0 + 1) / 2;
    a_end = seg_end / 2;
  }
  const std::size_t len = ml_->segment_length(a0, a_end);
  if (len == 0) return ml;
  const double z = env.rls.zeta;
  const double zeta0 = (std::isfinite(z) && z > 1e-4 && z < 0.5) ? z : 0.02;
  if (in_dec_ == 1)  // the fitter works in double: widen the segment (exact)
    for (std::size_t i = 0; i < len; ++i) xd_[a0 + i] = static_cast<double>(fr.x[a0 + i]);
  const MlStep::Outcome out = ml_->fit(std::span<const double>(xd_).subspan(a0, len), a0, env.f_d, zeta0);
  const double snr_db = env.rls.snr_db;
  if (out.resid_var < fr.noise_var) snr_status_db = snr_db + 10.0 * std::log10(fr.noise_var / out.resid_var);
  if (out.fitted) {
    ml = out.estimate;
    ml.snr_db = snr_db;
    if (out.unresolved_line && ml.status == dsp::EstimateStatus::ok) ml.status = dsp::EstimateStatus::inconsistent;
  }
  return ml;
}

namespace {

// What the status rule reads besides the selected estimate.
struct StatusInputs {
  const ImpactWindow* window = nullptr;
  double t_avail_s = 0;         // usable time after the onset, s
  double f_d = NAN;             // damped frequency, Hz
  double zeta_fallback = NAN;   // ridge-LS zeta (when the selected estimate has none)
  bool ridge_lost = false, ridge_ended = false;
  dsp::EstimateStatus envelope_window = dsp::EstimateStatus::ok;
  double snr_status_db = NAN, min_snr_db = 20, max_ci_ratio = 1.25;
};

// The event's values from the selected estimate, and the computed status (before the data problems,
// which ImpactAnalyzer::analyze applies).
ImpactStatus report(ImpactEvent& ev, const dsp::DampingEstimate& sel, const StatusInputs& in) {
  ev.f_hz = sel.f_hz;
  ev.zeta = sel.zeta;
  ev.zeta_ci95_lo = sel.zeta_ci95_lo;
  ev.zeta_ci95_hi = sel.zeta_ci95_hi;
  // An interval is only reported when it is one: finite, 0 <= lo <= zeta <= hi < 1 (a damping ratio
  // of 1 is critical damping, no free oscillation); otherwise both bounds are null. An estimate whose
  // interval spans more than a factor 10 (hi > 10 lo, e.g. [0, 1046] or [1e18, 1e23] from a fit that
  // saw almost no decay) does not determine zeta: not ok (fit_failed) whatever the estimator said.
  const bool interval_valid = std::isfinite(ev.zeta) && std::isfinite(ev.zeta_ci95_lo) &&
                              std::isfinite(ev.zeta_ci95_hi) && ev.zeta_ci95_lo >= 0.0 &&
                              ev.zeta_ci95_lo <= ev.zeta && ev.zeta <= ev.zeta_ci95_hi && ev.zeta_ci95_hi < 1.0;
  if (!interval_valid) ev.zeta_ci95_lo = ev.zeta_ci95_hi = NAN;
  const bool interval_tight = interval_valid && ev.zeta_ci95_hi <= 10.0 * ev.zeta_ci95_lo;
  // ok also promises precision: an interval wider than max_ci_ratio (hi / lo, default 1.25, i.e. about
  // +-11 %) is low_snr. Lines and noise in the band widen it; on the 51.2 kHz nuisance records of
  // test_pipeline_indep the estimates with wider intervals were off by up to 29 %, those within it by
  // at most 7.7 % (3 seeds, 861 impacts).
  const bool interval_precise = interval_valid && ev.zeta_ci95_hi <= in.max_ci_ratio * ev.zeta_ci95_lo;
  if (!(std::isfinite(ev.zeta) && ev.zeta > 0.0 && ev.zeta < 1.0)) ev.zeta = NAN;
  ev.amplitude = sel.amplitude;
  ev.window_s = sel.window_end_s - sel.window_start_s;

  // A window cut by the next impact matters only when the cut removes a noticeable part of the decay:
  // more than 5 % of its energy, exp(-2 sigma T) > 0.05 (T = usable time after the onset).
  ImpactStatus computed = from_estimate(sel.status);
  if (computed == ImpactStatus::ok && !interval_tight) computed = ImpactStatus::fit_failed;
  if (in.window->end == WindowEnd::next_impact) {
    const double z = std::isfinite(sel.zeta) ? sel.zeta : in.zeta_fallback;
    const double sigma = std::isfinite(z) && z > 0 && z < 1 ? z * kTwoPi * in.f_d / std::sqrt(1.0 - z * z) : NAN;
    if (!(std::exp(-2.0 * sigma * in.t_avail_s) <= 0.05)) computed = ImpactStatus::window_cut;
  }
  if (computed == ImpactStatus::window_cut) return computed;
  if (in.ridge_lost) return ImpactStatus::ridge_lost;
  // The free response stopped so early that no envelope window is left between the edge skips: the
  // values are the equivalent viscous estimate over the short segment, not a trusted one.
  if (in.ridge_ended && in.envelope_window == dsp::EstimateStatus::too_short) return ImpactStatus::too_short;
  if (!(in.snr_status_db >= in.min_snr_db) || in.envelope_window == dsp::EstimateStatus::low_snr)
    return ImpactStatus::low_snr;
  if (computed == ImpactStatus::ok && !interval_precise) return ImpactStatus::low_snr;
  return computed;
}

}  // namespace

ImpactEvent ImpactAnalyzer::analyze(const ImpactWindow& win) {
  prepare();
  ImpactEvent ev;
  ev.sample_index = win.onset_index;
  ev.t_s = static_cast<double>(win.onset_index) / fs_;
  Frame fr;
  fr.x = win.samples;
  fr.n = std::min(fr.x.size(), max_samples());
  fr.n_a = (fr.n + in_dec_ - 1) / in_dec_;
  fr.o = win.onset_offset;
  fr.onset_s = static_cast<double>(fr.o) / fs_;

  // 0. Peak and clipping (and at half rate the copy).
  const double peak = window_peak(fr);
  const bool clipped = !std::isnan(clip_) && peak >= clip_;  // NaN: no clip level (float data)
  const double peak_sq = peak * peak;
  auto finish = [&](ImpactStatus computed) {
    // Data problems first: they explain any estimate failure.
    if (win.spike) ev.status = ImpactStatus::spike;
    else if (clipped) ev.status = ImpactStatus::clipped;
    else if (win.end == WindowEnd::gap) ev.status = ImpactStatus::window_cut;
    else ev.status = computed;
    return ev;
  };
  fr.kernel_s = dsp::MorletCwt<double>::kernel_time_sd_s(eta0_, f_expected_);
  const bool whole = win.end == WindowEnd::complete || win.end == WindowEnd::decayed;
  // Room for the edge skips of both ends plus two kernel widths of decay (the foundation's minimum).
  if (fr.o >= fr.n || static_cast<double>(fr.n - fr.o) / fs_ < 10.0 * fr.kernel_s)
    return finish(whole ? ImpactStatus::too_short : ImpactStatus::window_cut);

  // Noise: floored at 1e-12 of the peak power (float32 rounding is ~1e-14), so noise-free data give
  // a finite SNR of at most 120 dB instead of a division by zero.
  fr.noise_var = win.noise_var;
  // Decays that overlap: the innovation's floor, without the previous ringing, when the window after
  // the onset resolves the fit band into 9 bins (header comment, "Noise").
  const double after_onset_s = static_cast<double>(fr.n - std::min(fr.n, fr.o)) / fs_;
  if (win.innovation_noise_var > 0 && win.innovation_noise_var < fr.noise_var &&
      after_onset_s * 2.0 * ml_band_rel_ * f_expected_ >= kFloorBins)
    fr.noise_var = win.innovation_noise_var;
  if (!(fr.noise_var > 1e-12 * peak_sq)) fr.noise_var = 1e-12 * peak_sq;
  if (!(fr.noise_var > 0)) return finish(ImpactStatus::low_snr);  // all zero

  // 1. CWT rows over the band (at half rate on the copy y[m] ~ x[2m]: column c stays at t = c dt).
  cwt_->load(in_dec_ == 2 ? std::span<const float>(xf_.data(), fr.n_a) : fr.x.first(fr.n));
  fr.cols = cwt_->columns();
  fr.dt = cwt_->time_step_s();
  // 2. Ridge search window (checked before any power is computed: a too-short window needs none),
  // then the ridge.
  const auto onset_col = static_cast<std::size_t>(std::ceil(fr.onset_s / fr.dt));
  const auto edge_cols = static_cast<std::size_t>(std::ceil(4.0 * fr.kernel_s / fr.dt));
  const std::size_t last_col = fr.cols > edge_cols ? fr.cols - edge_cols : 0;
  if (onset_col + 3 > last_col) return finish(whole ? ImpactStatus::too_short : ImpactStatus::window_cut);
  const RidgeTrack track = track_ridge(fr, onset_col, last_col);

  // 3. Frequency and the envelope estimators.
  const Envelope env = envelope_estimates(fr, track);
  // 4. Maximum likelihood. The SNR the status rule compares with min_snr_db: the ridge's, or, when the
  // ML fit modelled a steady line, the same ridge power against the fit's residual noise where that is
  // lower (the noise floor from the gaps between impacts holds the line's power, which the fit explained).
  double snr_status_db = env.rls.snr_db;
  dsp::DampingEstimate ml = ml_estimate(fr, track, env, snr_status_db);
  // 5. Cross-check (core/dsp/cross_check.hpp, the analyzer's rule).
  if (ml.status == dsp::EstimateStatus::ok && env.rls.status == dsp::EstimateStatus::ok &&
      !dsp::estimates_agree(ml, env.rls, dsp::kAnalyzerRule))
    ml.status = dsp::EstimateStatus::inconsistent;
  const dsp::DampingEstimate& sel =
      method_ == dsp::DampingMethod::ml ? ml : (method_ == dsp::DampingMethod::ridge_ls ? env.rls : env.two);

  ev.f_sd_hz = std::isfinite(sel.f_sd_hz) ? sel.f_sd_hz : env.f_sd;
  ev.snr_db = env.rls.snr_db;
  StatusInputs in;
  in.window = &win;
  in.t_avail_s = static_cast<double>(fr.n - fr.o) / fs_;
  in.f_d = env.f_d;
  in.zeta_fallback = env.rls.zeta;
  in.ridge_lost = track.lost || env.lost;
  in.ridge_ended = track.ended;
  in.envelope_window = env.window.status;
  in.snr_status_db = snr_status_db;
  in.min_snr_db = min_snr_db_;
  in.max_ci_ratio = max_ci_ratio_;
  return finish(report(ev, sel, in));
}

}  // namespace ridgewatch::pipeline
