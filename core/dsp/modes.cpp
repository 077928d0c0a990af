#include "core/dsp/modes.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

#include "core/dsp/ml_fit.hpp"
#include "core/dsp/morlet_cwt.hpp"

namespace ridgewatch::dsp {

namespace {

struct Peak {
  std::size_t row = 0;
  double f_hz = 0.0;
  double level = 0.0;  // profile value (noise-floor units)
};

// Local maxima of the noise-normalised energy profile that stand above the floor and are not just a
// ripple on a neighbour's flank (at least 3 dB above the lowest point within half an octave).
std::vector<Peak> find_peaks(const std::vector<double>& profile, const std::vector<double>& freqs,
                             double floor_level, double min_ratio, std::size_t half_octave) {
  std::vector<Peak> peaks;
  for (std::size_t r = 1; r + 1 < profile.size(); ++r) {
    if (!(profile[r] > profile[r - 1] && profile[r] >= profile[r + 1])) continue;
    if (profile[r] < floor_level * min_ratio) continue;
    const std::size_t lo = r > half_octave ? r - half_octave : 0;
    const std::size_t hi = std::min(profile.size() - 1, r + half_octave);
    const double left_min = *std::min_element(profile.begin() + static_cast<std::ptrdiff_t>(lo),
                                              profile.begin() + static_cast<std::ptrdiff_t>(r));
    const double right_min = *std::min_element(profile.begin() + static_cast<std::ptrdiff_t>(r + 1),
                                               profile.begin() + static_cast<std::ptrdiff_t>(hi + 1));
    if (profile[r] < 2.0 * std::max(left_min, right_min)) continue;
    // Sub-bin position: parabola through (ln f, ln profile) at r-1, r, r+1.
    const double y0 = std::log(profile[r - 1]), y1 = std::log(profile[r]), y2 = std::log(profile[r + 1]);
    const double denom = y0 - 2.0 * y1 + y2;
    double offset = denom < 0 ? 0.5 * (y0 - y2) / denom : 0.0;
    offset = std::clamp(offset, -0.5, 0.5);
    const double lf0 = std::log(freqs[r - 1]), lf1 = std::log(freqs[r]), lf2 = std::log(freqs[r + 1]);
    const double step = offset < 0 ? lf1 - lf0 : lf2 - lf1;
    peaks.push_back({r, std::exp(lf1 + offset * step), profile[r]});
  }
  return peaks;
}

}  // namespace

ModeSearchResult identify_modes(std::span<const double> signal, double fs, const ModeSearchOptions& opt) {
  const std::size_t n = signal.size();
  if (n < 64) throw std::invalid_argument("signal too short for mode identification (" + std::to_string(n) + " samples, need >= 64)");
  if (!(fs > 0) || !std::isfinite(fs)) throw std::invalid_argument("sample rate must be > 0");
  if (opt.max_modes < 1) throw std::invalid_argument("max_modes must be >= 1");
  if (opt.voices_per_octave < 4 || opt.voices_per_octave > 256)
    throw std::invalid_argument("voices_per_octave must be in [4, 256]");
  const double duration_s = static_cast<double>(n) / fs;

  ModeSearchResult result;
  // Lowest useful frequency: the kernel (time sd s = eta0 / (2 pi f)) must leave room for the edge
  // skips at both ends plus a window, i.e. 16 s <= record length.
  const double f_auto_min = std::max(20.0, 16.0 * opt.eta0 / (2.0 * std::numbers::pi * duration_s));
  result.f_min_hz = opt.f_min_hz > 0 ? opt.f_min_hz : f_auto_min;
  result.f_max_hz = opt.f_max_hz > 0 ? opt.f_max_hz : 0.45 * fs;
  if (!(result.f_max_hz < fs / 2))
    throw std::invalid_argument("f_max " + std::to_string(result.f_max_hz) + " Hz must be below half the sample rate (" + std::to_string(fs / 2) + " Hz)");
  if (!(result.f_min_hz < result.f_max_hz))
    throw std::invalid_argument("f_min " + std::to_string(result.f_min_hz) + " Hz must be below f_max " + std::to_string(result.f_max_hz) + " Hz");

  // Onset: given, or the first sample reaching half the peak magnitude.
  if (opt.onset_s >= 0) {
    result.onset_s = opt.onset_s;
  } else {
    double peak = 0.0;
    for (double v : signal) peak = std::max(peak, std::abs(v));
    std::size_t i = 0;
    while (i < n && std::abs(signal[i]) < 0.5 * peak) ++i;
    result.onset_s = static_cast<double>(std::min(i, n - 1)) / fs;
  }
  const auto n0 = static_cast<std::size_t>(std::llround(result.onset_s * fs));
  if (n0 + 32 >= n) throw std::invalid_argument("onset leaves fewer than 32 samples to analyse");

  const double octaves = std::log2(result.f_max_hz / result.f_min_hz);
  const auto rows = std::max<std::size_t>(3, static_cast<std::size_t>(std::ceil(octaves * static_cast<double>(opt.voices_per_octave))) + 1);
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = opt.eta0;
  cfg.frequencies_hz = make_frequency_grid(result.f_min_hz, result.f_max_hz, rows, GridSpacing::log);
  cfg.max_samples = n;
  MorletCwt<double> cwt(cfg);
  cwt.load(signal);
  std::vector<std::complex<double>> w(cwt.columns());

  // Energy profile in noise-floor units: sum_t |W|^2 / (white-noise gain of the row).
  std::vector<double> profile(rows);
  for (std::size_t r = 0; r < rows; ++r) {
    cwt.row(cfg.frequencies_hz[r], w);
    double e = 0.0;
    for (const auto& v : w) e += std::norm(v);
    profile[r] = e / cwt.noise_gain(cfg.frequencies_hz[r]);
  }
  // Noise floor: white noise gives the same profile value N sigma^2 in every row; modes and their
  // Gaussian skirts only raise rows. The 20 % quantile is a floor estimate that tolerates modes
  // covering most of the band.
  std::vector<double> sorted = profile;
  const std::size_t q = rows / 5;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(q), sorted.end());
  const double floor_level = sorted[q];
  std::vector<Peak> peaks = find_peaks(profile, cfg.frequencies_hz, floor_level,
                                       std::pow(10.0, opt.min_peak_snr_db / 10.0),
                                       std::max<std::size_t>(1, opt.voices_per_octave / 2));
  std::sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) { return a.level > b.level; });
  if (peaks.size() > opt.max_modes) peaks.resize(opt.max_modes);
  std::sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) { return a.f_hz < b.f_hz; });

  // Noise power of a row: the lower quartile of its own |W|^2 (right for coloured noise when the
  // mode has decayed into the noise for a quarter of the record), capped by the white-noise level
  // implied by the profile floor (right when the mode outlasts the record, e.g. noise-free data or
  // very light damping). floor_level = n sigma^2 for white noise.
  const double white_var = floor_level / static_cast<double>(w.size());
  const auto edge_cols = static_cast<std::size_t>(
      std::ceil(opt.envelope.edge_widths * MorletCwt<double>::kernel_time_sd_s(opt.eta0, result.f_min_hz) / cwt.time_step_s()));
  auto row_noise = [&](double f_hz) {
    const std::size_t lo = std::min(edge_cols, w.size());
    const std::size_t hi = w.size() > edge_cols ? w.size() - edge_cols : 0;
    const double own = hi > lo + 8 ? estimate_row_noise_power(std::span<const std::complex<double>>(w).subspan(lo, hi - lo))
                                   : estimate_row_noise_power(w);
    return std::min(own, white_var * cwt.noise_gain(f_hz));
  };
  EnvelopeOptions env = opt.envelope;
  env.onset_s = result.onset_s;
  std::vector<ModeGuess> guesses;
  double latest_end_s = result.onset_s;
  for (const Peak& pk : peaks) {
    IdentifiedMode mode;
    EnvelopeRow row{w, cwt.time_step_s(), pk.f_hz, opt.eta0, NAN};
    cwt.row(pk.f_hz, w);
    row.noise_power = row_noise(pk.f_hz);
    EnvelopeWindow win = choose_window(row, env);
    double f_sd = NAN;
    double f_d = phase_slope_frequency(row, win, f_sd);
    if (!std::isfinite(f_d) || f_d <= result.f_min_hz * 0.5 || f_d >= fs / 2) f_d = pk.f_hz;
    // Envelope at the damped frequency itself (Eq. 12 at omega = omega_d).
    row.f_row_hz = f_d;
    cwt.row(f_d, w);
    row.noise_power = row_noise(f_d);
    win = choose_window(row, env);
    mode.two_point = estimate_two_point(row, win, f_d);
    mode.ridge_ls = estimate_ridge_ls(row, win, f_d);
    mode.ridge_ls.f_sd_hz = f_sd;
    mode.two_point.f_sd_hz = f_sd;
    // A peak whose envelope gives no decay estimate at all is not a free-response mode (noise bump,
    // hum, the skirt of the record edge): leave it out of the joint fit and the report.
    if (!std::isfinite(mode.ridge_ls.zeta)) continue;
    if (std::isfinite(mode.ridge_ls.window_end_s)) latest_end_s = std::max(latest_end_s, mode.ridge_ls.window_end_s);
    const double zeta0 = (std::isfinite(mode.ridge_ls.zeta) && mode.ridge_ls.zeta > 0 && mode.ridge_ls.zeta < 0.5)
                             ? mode.ridge_ls.zeta
                             : 0.01;
    guesses.push_back({f_d, zeta0});
    result.modes.push_back(mode);
  }

  if (!guesses.empty()) {
    // The fit covers the decay and as much again (noise-only samples add little information but
    // cost time on long records).
    std::size_t n_end = n;
    const double span_s = std::max(latest_end_s - result.onset_s, 0.0);
    const auto capped = n0 + static_cast<std::size_t>(std::ceil(3.0 * span_s * fs)) + 256;
    if (n - n0 > (std::size_t{1} << 17)) n_end = std::min(n, capped);
    SpectralModeFitter fitter(n_end - n0, fs);
    MlFitOptions ml_opt;
    ml_opt.f_lo_hz = result.f_min_hz;
    ml_opt.f_hi_hz = result.f_max_hz;
    const MlFitResult ml = fitter.fit(signal.subspan(n0, n_end - n0), guesses, ml_opt);
    result.noise_sd = ml.noise_sd;
    for (std::size_t i = 0; i < result.modes.size(); ++i) {
      DampingEstimate e = ml.modes[i];
      e.window_start_s += result.onset_s;
      e.window_end_s += result.onset_s;
      e.snr_db = result.modes[i].ridge_ls.snr_db;
      result.modes[i].ml = e;
    }
  }
  for (IdentifiedMode& m : result.modes) {
    // Cross-check: the envelope fit and the time-series fit see the same mode through different
    // statistics. Where both claim to be fine but differ by more than 4 combined standard
    // uncertainties (in ln zeta or in f), the damped-sinusoid model does not hold there.
    DampingEstimate& a = m.ml;
    DampingEstimate& b = m.ridge_ls;
    if (a.status == EstimateStatus::ok && b.status == EstimateStatus::ok) {
      // A 1 % (zeta) and 1e-4 (f) allowance covers the envelope method's own small deterministic
    // biases (interference of neighbouring modes), which matter only when noise is negligible.
    const double z_zeta_tol = std::abs(std::log(a.zeta / b.zeta)) /
                              std::hypot(std::hypot(a.zeta_sd / a.zeta, b.zeta_sd / b.zeta), 0.01);
    const double z_f_tol = std::abs(a.f_hz - b.f_hz) /
                           std::hypot(std::hypot(a.f_sd_hz, b.f_sd_hz), 1e-4 * a.f_hz);
    if (!(z_zeta_tol <= 4.0) || !(z_f_tol <= 4.0)) a.status = b.status = EstimateStatus::inconsistent;
    }
    switch (opt.method) {
      case DampingMethod::two_point: m.selected = m.two_point; break;
      case DampingMethod::ridge_ls: m.selected = m.ridge_ls; break;
      case DampingMethod::ml: m.selected = m.ml; break;
    }
  }
  return result;
}

}  // namespace ridgewatch::dsp
