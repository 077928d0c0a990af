#include "core/dsp/backbone.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace ridgewatch::dsp {

namespace {

constexpr double kZ95 = 1.959963984540054;

// Weighted least squares y = a + b x with weights w; returns false when degenerate. sd from the
// weights (the stated uncertainties), rss = sum w (y - a - b x)^2.
struct LineFit {
  double a = NAN, b = NAN, a_sd = NAN, b_sd = NAN, rss = NAN;
};

bool fit_line(const std::vector<double>& x, const std::vector<double>& y, const std::vector<double>& w, LineFit& out) {
  double s0 = 0, s1 = 0, s2 = 0, sy = 0, sxy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    s0 += w[i];
    s1 += w[i] * x[i];
    s2 += w[i] * x[i] * x[i];
    sy += w[i] * y[i];
    sxy += w[i] * x[i] * y[i];
  }
  const double det = s0 * s2 - s1 * s1;
  if (!(det > 0) || !std::isfinite(det)) return false;
  out.b = (s0 * sxy - s1 * sy) / det;
  out.a = (s2 * sy - s1 * sxy) / det;
  out.b_sd = std::sqrt(s0 / det);
  out.a_sd = std::sqrt(s2 / det);
  out.rss = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double r = y[i] - out.a - out.b * x[i];
    out.rss += w[i] * r * r;
  }
  return true;
}

}  // namespace

std::string_view to_string(BackboneLaw law) {
  switch (law) {
    case BackboneLaw::none: return "constant";
    case BackboneLaw::linear: return "a+b*A";
    case BackboneLaw::coulomb: return "a+b/A";
  }
  return "constant";
}

void test_backbone(Backbone& bb, const BackboneOptions& opt) {
  bb.tested = false;
  bb.amplitude_dependent = false;
  bb.law = BackboneLaw::none;
  std::vector<double> amp, zeta, w;
  for (const BackbonePoint& p : bb.points) {
    if (!(p.amplitude > 0) || !std::isfinite(p.zeta) || !(p.zeta_sd > 0) || !std::isfinite(p.zeta_sd)) continue;
    amp.push_back(p.amplitude);
    zeta.push_back(p.zeta);
    w.push_back(1.0 / (p.zeta_sd * p.zeta_sd));
  }
  const std::size_t k = amp.size();
  if (k < std::max<std::size_t>(opt.min_segments, 3)) return;
  bb.tested = true;
  bb.dof = k - 1;
  double sw = 0, swz = 0;
  for (std::size_t i = 0; i < k; ++i) {
    sw += w[i];
    swz += w[i] * zeta[i];
  }
  const double zmean = swz / sw;
  bb.chi2_constant = 0;
  for (std::size_t i = 0; i < k; ++i) bb.chi2_constant += w[i] * (zeta[i] - zmean) * (zeta[i] - zmean);
  // Both laws on the raw amplitude, zeta = a + b A and zeta = a + b / A, by weighted least squares; the
  // one with the smaller residual sum carries the test (a curved 1/A backbone fits a straight line in A
  // badly, so a test on the line alone would miss dry friction).
  LineFit l1, l2;
  const bool ok1 = fit_line(amp, zeta, w, l1);
  std::vector<double> inv(k);
  for (std::size_t i = 0; i < k; ++i) inv[i] = 1.0 / amp[i];
  const bool ok2 = fit_line(inv, zeta, w, l2);
  if (!ok1 && !ok2) return;
  const bool use_coulomb = ok2 && (!ok1 || l2.rss < l1.rss);
  const LineFit& best = use_coulomb ? l2 : l1;
  // Scatter beyond the stated uncertainties widens the slope's uncertainty (never narrows it).
  const double inflate = std::sqrt(std::max(1.0, best.rss / static_cast<double>(k - 2)));
  // Sign convention: + when zeta rises with the amplitude (b / A falls with A).
  bb.slope_z = (use_coulomb ? -1.0 : 1.0) * best.b / (best.b_sd * inflate);
  const auto [amin, amax] = std::minmax_element(amp.begin(), amp.end());
  const double x_lo = use_coulomb ? 1.0 / *amax : *amin, x_hi = use_coulomb ? 1.0 / *amin : *amax;
  bb.relative_change = std::abs(best.b) * (x_hi - x_lo) / std::abs(zmean);
  bb.amplitude_dependent = std::abs(bb.slope_z) > opt.slope_z && bb.relative_change > opt.min_relative_change;
  if (!bb.amplitude_dependent) {
    bb.a = zmean;
    const double sd = std::sqrt(1.0 / sw) * std::sqrt(std::max(1.0, bb.chi2_constant / static_cast<double>(bb.dof)));
    bb.a_ci95_lo = zmean - kZ95 * sd;
    bb.a_ci95_hi = zmean + kZ95 * sd;
    return;
  }
  bb.law = use_coulomb ? BackboneLaw::coulomb : BackboneLaw::linear;
  bb.a = best.a;
  bb.b = best.b;
  bb.a_ci95_lo = best.a - kZ95 * inflate * best.a_sd;
  bb.a_ci95_hi = best.a + kZ95 * inflate * best.a_sd;
  bb.b_ci95_lo = best.b - kZ95 * inflate * best.b_sd;
  bb.b_ci95_hi = best.b + kZ95 * inflate * best.b_sd;
}

Backbone estimate_backbone(const EnvelopeRow& row, const EnvelopeWindow& win, double f_d_hz,
                           const BackboneOptions& opt) {
  Backbone bb;
  if (win.end <= win.start || win.end > row.w.size() || !(row.time_step_s > 0) || !(f_d_hz > 0)) return bb;
  const double s = row.eta0 / (2.0 * std::numbers::pi * row.f_row_hz);
  const auto min_len = static_cast<std::size_t>(std::ceil(opt.min_segment_widths * s / row.time_step_s));
  const std::size_t len = win.end - win.start;
  if (min_len == 0) return bb;
  const std::size_t k = std::min(opt.max_segments, len / min_len);
  if (k < 2) return bb;
  const std::size_t seg = len / k;
  for (std::size_t i = 0; i < k; ++i) {
    EnvelopeWindow sub = win;
    sub.start = win.start + i * seg;
    sub.end = i + 1 == k ? win.end : sub.start + seg;
    sub.peak = win.peak;
    sub.status = EstimateStatus::ok;
    BackbonePoint p;
    double f_sd = NAN;
    const double f = phase_slope_frequency(row, sub, f_sd);
    p.f_hz = std::isfinite(f) ? f : NAN;
    p.f_sd_hz = f_sd;
    const DampingEstimate e = estimate_ridge_ls(row, sub, std::isfinite(f) ? f : f_d_hz);
    p.t_s = 0.5 * static_cast<double>(sub.start + sub.end) * row.time_step_s;
    if (std::isfinite(e.zeta) && e.zeta > 0 && e.zeta < 1 && std::isfinite(e.amplitude)) {
      // Mean amplitude of the segment: the fitted exponential's geometric midpoint.
      const double sigma = decay_from_zeta(e.zeta, 2.0 * std::numbers::pi * e.f_hz);
      p.amplitude = e.amplitude * std::exp(-sigma * 0.5 * static_cast<double>(sub.end - sub.start) * row.time_step_s);
      p.zeta = e.zeta;
      p.zeta_sd = e.zeta_sd;
    }
    bb.points.push_back(p);
  }
  test_backbone(bb, opt);
  return bb;
}

}  // namespace ridgewatch::dsp
