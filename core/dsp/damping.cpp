#include "core/dsp/damping.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "core/dsp/kernels/lag_correlation.hpp"
#include "core/dsp/kernels/phase_advance.hpp"

namespace ridgewatch::dsp {

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
constexpr double kZ95 = 1.959963984540054;  // two-sided 95 % normal quantile

double kernel_sd_s(const EnvelopeRow& row) { return row.eta0 / (kTwoPi * row.f_row_hz); }

double debiased_power(double p, double noise) {
  // E|W|^2 = |W_signal|^2 + noise: subtract the noise, floor at a quarter of the raw power.
  return std::max(p - noise, 0.25 * p);
}

// Weighted straight-line fit y = a + b t with a sandwich covariance for errors whose correlation is
// rho(dt) = exp(-dt^2 / (4 s^2)) and whose variances are 1 / w. Points are taken every `stride`
// columns; the correlation makes denser sampling add almost nothing.
//
// The weights are those of both estimators, w = 2 (|W|^2 - noise)_+ / noise: the inverse variance of
// ln|W| and of arg W, noise / (2 |W|^2). They, the bread sums and the meat depend on the row's samples
// at the points, the noise, the column grid and the kernel width only, not on the fitted values: the
// caller computes them once (envelope_fit_weights) and passes them to every fit on that row and window
// with that stride (the analyzer: the phase slope and the ridge LS on one row). The values come from
// fill_values(y, power, count), which writes y[i] for the point i from the row (power[i]: its debiased
// |W|^2).
struct LineFit {
  double intercept = NAN, slope = NAN, slope_sd = NAN;
  std::size_t points = 0;
};

// Sandwich standard uncertainty of the slope from the weights and times in `fw` (s0, s1 and
// det = s0 s2 - s1^2 > 0: the bread).
double sandwich_slope_sd(const EnvelopeFitWeights& fw, double dt, double kernel_sd, double det,
                         EnvelopeWorkspace& ws) {
  const std::size_t count = fw.count, stride = fw.stride;
  const double s0 = fw.s0, s1 = fw.s1;
  // Meat of the sandwich: sum_ij x_i x_j^T sqrt(w_i w_j) rho_ij, over pairs within 6 correlation
  // lengths (rho < 1e-15 beyond).
  const double corr_len = 2.0 * kernel_sd;
  const double lag_step = dt * static_cast<double>(stride) / corr_len;
  const auto reach = std::min<std::size_t>(
      count - 1, static_cast<std::size_t>(std::ceil(6.0 / lag_step)));
  // rho_k = exp(-(k lag_step)^2) by the recurrence rho_{k+1} = rho_k q_k, q_k = exp(-(2k+1) lag_step^2),
  // q_{k+1} = q_k exp(-2 lag_step^2): two exponentials per fit instead of one per lag (relative
  // rounding ~k eps, k <= reach ~ 30: far below what a standard uncertainty needs).
  ws.correlation.resize(reach + 1);
  {
    const double l2 = lag_step * lag_step;
    const double q_step = std::exp(-2.0 * l2);
    double r = 1.0, q = std::exp(-l2);
    for (std::size_t k = 0; k <= reach; ++k) {
      // symmetric pairs (i, j) and (j, i) count twice: x_i x_j^T + x_j x_i^T
      ws.correlation[k] = r * (k == 0 ? 1.0 : 2.0);
      r *= q;
      q *= q_step;
    }
  }
  // The slope's variance is row 2 of the bread times the meat times bread column 2: with the bread
  // (X^T W X)^-1 = [s2 -s1; -s1 s0] / det, it is sum_ij rho_ij z_i z_j / det^2 for
  // z_i = sqrt(w_i) (s0 t_i - s1), the slope's influence of point i. Lag by lag, the pairs (i, i + k)
  // contribute rho_k sum_i z_i z_{i+k}: one correlation per lag (kernels::lag_correlation_sum). The
  // meat's three correlations with [1, t, t^2] and their combination with the bread cancelled:
  // against a long double evaluation this is within 7e-16, they were within 1.1e-14
  // (tests/test_damping.cpp).
  const double* u = fw.root_weight.data();
  const double* tt = fw.time.data();
  ws.value.resize(count);  // scratch here: the values are filled after the weights
  double* z = ws.value.data();
  for (std::size_t i = 0; i < count; ++i) z[i] = u[i] * (s0 * tt[i] - s1);
  const double sum = kernels::lag_correlation_sum(z, count, ws.correlation.data(), reach);
  const double var = sum / det / det;  // (det^2 would overflow for weights beyond ~1e75)
  return std::sqrt(std::max(var, 0.0));
}

template <typename ValueFn>
LineFit weighted_line_fit(const EnvelopeRow& row, std::size_t begin, std::size_t end, std::size_t stride,
                          const EnvelopeFitWeights& fw, ValueFn fill_values, EnvelopeWorkspace& ws) {
  LineFit fit;
  if (end <= begin) return fit;
  const std::size_t count = (end - begin + stride - 1) / stride;
  if (fw.begin != begin || fw.stride != stride || fw.count != count)
    throw std::invalid_argument("envelope line fit: the weights were computed for another window or stride");
  ws.value.resize(count);
  fill_values(ws.value.data(), fw.power.data(), count);
  const double* y = ws.value.data();
  const double* wt = fw.weight.data();
  const double* tt = fw.time.data();
  double sy = 0, sty = 0;
  for (std::size_t i = 0; i < count; ++i) {
    sy += wt[i] * y[i];
    sty += wt[i] * tt[i] * y[i];
  }
  fit.points = count;
  const double s0 = fw.s0, s1 = fw.s1, s2 = fw.s2;
  const double det = s0 * s2 - s1 * s1;
  if (fit.points < 3 || !(det > 0)) return fit;
  const double t_ref = static_cast<double>(begin) * row.time_step_s;
  fit.slope = (s0 * sty - s1 * sy) / det;
  fit.intercept = (s2 * sy - s1 * sty) / det - fit.slope * t_ref;
  fit.slope_sd = fw.slope_sd;
  return fit;
}

DampingEstimate base_estimate(DampingMethod method, const EnvelopeRow& row, const EnvelopeWindow& win) {
  DampingEstimate e;
  e.method = method;
  e.window_start_s = static_cast<double>(win.start) * row.time_step_s;
  e.window_end_s = static_cast<double>(win.end) * row.time_step_s;
  if (win.peak < row.w.size() && win.noise_power > 0)
    e.snr_db = 10.0 * std::log10(std::norm(row.w[win.peak]) / win.noise_power);
  if (win.start < row.w.size()) e.amplitude = std::abs(row.w[win.start]);
  e.status = win.status;
  return e;
}

void set_zeta_interval(DampingEstimate& e) {
  // Log-normal interval: zeta > 0 always, symmetric in ln zeta (first-order equal to zeta +- 1.96 sd).
  const double rel = e.zeta_sd / e.zeta;
  e.zeta_ci95_lo = e.zeta * std::exp(-kZ95 * rel);
  e.zeta_ci95_hi = e.zeta * std::exp(kZ95 * rel);
}

}  // namespace

std::string_view to_string(DampingMethod method) {
  switch (method) {
    case DampingMethod::two_point: return "two-point";
    case DampingMethod::ridge_ls: return "ridge-ls";
    case DampingMethod::ml: return "ml";
  }
  return "?";
}

bool parse_damping_method(std::string_view text, DampingMethod& method) {
  for (DampingMethod m : {DampingMethod::two_point, DampingMethod::ridge_ls, DampingMethod::ml}) {
    if (text == to_string(m)) {
      method = m;
      return true;
    }
  }
  return false;
}

std::string_view to_string(EstimateStatus status) {
  switch (status) {
    case EstimateStatus::ok: return "ok";
    case EstimateStatus::too_short: return "too_short";
    case EstimateStatus::low_snr: return "low_snr";
    case EstimateStatus::not_decaying: return "not_decaying";
    case EstimateStatus::fit_failed: return "fit_failed";
    case EstimateStatus::inconsistent: return "inconsistent";
  }
  return "?";
}

void EnvelopeWorkspace::reserve(std::size_t columns, std::size_t reach) {
  value.reserve(columns);
  correlation.reserve(std::min(columns, reach) + 1);
}

void EnvelopeFitWeights::reserve(std::size_t columns) {
  power.reserve(columns);
  weight.reserve(columns);
  root_weight.reserve(columns);
  time.reserve(columns);
}

std::size_t ridge_ls_stride(const EnvelopeRow& row) {
  // About 8 points per kernel width: the samples are correlated over ~2 s anyway.
  const double per = kernel_sd_s(row) / (8.0 * row.time_step_s);
  return std::max<std::size_t>(1, static_cast<std::size_t>(per));
}

void envelope_fit_weights(const EnvelopeRow& row, const EnvelopeWindow& win, std::size_t stride,
                          EnvelopeFitWeights& fw, EnvelopeWorkspace& ws) {
  const std::size_t begin = win.start;
  const std::size_t count = win.end > begin ? (win.end - begin + stride - 1) / stride : 0;
  const double noise = win.noise_power, dt = row.time_step_s;
  fw.begin = begin;
  fw.stride = stride;
  fw.count = count;
  fw.power.resize(count);
  fw.weight.resize(count);
  fw.root_weight.resize(count);
  fw.time.resize(count);
  double s0 = 0, s1 = 0, s2 = 0;
  const double t_ref = static_cast<double>(begin) * dt;  // centre times for conditioning
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t c = begin + i * stride;
    const double t = static_cast<double>(c) * dt - t_ref;
    const double p = debiased_power(std::norm(row.w[c]), noise);
    const double w = 2.0 * p / noise;
    fw.power[i] = p;
    fw.weight[i] = w;
    fw.root_weight[i] = std::sqrt(w);
    fw.time[i] = t;
    s0 += w;
    s1 += w * t;
    s2 += w * t * t;
  }
  fw.s0 = s0;
  fw.s1 = s1;
  fw.s2 = s2;
  fw.slope_sd = NAN;
  const double det = s0 * s2 - s1 * s1;
  if (count >= 3 && det > 0) fw.slope_sd = sandwich_slope_sd(fw, dt, kernel_sd_s(row), det, ws);
}

double estimate_row_noise_power(std::span<const std::complex<double>> w) {
  if (w.empty()) return NAN;
  std::vector<double> p(w.size());
  for (std::size_t i = 0; i < w.size(); ++i) p[i] = std::norm(w[i]);
  const std::size_t q = p.size() / 4;
  std::nth_element(p.begin(), p.begin() + static_cast<std::ptrdiff_t>(q), p.end());
  return p[q] / std::log(4.0 / 3.0);
}

EnvelopeWindow choose_window(const EnvelopeRow& row, const EnvelopeOptions& options) {
  EnvelopeWindow win;
  const std::size_t n = row.w.size();
  const double dt = row.time_step_s;
  const double s = kernel_sd_s(row);
  const auto edge = static_cast<std::size_t>(std::ceil(options.edge_widths * s / dt));
  const auto onset = static_cast<std::size_t>(std::max(0.0, std::round(options.onset_s / dt)));
  win.noise_power = row.noise_power;
  if (!(win.noise_power > 0)) {
    // Noise from the part of the row away from the record edges.
    const std::size_t lo = std::min(edge, n), hi = n > edge ? n - edge : 0;
    win.noise_power = hi > lo + 8 ? estimate_row_noise_power(row.w.subspan(lo, hi - lo))
                                  : estimate_row_noise_power(row.w);
  }
  if (n < 2 * edge + 3 || onset >= n - edge) {
    win.status = EstimateStatus::too_short;
    return win;
  }
  const std::size_t last = n - edge;  // exclusive
  // First maximum of |W|^2 from the onset on. The running maximum is kept as a value (recomputing the
  // norm at the running peak would make each column wait for the previous one's select and norm).
  win.peak = onset;
  double peak_power = std::norm(row.w[onset]);
  for (std::size_t c = onset; c < last; ++c) {
    const double p = std::norm(row.w[c]);
    if (p > peak_power) {
      peak_power = p;
      win.peak = c;
    }
  }
  const auto after_peak = static_cast<std::size_t>(std::ceil(2.0 * s / dt));
  win.start = std::max(onset + edge, win.peak + after_peak);
  if (win.start >= last) {
    win.status = EstimateStatus::too_short;
    win.end = win.start;
    return win;
  }
  const double threshold = options.end_snr * win.noise_power;
  win.end = win.start;
  while (win.end < last && std::norm(row.w[win.end]) >= threshold) ++win.end;
  if (peak_power < 4.0 * threshold) {
    win.status = EstimateStatus::low_snr;
  } else if (static_cast<double>(win.end - win.start) * dt < options.min_window_widths * s) {
    win.status = EstimateStatus::too_short;
  }
  return win;
}

double phase_angle(std::complex<double> z) { return kernels::phase_angle(z); }

double phase_slope_frequency(const EnvelopeRow& row, const EnvelopeWindow& win, double& sd_hz) {
  EnvelopeWorkspace ws;
  EnvelopeFitWeights fw;
  if (win.end > win.start + 2) envelope_fit_weights(row, win, kPhaseSlopeStride, fw, ws);
  return phase_slope_frequency(row, win, sd_hz, fw, ws);
}

double phase_slope_frequency(const EnvelopeRow& row, const EnvelopeWindow& win, double& sd_hz,
                             const EnvelopeFitWeights& weights, EnvelopeWorkspace& ws) {
  sd_hz = NAN;
  if (win.end <= win.start + 2) return NAN;
  // Unwrapped phase relative to the window start, accumulated column by column.
  const double advance = kTwoPi * row.phase_reference_hz * row.time_step_s;  // 0 unless decimated
  const std::complex<double> derotate = std::polar(1.0, -advance);
  const LineFit fit = weighted_line_fit(
      row, win.start, win.end, kPhaseSlopeStride, weights,
      [&](double* y, const double*, std::size_t count) {
        // The advances into y[1..count), then their running sum.
        kernels::phase_advances(row.w.data() + win.start, count, derotate, advance, y);
        double acc = 0.0;
        y[0] = acc;
        for (std::size_t i = 1; i < count; ++i) {
          acc += y[i];
          y[i] = acc;
        }
      },
      ws);
  sd_hz = fit.slope_sd / kTwoPi;
  return fit.slope / kTwoPi;
}

DampingEstimate estimate_ridge_ls(const EnvelopeRow& row, const EnvelopeWindow& win, double f_d_hz) {
  EnvelopeWorkspace ws;
  EnvelopeFitWeights fw;
  if (win.end > win.start + 2) envelope_fit_weights(row, win, ridge_ls_stride(row), fw, ws);
  return estimate_ridge_ls(row, win, f_d_hz, fw, ws);
}

DampingEstimate estimate_ridge_ls(const EnvelopeRow& row, const EnvelopeWindow& win, double f_d_hz,
                                  const EnvelopeFitWeights& weights, EnvelopeWorkspace& ws) {
  DampingEstimate e = base_estimate(DampingMethod::ridge_ls, row, win);
  e.f_hz = f_d_hz;
  if (win.end <= win.start + 2) {
    if (e.status == EstimateStatus::ok) e.status = EstimateStatus::too_short;
    return e;
  }
  const LineFit fit = weighted_line_fit(
      row, win.start, win.end, ridge_ls_stride(row), weights,
      [](double* y, const double* power, std::size_t count) {
        for (std::size_t i = 0; i < count; ++i) y[i] = 0.5 * std::log(power[i]);
      },
      ws);
  e.points = fit.points;
  if (!std::isfinite(fit.slope)) {
    e.status = EstimateStatus::too_short;
    return e;
  }
  const double sigma = -fit.slope;
  if (!(sigma > 0)) {
    e.status = EstimateStatus::not_decaying;
    return e;
  }
  const double omega_d = kTwoPi * f_d_hz;
  e.zeta = zeta_from_decay(sigma, omega_d);
  // d zeta / d sigma = omega_d^2 / (omega_d^2 + sigma^2)^(3/2)
  const double dz = omega_d * omega_d / std::pow(omega_d * omega_d + sigma * sigma, 1.5);
  e.zeta_sd = dz * fit.slope_sd;
  set_zeta_interval(e);
  // Eq. (12) neglects the decay inside the kernel: for A exp(-sigma t) exp(i omega_d t) the row at
  // scale s sees A exp(-sigma t) |Psi(omega_d + i sigma)| = A exp(-sigma t) exp(-((s omega_d - eta0)^2
  // - s^2 sigma^2) / 2). Divide that gain out so the amplitude is the signal's own envelope.
  const double s = kernel_sd_s(row);
  const double detune = s * omega_d - row.eta0;
  const double gain = std::exp(-0.5 * (detune * detune - s * s * sigma * sigma));
  e.amplitude = std::exp(fit.intercept + fit.slope * e.window_start_s) / gain;
  return e;
}

DampingEstimate estimate_two_point(const EnvelopeRow& row, const EnvelopeWindow& win, double f_d_hz) {
  DampingEstimate e = base_estimate(DampingMethod::two_point, row, win);
  e.f_hz = f_d_hz;
  if (win.end <= win.start + 2 || !(f_d_hz > 0)) {
    if (e.status == EstimateStatus::ok) e.status = EstimateStatus::too_short;
    return e;
  }
  const double noise = win.noise_power;
  const double dt = row.time_step_s;
  auto log_env = [&](double t) {  // ln envelope at time t, linear interpolation between columns
    const double x = t / dt;
    const auto c = static_cast<std::size_t>(std::floor(x));
    const double u = x - static_cast<double>(c);
    const double l0 = 0.5 * std::log(debiased_power(std::norm(row.w[c]), noise));
    const double l1 = 0.5 * std::log(debiased_power(std::norm(row.w[c + 1]), noise));
    return (1.0 - u) * l0 + u * l1;
  };
  const double t0 = static_cast<double>(win.start) * dt;
  const double t_last = static_cast<double>(win.end - 1) * dt;
  const double period = 1.0 / f_d_hz;
  const double l0 = log_env(t0);
  // First instant where the envelope has dropped by e^1.1, rounded to whole periods (Eq. 17).
  double target_t = t_last;
  for (std::size_t c = win.start; c + 1 < win.end; ++c) {
    if (log_env(static_cast<double>(c) * dt) <= l0 - 1.1) {
      target_t = static_cast<double>(c) * dt;
      break;
    }
  }
  auto m = static_cast<long>(std::lround((target_t - t0) / period));
  while (m > 0 && t0 + static_cast<double>(m) * period > t_last) --m;
  if (m < 1) {
    e.status = EstimateStatus::too_short;
    return e;
  }
  const double t1 = t0 + static_cast<double>(m) * period;
  const double l1 = log_env(t1);
  const double md = static_cast<double>(m);
  const double delta = (l0 - l1) / md;  // Eq. (18)
  e.points = 2;
  e.window_end_s = t1;
  if (!(delta > 0)) {
    e.status = EstimateStatus::not_decaying;
    return e;
  }
  const double four_pi2 = 4.0 * std::numbers::pi * std::numbers::pi;
  e.zeta = delta / std::sqrt(four_pi2 + delta * delta);  // Eq. (19)
  // var ln|W| = noise / (2 |W|^2) at each point; d zeta / d delta = 4 pi^2 / (4 pi^2 + delta^2)^1.5
  const double var_delta = 0.5 * noise * (std::exp(-2.0 * l0) + std::exp(-2.0 * l1)) / (md * md);
  e.zeta_sd = four_pi2 / std::pow(four_pi2 + delta * delta, 1.5) * std::sqrt(var_delta);
  set_zeta_interval(e);
  e.amplitude = std::exp(l0);
  return e;
}

}  // namespace ridgewatch::dsp
