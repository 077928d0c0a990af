#include "core/diagnosis/damping_step.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

namespace ridgewatch::diagnosis {

namespace {

/// One impact's damping ratio as the fit sees it: the model's ζ at its onset plus its own correction.
struct ImpactZeta {
  double t_s = 0.0;
  double zeta = 0.0;
  double var = 0.0;  ///< noise variance of zeta
};

std::size_t layout_index(const FitResult& fit, const std::string& name) {
  for (std::size_t i = 0; i < fit.layout.size(); ++i)
    if (fit.layout[i].name == name) return i;
  return fit.layout.size();
}

double estimate_value(const FitResult& fit, const std::string& name, double otherwise) {
  for (const auto& e : fit.estimates)
    if (e.name == name) return e.value;
  return otherwise;
}

/// Per-impact ζ of every window (step 1 of damping_step.hpp): the window's residual regressed on the
/// model's derivatives (forward differences over the whole chain) with respect to an additive change
/// of ζ, its ln F and its onset shift. The nuisance columns keep a force or onset error from being
/// read as damping; the carried tails of the neighbours' perturbations are left in (e^-5 after a gap).
std::vector<ImpactZeta> per_impact_zeta(const ModelFitter& fitter, const FitResult& fit) {
  const std::size_t iz = layout_index(fit, "zeta");
  if (iz == fit.layout.size()) return {};
  const auto& seg = fitter.segmentation();
  const std::size_t nw = seg.windows.size();
  const ModelFitter::Chain base = fitter.evaluate(fit.layout, fit.params);
  // Steps: ζ by 0.1 % (u = ln ζ), the force by 0.1 %, the onset by 0.05 sample; the response is
  // linear in the force and smooth in the others (RK4 on a fixed grid), so forward differences hold.
  constexpr double kDu = 1e-3, kDf = 1e-3, kDs = 0.05;
  const double zeta = estimate_value(fit, "zeta", 0.0);
  const double dzeta = zeta * std::expm1(kDu);
  FitParams pz = fit.params, pf = fit.params, ps = fit.params;
  pz.u[static_cast<Eigen::Index>(iz)] += kDu;
  for (auto& v : pf.ln_force) v += kDf;
  for (auto& v : ps.shift) v += kDs;
  const ModelFitter::Chain cz = fitter.evaluate(fit.layout, pz);
  const ModelFitter::Chain cf = fitter.evaluate(fit.layout, pf);
  const ModelFitter::Chain cs = fitter.evaluate(fit.layout, ps);
  const double rate = estimate_value(fit, "damping_drift.rate_per_s", 0.0);
  const double sigma2 = seg.noise_sd * seg.noise_sd;
  const auto y = fitter.data();
  std::vector<ImpactZeta> out;
  for (std::size_t w = 0; w < nw; ++w) {
    const auto& win = seg.windows[w];
    Eigen::Matrix3d n = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < base.out[w].size(); ++i) {
      const double wt = seg.weight[win.begin + i];
      if (wt <= 0.0) continue;
      const double m = base.out[w][i];
      const Eigen::Vector3d a((cz.out[w][i] - m) / dzeta, (cf.out[w][i] - m) / kDf, (cs.out[w][i] - m) / kDs);
      n += wt * a * a.transpose();
      b += wt * a * (y[win.begin + i] - m);
    }
    const Eigen::Matrix3d inv = n.completeOrthogonalDecomposition().pseudoInverse();
    const double var = sigma2 * inv(0, 0);
    if (!(var > 0.0) || !std::isfinite(var)) continue;  // no damping information in this window
    out.push_back({win.onset_s, zeta + rate * win.onset_s + (inv * b)(0), var});
  }
  return out;
}

/// Weighted least squares of z on the columns of x; returns the residual χ² and the coefficients.
double weighted_chi2(const Eigen::MatrixXd& x, const Eigen::VectorXd& z, const Eigen::VectorXd& wt, Eigen::VectorXd& coef) {
  const Eigen::MatrixXd xw = wt.cwiseSqrt().asDiagonal() * x;
  const Eigen::VectorXd zw = wt.cwiseSqrt().cwiseProduct(z);
  coef = xw.completeOrthogonalDecomposition().solve(zw);
  return (zw - xw * coef).squaredNorm();
}

}  // namespace

std::vector<StepGap> damping_step_gaps(const ModelFitter& fitter, const FitResult& rate_fit, std::size_t max_gaps,
                                       double* f_statistic) {
  if (f_statistic != nullptr) *f_statistic = 0.0;
  if (layout_index(rate_fit, "damping_drift.rate_per_s") == rate_fit.layout.size()) return {};
  const std::vector<ImpactZeta> z = per_impact_zeta(fitter, rate_fit);
  const auto& seg = fitter.segmentation();
  const std::size_t n = z.size();
  if (n != seg.windows.size() || n < 6) return {};  // every window must have its ζ (the gaps are between windows)
  Eigen::MatrixXd x(static_cast<Eigen::Index>(n), 3);
  Eigen::VectorXd zz(static_cast<Eigen::Index>(n)), wt(static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    x(k, 0) = 1.0;
    x(k, 1) = z[i].t_s - z.front().t_s;
    zz(k) = z[i].zeta;
    wt(k) = 1.0 / z[i].var;
  }
  Eigen::VectorXd coef;
  const double chi2_line = weighted_chi2(x.leftCols(2), zz, wt, coef);
  // Admissible gaps: at least two impacts on each side (one impact alone on a side is fitted exactly
  // by the step, whatever its error) and a training impact on each side (else the training fit cannot
  // see the step). Per training split (the number of training impacts before the gap) the best gap.
  std::vector<StepGap> best_per_split;
  std::vector<std::size_t> split_of;
  for (std::size_t k = 1; k + 2 < n; ++k) {
    std::size_t train_before = 0, train_after = 0;
    for (std::size_t w = 0; w < n; ++w) (w <= k ? train_before : train_after) += fitter.is_heldout(w) ? 0 : 1;
    if (train_before == 0 || train_after == 0) continue;
    for (std::size_t i = 0; i < n; ++i) x(static_cast<Eigen::Index>(i), 2) = i > k ? 1.0 : 0.0;
    const double chi2 = weighted_chi2(x, zz, wt, coef);
    const auto& a = seg.windows[k];
    const auto& b = seg.windows[k + 1];
    // The model's step time: the middle of the gap between the two windows (before the next window
    // when they touch), so that no fitted sample sees ζ change inside its window.
    const double fs = seg.sample_rate_hz;
    const double t = a.end <= b.begin ? 0.5 * static_cast<double>(a.end + b.begin) / fs : static_cast<double>(b.begin) / fs;
    // Starts of the full fit from this line and step (inside the fit ranges): the drift-rate fit's
    // rate is a line through the step, often at the end of its range, where LM has no gradient.
    StepGap g{k, a.onset_s, b.onset_s, t, coef(0) - coef(1) * z.front().t_s, std::clamp(coef(1), -0.009, 0.009),
              std::clamp(coef(2), -0.45, 0.45), chi2};
    const auto it = std::find(split_of.begin(), split_of.end(), train_before);
    if (it == split_of.end()) {
      split_of.push_back(train_before);
      best_per_split.push_back(g);
    } else if (chi2 < best_per_split[static_cast<std::size_t>(it - split_of.begin())].chi2) {
      best_per_split[static_cast<std::size_t>(it - split_of.begin())] = g;
    }
  }
  if (best_per_split.empty()) return {};
  std::sort(best_per_split.begin(), best_per_split.end(), [](const StepGap& p, const StepGap& q) { return p.chi2 < q.chi2; });
  // F(1, n - 3) of the best step against the line, scaled by the scatter around the step model (the
  // per-impact ζ scatter more than their noise variances where the model misses other physics). The
  // threshold 20 is F(1, 13)'s 0.07 % point: over the ~12 admissible gaps of 16 impacts a record
  // without a step reaches it in about 1 % of cases (then two extra fits, and the BIC still decides).
  const double best = best_per_split.front().chi2;
  const double f = (chi2_line - best) / std::max(best / static_cast<double>(n - 3), std::numeric_limits<double>::min());
  if (f_statistic != nullptr) *f_statistic = f;
  if (!(f > kStepFThreshold)) return {};
  if (best_per_split.size() > max_gaps) best_per_split.resize(max_gaps);
  return best_per_split;
}

std::optional<StepFit> fit_damping_step(const ModelFitter& fitter, const std::vector<std::string>& with,
                                        const FitResult& rate_fit, ModelFitter& stepped) {
  const auto& settings = fitter.parameter_settings();
  if (settings.count("damping_drift.step") != 0 || settings.count(kStepTimeKey) != 0) return std::nullopt;
  std::optional<StepFit> best;
  for (const StepGap& gap : damping_step_gaps(fitter, rate_fit, kStepFits)) {
    ModelFitter candidate = fitter;
    auto s = settings;
    s[kStepTimeKey] = {gap.time_s, true, true};
    candidate.set_parameter_settings(s);
    FitResult g = candidate.fit(with, &rate_fit,
                                {{"zeta", gap.zeta_start}, {"damping_drift.rate_per_s", gap.rate_start}, {"damping_drift.step", gap.step_start}});
    if (!best || g.train_chi2 < best->fit.train_chi2) {
      best = StepFit{std::move(g), gap};
      stepped = std::move(candidate);
    }
  }
  if (!best || !(best->fit.bic < rate_fit.bic)) return std::nullopt;
  for (const auto& e : best->fit.estimates)
    if (e.name == "damping_drift.step" && std::abs(e.value) > 2.0 * e.sd) return best;
  return std::nullopt;
}

std::optional<ParameterEstimate> chosen_step_time(const ModelFitter& fitter) {
  const auto it = fitter.parameter_settings().find(kStepTimeKey);
  if (it == fitter.parameter_settings().end() || !it->second.chosen_from_data) return std::nullopt;
  const auto& w = fitter.segmentation().windows;
  ParameterEstimate e;
  e.name = kStepTimeKey;
  e.value = it->second.value;
  e.sd = std::numeric_limits<double>::quiet_NaN();
  for (std::size_t k = 0; k + 1 < w.size(); ++k)
    if (w[k].onset_s < e.value && e.value <= w[k + 1].onset_s) {
      e.ci95_lo = w[k].onset_s;
      e.ci95_hi = w[k + 1].onset_s;
    }
  return e;
}

std::map<std::string, ModelFitter::ParameterSetting> without_chosen_step(const ModelFitter& fitter) {
  auto s = fitter.parameter_settings();
  if (const auto it = s.find(kStepTimeKey); it != s.end() && it->second.chosen_from_data) s.erase(it);
  return s;
}

}  // namespace ridgewatch::diagnosis
