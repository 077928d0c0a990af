// Damping-ratio estimators for one mode of a free response, all returning the same value type.
//
// Signal model, Eq. (16): x(t) = A exp(-sigma t) sin(omega_d t + phi) with sigma = zeta omega_0 and
// omega_d = omega_0 sqrt(1 - zeta^2). Every estimator measures the decay rate sigma and the damped
// frequency omega_d and reports zeta = sigma / sqrt(omega_d^2 + sigma^2), which is Eq. (19) with the
// logarithmic decrement delta = 2 pi sigma / omega_d of Eq. (17).
//
//  - two_point: the paper's method, Eq. (17)-(19): the wavelet envelope at two instants m periods apart.
//  - ridge_ls:  weighted least squares of ln|W| along the ridge over an automatically chosen window.
//  - ml:        nonlinear least squares of sampled damped sinusoids to the signal (see ml_fit.hpp),
//               the maximum-likelihood estimate for white Gaussian noise.
#pragma once

#include <cmath>
#include <complex>
#include <cstddef>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/dsp/morlet_cwt.hpp"

namespace ridgewatch::dsp {

enum class DampingMethod { two_point, ridge_ls, ml };

std::string_view to_string(DampingMethod method);
/// Parses "two-point", "ridge-ls", "ml"; returns false for anything else.
bool parse_damping_method(std::string_view text, DampingMethod& method);

/// Why an estimate should not be trusted; `ok` when it can.
enum class EstimateStatus {
  ok,
  too_short,     ///< fewer usable envelope samples than needed (window cut, record too short)
  low_snr,       ///< envelope never rises far enough above the noise floor
  not_decaying,  ///< envelope does not decay (sigma <= 0): not a free response
  fit_failed,    ///< the optimiser did not converge or the fit is degenerate
  inconsistent,  ///< independent estimators disagree beyond their uncertainties: the damped-sinusoid
                 ///< model does not describe this mode (close modes, non-viscous damping, ...)
};
std::string_view to_string(EstimateStatus status);

struct DampingEstimate {
  DampingMethod method = DampingMethod::ridge_ls;
  EstimateStatus status = EstimateStatus::fit_failed;
  double f_hz = NAN;              ///< damped natural frequency omega_d / 2 pi
  double f_sd_hz = NAN;           ///< its standard uncertainty (1 sigma)
  double zeta = NAN;              ///< damping ratio (dimensionless)
  double zeta_sd = NAN;           ///< standard uncertainty of zeta (1 sigma)
  double zeta_ci95_lo = NAN;      ///< 95 % interval
  double zeta_ci95_hi = NAN;
  double amplitude = NAN;         ///< envelope amplitude at window_start_s (signal units)
  double snr_db = NAN;            ///< peak envelope power over the noise power in the same band
  double window_start_s = NAN;    ///< part of the record the estimate used
  double window_end_s = NAN;
  std::size_t points = 0;         ///< envelope samples (or DFT bins) used
};

/// Decay rate sigma (1/s) to damping ratio, and back, for damped angular frequency omega_d (rad/s).
inline double zeta_from_decay(double sigma_per_s, double omega_d_rad_s) {
  return sigma_per_s / std::hypot(omega_d_rad_s, sigma_per_s);
}
inline double decay_from_zeta(double zeta, double omega_d_rad_s) {
  return zeta * omega_d_rad_s / std::sqrt(1.0 - zeta * zeta);
}

/// Settings of the envelope-based estimators.
struct EnvelopeOptions {
  /// Edge/impact effect skipped at the start and end, in kernel time widths s = eta0 / (2 pi f).
  /// The envelope of a step-started exponential equals the exponential times Phi((t - t0)/s - ...),
  /// within 3e-5 of it beyond 4 s.
  double edge_widths = 4.0;
  /// The window ends where the envelope power falls below this multiple of the row's noise power.
  double end_snr = 10.0;
  /// Minimum number of kernel widths the window must span.
  double min_window_widths = 2.0;
  /// Noise standard deviation of the input samples; <= 0 or NaN: estimated from the row itself
  /// (lower quartile of |W|^2, which is exponentially distributed where the row holds only noise).
  double noise_sd = NAN;
  /// Start of the free response (impact onset) in seconds from the record start.
  double onset_s = 0.0;
};

/// One row of the transform with what the envelope estimators need to know about it.
struct EnvelopeRow {
  std::span<const std::complex<double>> w;  ///< W(t, f_row) on the transform's time grid
  double time_step_s = 0.0;
  double f_row_hz = 0.0;
  double eta0 = 7.0;
  double noise_power = NAN;  ///< E|W|^2 of the noise alone in this row
  /// Phase unwrapping reference for decimated rows: phase_slope_frequency unwraps the column-to-column
  /// phase advance around 2 pi phase_reference_hz time_step_s instead of around 0, so rows whose
  /// carrier advances by more than pi per column (band-limited transforms) unwrap correctly as long
  /// as the true frequency is within fs_columns/2 of this reference. 0 (default): plain unwrapping.
  double phase_reference_hz = 0.0;
};

/// Envelope window [start, end) in column indices and derived quantities.
struct EnvelopeWindow {
  std::size_t start = 0, end = 0;  ///< columns
  std::size_t peak = 0;            ///< column of the envelope maximum
  double noise_power = NAN;        ///< noise E|W|^2 used
  EstimateStatus status = EstimateStatus::ok;
};

/// Scratch arrays of the line fits below (the fitted values and the lag correlations of the sandwich
/// covariance). The estimators resize them; callers on a real-time path reserve() them once, after
/// which the estimators allocate nothing. Nothing in it carries over from one call to the next.
struct EnvelopeWorkspace {
  std::vector<double> value, correlation;
  /// Reserves room for windows of up to `columns` columns and correlation reaches of up to `reach`.
  void reserve(std::size_t columns, std::size_t reach);
};

/// The weights of the envelope line fits (phase slope, ridge LS) on one row's window, at every
/// `stride`-th column from window.start: w = 2 (|W|^2 - noise)_+ / noise (the inverse variance of
/// ln|W| and of arg W), with the debiased |W|^2, the times from the window start, the bread sums and
/// the sandwich standard uncertainty of the slope. They depend on the row's samples, the window's
/// noise power, the column grid and the kernel width, not on the fitted values: a caller whose two fits
/// use the same row, window and stride computes them once and passes them to both.
struct EnvelopeFitWeights {
  std::size_t begin = 0, stride = 1, count = 0;  ///< the points: begin + i stride, i < count (columns)
  std::vector<double> power, weight, root_weight, time;  ///< per point (time in s from begin)
  double s0 = 0, s1 = 0, s2 = 0;  ///< weight sums sum w, sum w t, sum w t^2
  double slope_sd = NAN;          ///< sandwich standard uncertainty of the slope (NaN: < 3 points)
  /// Reserves room for windows of up to `columns` columns (no allocation in envelope_fit_weights).
  void reserve(std::size_t columns);
};

/// The phase slope's stride: unwrapping needs every column (phase advance < pi per column).
inline constexpr std::size_t kPhaseSlopeStride = 1;
/// The ridge LS's stride: about 8 points per kernel width (the samples are correlated over ~2 widths).
std::size_t ridge_ls_stride(const EnvelopeRow& row);
/// The weights of a fit on `window` of `row` with `stride` into `weights` (ws: scratch).
void envelope_fit_weights(const EnvelopeRow& row, const EnvelopeWindow& window, std::size_t stride,
                          EnvelopeFitWeights& weights, EnvelopeWorkspace& ws);

/// Noise power of a row estimated from its lower quartile: where the row holds only noise,
/// |W|^2 is exponential with mean P, whose 25 % quantile is P ln(4/3).
double estimate_row_noise_power(std::span<const std::complex<double>> w);

/// Chooses the fitting window on a row: starts edge_widths kernel widths after the onset and at
/// least 2 widths after the envelope peak, ends where |W|^2 < end_snr * noise or edge_widths before
/// the record end.
EnvelopeWindow choose_window(const EnvelopeRow& row, const EnvelopeOptions& options);

/// arg z in (-pi, pi], as std::arg: near the positive real axis (|arg z| <= 0.124, where the
/// derotated column-to-column phase advances of a row near the mode lie) by a series that is as
/// accurate as atan2 and cheaper; elsewhere std::arg (kernels::phase_angle). Used by
/// phase_slope_frequency.
double phase_angle(std::complex<double> z);

/// Damped frequency from the slope of the unwrapped phase of W along the row (weights |W|^2).
/// Unbiased: past the edges, arg W(t) = omega_d t + const for any row near the mode.
/// Returns NaN when the window has fewer than 3 points. sd_hz receives the standard uncertainty.
double phase_slope_frequency(const EnvelopeRow& row, const EnvelopeWindow& window, double& sd_hz);
/// With weights from envelope_fit_weights(row, window, kPhaseSlopeStride, ...) (std::invalid_argument
/// when they are for another window or stride); allocates nothing once `workspace` is reserved.
double phase_slope_frequency(const EnvelopeRow& row, const EnvelopeWindow& window, double& sd_hz,
                             const EnvelopeFitWeights& weights, EnvelopeWorkspace& workspace);

/// Eq. (17)-(19): the logarithmic decrement between the window start and the first instant m whole
/// periods later where the envelope has fallen by about e^1.1 (the spacing that minimises the
/// variance of delta for two noisy points).
DampingEstimate estimate_two_point(const EnvelopeRow& row, const EnvelopeWindow& window, double f_d_hz);

/// Weighted least squares of ln|W| against t over the window; weights 2|W|^2 / noise (the inverse
/// variance of ln|W|), noise-debiased envelope ln sqrt(|W|^2 - noise). The 95 % interval accounts for
/// the correlation of neighbouring envelope samples (the row's noise has a Gaussian autocorrelation
/// exp(-dt^2 / (4 s^2))) with a sandwich covariance.
DampingEstimate estimate_ridge_ls(const EnvelopeRow& row, const EnvelopeWindow& window, double f_d_hz);
/// With weights from envelope_fit_weights(row, window, ridge_ls_stride(row), ...) (as above).
DampingEstimate estimate_ridge_ls(const EnvelopeRow& row, const EnvelopeWindow& window, double f_d_hz,
                                  const EnvelopeFitWeights& weights, EnvelopeWorkspace& workspace);

}  // namespace ridgewatch::dsp
