#include "core/diagnosis/term_discovery.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>
#include <sstream>
#include <utility>

#include <Eigen/Dense>

#include "core/diagnosis/diagnose.hpp"
#include "core/model/effect_registry.hpp"

namespace ridgewatch::diagnosis {

namespace {

/// One library term: its expression, the name of its coefficient, the coefficient's unit and its value
/// at a state.
struct LibraryTerm {
  std::string expr, param, unit;
  std::function<double(const TraceSample&)> eval;
  /// Dead-zone family only: the gap b (m) of sat_b(x) and the name of its parameter in the proposal
  /// (0 and empty for every other term).
  double gap;
  std::string gap_param;

  LibraryTerm(std::string e, std::string p, std::string u, std::function<double(const TraceSample&)> f,
              double b = 0.0, std::string bp = {})
      : expr(std::move(e)), param(std::move(p)), unit(std::move(u)), eval(std::move(f)), gap(b), gap_param(std::move(bp)) {}
};

/// Unit of the coefficient of x^ex v^ev t^et: N s^(ev-et) / m^(ex+ev).
std::string coefficient_unit(int ex, int ev, int et) {
  const int m = ex + ev, s = ev - et;
  std::string num = "N", den;
  if (s > 0) num += s == 1 ? " s" : " s^" + std::to_string(s);
  if (m > 0) den = m == 1 ? "m" : "m^" + std::to_string(m);
  if (s < 0) den += (den.empty() ? "" : " ") + std::string(s == -1 ? "s" : "s^" + std::to_string(-s));
  if (den.empty()) return num;
  return num + "/" + (den.find(' ') != std::string::npos ? "(" + den + ")" : den);
}

std::vector<LibraryTerm> library(int mesh_orders) {
  std::vector<LibraryTerm> L;
  auto poly = [&](const std::string& e, const std::string& p, int ex, int ev) {
    L.push_back({e, "a_" + p, coefficient_unit(ex, ev, 0), [ex, ev](const TraceSample& s) {
                   return std::pow(s.x, ex) * std::pow(s.v, ev);
                 }});
  };
  // First the two linear terms: corrections of c0 and ζ, always in the regression, never proposed.
  poly("x", "x", 1, 0);
  poly("v", "v", 0, 1);
  poly("x^2", "x2", 2, 0);
  poly("x*v", "xv", 1, 1);
  poly("v^2", "v2", 0, 2);
  poly("x^3", "x3", 3, 0);
  poly("x^2*v", "x2v", 2, 1);
  poly("x*v^2", "xv2", 1, 2);
  poly("v^3", "v3", 0, 3);
  L.push_back({"sign(v)", "a_sgnv", "N", [](const TraceSample& s) { return s.v > 0.0 ? 1.0 : (s.v < 0.0 ? -1.0 : 0.0); }});
  L.push_back({"abs(v)*v", "a_absvv", coefficient_unit(0, 2, 0), [](const TraceSample& s) { return std::abs(s.v) * s.v; }});
  // Slow drifts of the stiffness and the damping over the record (e.g. warming).
  L.push_back({"t_abs*x", "a_tx", coefficient_unit(1, 0, 1), [](const TraceSample& s) { return s.t_abs * s.x; }});
  L.push_back({"t_abs*v", "a_tv", coefficient_unit(0, 1, 1), [](const TraceSample& s) { return s.t_abs * s.v; }});
  // Mesh-periodic stiffness and damping (Eq. B1's form on the dynamic deflection).
  for (int k = 1; k <= mesh_orders; ++k) {
    const std::string arg = k == 1 ? "theta" : std::to_string(k) + "*theta";
    const std::string ks = std::to_string(k);
    L.push_back({"x*cos(" + arg + ")", "a_xc" + ks, "N/m", [k](const TraceSample& s) { return s.x * std::cos(k * s.theta); }});
    L.push_back({"x*sin(" + arg + ")", "a_xs" + ks, "N/m", [k](const TraceSample& s) { return s.x * std::sin(k * s.theta); }});
    L.push_back({"v*cos(" + arg + ")", "a_vc" + ks, "N s/m", [k](const TraceSample& s) { return s.v * std::cos(k * s.theta); }});
    L.push_back({"v*sin(" + arg + ")", "a_vs" + ks, "N s/m", [k](const TraceSample& s) { return s.v * std::sin(k * s.theta); }});
  }
  return L;
}

constexpr std::size_t kAlways = 2;  // x and v

/// The dead-zone family: sat_b(x) = min(max(x, -b), b), the force a spring of stiffness a_dz loses
/// inside a gap |x| < b (with a_dz = c0 the mesh carries no dynamic force there: backlash, a dead zone
/// around the loaded contact). Nonlinear in b, so one column per gap of a grid: b = x_rms · 2^-k,
/// k = 0..4 (x_rms the RMS of the model's dynamic deflection over all windows). discover_terms lets
/// only the gap that fits the training impacts best into the regression; the proposal fits b itself.
constexpr int kGapGrid = 5;

void add_dead_zone_terms(std::vector<LibraryTerm>& L, double x_rms) {
  for (int k = 0; k < kGapGrid; ++k) {
    const double b = x_rms * std::ldexp(1.0, -k);
    L.emplace_back("min(max(x, -b_dz), b_dz)", "a_dz", "N/m", [b](const TraceSample& s) { return std::clamp(s.x, -b, b); },
                   b, "b_dz");
  }
}

/// Response of the fitted linear mesh oscillator m ẍ + d ẋ + k x = f (f linear between samples, zero
/// state at the window start) as the sensor sees it (displacement, velocity or acceleration), times
/// `gain`. RK4 with steps of ω h <= 0.15 rad (the linear oscillator's RK4 error is then (ωh)^4/120 =
/// 4e-6 in frequency: far below what a regression column needs).
void oscillator_response(const std::vector<double>& f, double fs, double m, double d, double k,
                         model::SensorQuantity q, double gain, std::vector<double>& out) {
  const double w = std::sqrt(k / m);
  const int sub = std::max(1, static_cast<int>(std::ceil(w / (0.15 * fs))));
  const double h = 1.0 / (fs * sub);
  out.assign(f.size(), 0.0);
  double x = 0.0, v = 0.0;
  auto acc = [&](double force, double xx, double vv) { return (force - d * vv - k * xx) / m; };
  for (std::size_t i = 0; i < f.size(); ++i) {
    switch (q) {
      case model::SensorQuantity::kDisplacement: out[i] = gain * x; break;
      case model::SensorQuantity::kAcceleration: out[i] = gain * acc(f[i], x, v); break;
      case model::SensorQuantity::kVelocity: out[i] = gain * v; break;
    }
    if (i + 1 == f.size()) break;
    for (int s = 0; s < sub; ++s) {
      const double a = static_cast<double>(s) / sub, b = (s + 0.5) / sub, c = (s + 1.0) / sub;
      const double f0 = f[i] + a * (f[i + 1] - f[i]), fm = f[i] + b * (f[i + 1] - f[i]), f1 = f[i] + c * (f[i + 1] - f[i]);
      const double k1x = v, k1v = acc(f0, x, v);
      const double k2x = v + 0.5 * h * k1v, k2v = acc(fm, x + 0.5 * h * k1x, v + 0.5 * h * k1v);
      const double k3x = v + 0.5 * h * k2v, k3v = acc(fm, x + 0.5 * h * k2x, v + 0.5 * h * k2v);
      const double k4x = v + h * k3v, k4v = acc(f1, x + h * k3x, v + h * k3v);
      x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
      v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    }
  }
}

/// Per-window normal equations with the window's two nuisance columns eliminated (Schur complement):
/// for library columns L and the residual r, M = [L r]ᵀ P [L r] with P the projection off the
/// nuisance columns. The last row/column is the residual. Also the window's used sample count.
struct WindowGram {
  Eigen::MatrixXd m;
  double n = 0.0;
  bool heldout = false;
};

/// Training solve over the active library columns: coefficients (normalised), their standard errors,
/// and the training residual sum of squares.
struct Solve {
  Eigen::VectorXd xi, sd;
  double rss = 0.0;
  bool ok = false;
};

Solve solve_training(const std::vector<WindowGram>& grams, const std::vector<std::size_t>& active, double dof) {
  const auto k = static_cast<Eigen::Index>(active.size());
  const Eigen::Index r = grams.front().m.rows() - 1;
  Eigen::MatrixXd G = Eigen::MatrixXd::Zero(k, k);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(k);
  double rr = 0.0;
  for (const auto& g : grams) {
    if (g.heldout) continue;
    for (Eigen::Index i = 0; i < k; ++i) {
      const auto ai = static_cast<Eigen::Index>(active[static_cast<std::size_t>(i)]);
      b[i] += g.m(ai, r);
      for (Eigen::Index j = 0; j < k; ++j) G(i, j) += g.m(ai, static_cast<Eigen::Index>(active[static_cast<std::size_t>(j)]));
    }
    rr += g.m(r, r);
  }
  Solve s;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(G);
  if (ldlt.info() != Eigen::Success) return s;
  s.xi = ldlt.solve(b);
  s.rss = rr - b.dot(s.xi);
  const double s2 = std::max(s.rss, 0.0) / std::max(1.0, dof - static_cast<double>(k));
  const Eigen::MatrixXd cov = ldlt.solve(Eigen::MatrixXd::Identity(k, k)) * s2;
  s.sd = cov.diagonal().cwiseMax(0.0).cwiseSqrt();
  s.ok = s.xi.allFinite() && s.sd.allFinite();
  return s;
}

/// Held-out residual sum of squares (σ units) with the active coefficients frozen and each held-out
/// window's nuisances refitted (they are eliminated in its Gram matrix).
double heldout_rss(const std::vector<WindowGram>& grams, const std::vector<std::size_t>& active, const Eigen::VectorXd& xi) {
  const Eigen::Index r = grams.front().m.rows() - 1;
  double rss = 0.0;
  for (const auto& g : grams) {
    if (!g.heldout) continue;
    double v = g.m(r, r);
    for (std::size_t i = 0; i < active.size(); ++i) {
      const auto ai = static_cast<Eigen::Index>(active[i]);
      v -= 2.0 * xi[static_cast<Eigen::Index>(i)] * g.m(ai, r);
      for (std::size_t j = 0; j < active.size(); ++j)
        v += xi[static_cast<Eigen::Index>(i)] * xi[static_cast<Eigen::Index>(j)] * g.m(ai, static_cast<Eigen::Index>(active[j]));
    }
    rss += v;
  }
  return rss;
}

/// The normalised library columns and residual of one window, Gram matrix with nuisances eliminated.
WindowGram window_gram(const ModelFitter& fitter, const FitResult& fit, const ModelFitter::Linearisation& lin,
                       const std::vector<LibraryTerm>& L, const std::vector<double>& scale, std::size_t w,
                       double m_red, double damping, double c0, double gain) {
  const auto& seg = fitter.segmentation();
  const auto& win = seg.windows[w];
  const auto y = fitter.data();
  const std::size_t n = fit.model[w].size();
  const auto nl = static_cast<Eigen::Index>(L.size());
  Eigen::MatrixXd A(static_cast<Eigen::Index>(n), nl + 3);
  std::vector<double> force(n), resp;
  for (std::size_t j = 0; j < L.size(); ++j) {
    for (std::size_t i = 0; i < n; ++i) force[i] = L[j].eval(lin.states[w][i]);
    oscillator_response(force, seg.sample_rate_hz, m_red, damping, c0, fitter.rig().sensor_quantity, gain, resp);
    for (std::size_t i = 0; i < n; ++i) A(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = resp[i] * scale[j];
  }
  double used = 0.0;
  const double inv_sd = 1.0 / seg.noise_sd;
  for (std::size_t i = 0; i < n; ++i) {
    const double wt = seg.weight[win.begin + i];
    const auto row = static_cast<Eigen::Index>(i);
    A.row(row).head(nl) *= wt;
    A(row, nl) = wt * lin.d_ln_force[w][i] * inv_sd;
    A(row, nl + 1) = wt * lin.d_shift[w][i] * inv_sd;
    A(row, nl + 2) = wt * (y[win.begin + i] - fit.model[w][i]) * inv_sd;
    used += wt;
  }
  const Eigen::MatrixXd M = A.transpose() * A;
  // Eliminate the two nuisance columns (indices nl, nl+1): M' = M_oo - M_on M_nn^+ M_no over the
  // library and residual indices o. A window whose nuisance columns are degenerate (no pulse in it)
  // gets the pseudo-inverse through the complete orthogonal decomposition.
  std::vector<Eigen::Index> o(static_cast<std::size_t>(nl));
  std::iota(o.begin(), o.end(), 0);
  o.push_back(nl + 2);
  const auto no = static_cast<Eigen::Index>(o.size());
  Eigen::MatrixXd Moo(no, no), Mon(no, 2);
  for (Eigen::Index i = 0; i < no; ++i) {
    for (Eigen::Index j = 0; j < no; ++j) Moo(i, j) = M(o[static_cast<std::size_t>(i)], o[static_cast<std::size_t>(j)]);
    Mon(i, 0) = M(o[static_cast<std::size_t>(i)], nl);
    Mon(i, 1) = M(o[static_cast<std::size_t>(i)], nl + 1);
  }
  const Eigen::Matrix2d Mnn = M.block(nl, nl, 2, 2);
  const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> cod(Mnn);
  WindowGram g;
  g.m = Moo - Mon * cod.solve(Mon.transpose());
  g.n = used;
  g.heldout = fitter.is_heldout(w);
  return g;
}

std::string format_coefficient(double v) {
  std::ostringstream o;
  o.precision(4);
  o << v;
  return o.str();
}

}  // namespace

std::vector<std::string> term_library(int mesh_orders) {
  std::vector<std::string> out;
  for (const auto& t : library(mesh_orders)) out.push_back(t.expr);
  out.push_back("min(max(x, -b_dz), b_dz)");  // the dead-zone family (its gap grid depends on the fit)
  return out;
}

namespace {

/// The linearised problem of a fit: per-window Gram matrices over the normalised library columns,
/// the column scales and the sample counts.
struct Problem {
  std::vector<LibraryTerm> library;
  std::vector<double> scale;       ///< column scale: 1 / RMS of the term over the model's states
  std::vector<WindowGram> grams;
  double n_train = 0.0, n_held = 0.0, dof = 0.0;
};

Problem build_problem(const ModelFitter& fitter, const FitResult& fit, int mesh_orders) {
  Problem pr;
  const auto& seg = fitter.segmentation();
  pr.library = library(mesh_orders);
  const auto& L = pr.library;
  double c0 = 0.0, zeta = 0.0;
  for (const auto& e : fit.estimates) {
    if (e.name == "c0_n_per_m") c0 = e.value;
    if (e.name == "zeta") zeta = e.value;
  }
  const double m_red = fitter.rig().reduced_mass_kg();
  const double damping = 2.0 * zeta * std::sqrt(c0 * m_red);
  const double gain = fit.params.polarity * fitter.rig().sensor_sensitivity / seg.noise_sd;
  const ModelFitter::Linearisation lin = fitter.linearise(fit);
  double x2 = 0.0, nx = 0.0;
  for (const auto& states : lin.states)
    for (const auto& st : states) {
      x2 += st.x * st.x;
      nx += 1.0;
    }
  if (x2 > 0.0) add_dead_zone_terms(pr.library, std::sqrt(x2 / nx));
  // Column scales: the inverse RMS of each term over the model's states (so that the normal equations
  // see columns of comparable size; the coefficients are mapped back to N per unit of the term).
  pr.scale.assign(L.size(), 0.0);
  for (std::size_t j = 0; j < L.size(); ++j) {
    double s2 = 0.0, n = 0.0;
    for (const auto& states : lin.states)
      for (const auto& st : states) {
        const double v = L[j].eval(st);
        s2 += v * v;
        n += 1.0;
      }
    pr.scale[j] = s2 > 0.0 ? std::sqrt(n / s2) : 0.0;
  }
  double train_windows = 0.0;
  for (std::size_t w = 0; w < seg.windows.size(); ++w) {
    pr.grams.push_back(window_gram(fitter, fit, lin, L, pr.scale, w, m_red, damping, c0, gain));
    (pr.grams.back().heldout ? pr.n_held : pr.n_train) += pr.grams.back().n;
    if (!pr.grams.back().heldout) train_windows += 1.0;
  }
  pr.dof = pr.n_train - 2.0 * train_windows;  // two nuisances per training window
  return pr;
}

/// The dead-zone column whose gap fits the training impacts best beside x and v (the least training
/// RSS of the three-column solve; the held-out impacts are kept for the gates), 0 if there is none.
std::size_t best_gap(const Problem& pr, const std::vector<std::size_t>& base) {
  std::size_t best = 0;
  double best_rss = INFINITY;
  for (std::size_t j = 0; j < pr.library.size(); ++j) {
    if (pr.library[j].gap == 0.0 || !(pr.scale[j] > 0.0) || !std::isfinite(pr.scale[j])) continue;
    std::vector<std::size_t> with = base;
    with.push_back(j);
    const Solve s = solve_training(pr.grams, with, pr.dof);
    if (s.ok && s.rss < best_rss) {
      best_rss = s.rss;
      best = j;
    }
  }
  return best;
}

/// Sequentially thresholded least squares on the training impacts, one term per pass (the weakest
/// |ξ / sd|), x and v (the first kAlways entries) never dropped. Returns false if singular.
bool stlsq(const Problem& pr, std::vector<std::size_t>& active, Solve& s, const TermDiscoveryOptions& opt) {
  s = solve_training(pr.grams, active, pr.dof);
  while (active.size() > kAlways) {
    if (!s.ok) return false;
    std::size_t weakest = 0;
    double t_min = INFINITY;
    for (std::size_t i = kAlways; i < active.size(); ++i) {
      const double t = std::abs(s.xi[static_cast<Eigen::Index>(i)]) / std::max(s.sd[static_cast<Eigen::Index>(i)], 1e-300);
      if (t < t_min) {
        t_min = t;
        weakest = i;
      }
    }
    if (t_min >= opt.t_threshold && active.size() - kAlways <= opt.max_terms) break;
    active.erase(active.begin() + static_cast<std::ptrdiff_t>(weakest));
    s = solve_training(pr.grams, active, pr.dof);
  }
  return s.ok;
}

/// Held-out validation: a term stays only if the held-out residual power grows by more than
/// `gate_se` standard errors (one is sqrt(2 n) (1 + excess) in σ² units: the sd of a sum of n squared
/// white residuals) without it; the term whose removal costs least goes first. Returns the held-out RSS of the result.
double heldout_prune(const Problem& pr, std::vector<std::size_t>& active, Solve& s, double gate_se) {
  double h_with = heldout_rss(pr.grams, active, s.xi);
  for (bool dropped = true; dropped && active.size() > kAlways;) {
    dropped = false;
    std::size_t drop = 0;
    double best_without = INFINITY;
    Solve best;
    for (std::size_t i = kAlways; i < active.size(); ++i) {
      std::vector<std::size_t> without = active;
      without.erase(without.begin() + static_cast<std::ptrdiff_t>(i));
      const Solve sw = solve_training(pr.grams, without, pr.dof);
      if (!sw.ok) continue;
      const double h = heldout_rss(pr.grams, without, sw.xi);
      if (h < best_without) {
        best_without = h;
        drop = i;
        best = sw;
      }
    }
    const double se = std::sqrt(2.0 * pr.n_held) * (1.0 + std::max(0.0, h_with / pr.n_held - 1.0));
    if (std::isfinite(best_without) && best_without - h_with < gate_se * se) {
      active.erase(active.begin() + static_cast<std::ptrdiff_t>(drop));
      s = best;
      h_with = best_without;
      dropped = true;
    }
  }
  return h_with;
}

/// The surviving terms as a user-defined effect: each coefficient's sign goes into the expression, so
/// that every parameter is a positive size (a [0, max] range, fitted on a log scale by compare and
/// diagnose; null 0 = the term vanishes), max 100x the estimate (room for compare's nonlinear refit
/// of a first-order value), default = the estimate (compare's start).
void build_proposal(const Problem& pr, const std::vector<std::size_t>& active, const Solve& s, double h_with,
                    TermDiscoveryResult& res) {
  std::ostringstream force;
  for (std::size_t i = kAlways; i < active.size(); ++i) {
    const LibraryTerm& t = pr.library[active[i]];
    DiscoveredTerm d;
    d.term = t.expr;
    d.parameter = t.param;
    d.unit = t.unit;
    d.coefficient = s.xi[static_cast<Eigen::Index>(i)] * pr.scale[active[i]];
    d.sd = s.sd[static_cast<Eigen::Index>(i)] * pr.scale[active[i]];
    d.linear_coefficient = d.coefficient;
    d.gap_parameter = t.gap_param;
    d.gap = t.gap;
    std::vector<std::size_t> without = active;
    without.erase(without.begin() + static_cast<std::ptrdiff_t>(i));
    const Solve sw = solve_training(pr.grams, without, pr.dof);
    if (sw.ok) d.heldout_loss = (heldout_rss(pr.grams, without, sw.xi) - h_with) / pr.n_held;
    res.terms.push_back(d);
    const bool neg = d.coefficient < 0.0;
    if (i == kAlways) force << (neg ? "-" : "");
    else force << (neg ? " - " : " + ");
    force << t.param << " * " << t.expr;
    model::EffectParameter p;
    p.key = t.param;
    p.unit = t.unit;
    p.min_value = 0.0;
    p.max_value = 100.0 * std::abs(d.coefficient);
    p.default_value = std::abs(d.coefficient);
    p.null_value = 0.0;
    p.description = "coefficient of " + t.expr + " (term discovery, " + format_coefficient(d.coefficient) + " fitted)";
    res.definition.parameters.push_back(p);
    if (!t.gap_param.empty()) {
      // The gap of the dead-zone term: fitted with the coefficient (log scale over [0, 100 b]).
      model::EffectParameter b;
      b.key = t.gap_param;
      b.unit = "m";
      b.min_value = 0.0;
      b.max_value = 100.0 * t.gap;
      b.default_value = t.gap;
      b.null_value = 0.0;
      b.description = "gap of the dead-zone term (term discovery, " + format_coefficient(t.gap) + " m from the grid)";
      res.definition.parameters.push_back(b);
      // Its kinks at x = ±b_dz, located by the integrator (a step over a kink costs RK4 its order).
      res.definition.kinks = {"x - " + t.gap_param, "x + " + t.gap_param};
    }
  }
  res.force = force.str();
  res.definition.force = res.force;
}

}  // namespace

TermDiscoveryResult discover_terms(const ModelFitter& fitter, const FitResult& fit, const TermDiscoveryOptions& opt) {
  TermDiscoveryResult res;
  res.base_effects = fit.effects;
  res.definition.name = opt.effect_name;
  const Problem pr = build_problem(fitter, fit, opt.mesh_orders);
  if (pr.n_held <= 0.0 || pr.n_train <= 0.0) {
    res.note = "no held-out or no training samples";
    return res;
  }
  // A term that is zero on every state (e.g. sign(v) of a model at rest) cannot be estimated.
  std::vector<std::size_t> active;
  for (std::size_t j = 0; j < pr.library.size(); ++j)
    if (pr.scale[j] > 0.0 && std::isfinite(pr.scale[j]) && pr.library[j].gap == 0.0) active.push_back(j);
  if (active.size() < kAlways || active[0] != 0 || active[1] != 1) {
    res.note = "the model does not move (x or v is zero on every sample)";
    return res;
  }
  const std::vector<std::size_t> base = {0, 1};
  const Solve s0 = solve_training(pr.grams, base, pr.dof);
  if (const std::size_t gap = best_gap(pr, base); gap != 0) active.push_back(gap);
  Solve s;
  if (!s0.ok || !stlsq(pr, active, s, opt)) {
    res.note = "the library's normal equations are singular";
    return res;
  }
  res.heldout_excess_before = heldout_rss(pr.grams, base, s0.xi) / pr.n_held - 1.0;
  const double h_with = heldout_prune(pr, active, s, opt.term_gate_se);
  res.heldout_excess_after = h_with / pr.n_held - 1.0;
  res.heldout_gain = res.heldout_excess_before - res.heldout_excess_after;
  // diagnose's gain gate: three standard errors of a held-out power ratio over n_held white samples.
  res.required_gain = 3.0 * std::sqrt(2.0 / pr.n_held) * (1.0 + std::max(0.0, res.heldout_excess_after));
  if (active.size() <= kAlways) {
    res.note = "no library term improves the held-out impacts beyond a change of c0 and zeta";
    return res;
  }
  build_proposal(pr, active, s, h_with, res);
  if (!(res.heldout_gain > res.required_gain)) {
    res.note = "the surviving terms gain " + format_number(res.heldout_gain) + " of held-out excess, less than the " +
               format_number(res.required_gain, 2) + " the gate needs";
    return res;
  }
  // The proposal must load as a user-defined effect exactly as a rig file's would (compiled, checked
  // on the grid of states): otherwise it is no proposal.
  try {
    (void)model::make_custom_effect(res.definition);
  } catch (const std::exception& e) {
    res.note = std::string("the proposed effect does not load: ") + e.what();
    return res;
  }
  res.proposed = true;
  return res;
}

void verify_proposal(const ModelFitter& fitter, const FitResult& base_fit, TermDiscoveryResult& p) {
  if (!p.proposed) return;
  const std::vector<model::UserEffect> saved = model::user_effects();
  std::vector<model::UserEffect> with = saved;
  with.push_back({model::make_custom_effect(p.definition), {}});
  model::set_user_effects(with);
  std::vector<std::string> effects = p.base_effects;
  effects.push_back(p.definition.name);
  // Two starts, the better training fit kept: warm from the base fit, and cold from the rig's values
  // (as compare starts a pasted block). The warm start alone counts twice what the base model's ζ
  // and c0 absorbed of the missing force (cubic damping: ζ twice the truth beside the full v³
  // coefficient), and the fit could stop in that corner.
  FitResult f;
  bool ok = false;
  for (const FitResult* warm : {&base_fit, static_cast<const FitResult*>(nullptr)}) {
    try {
      FitResult g = fitter.fit(effects, warm);
      if (!ok || g.train_chi2 < f.train_chi2) f = std::move(g);
      ok = true;
    } catch (const std::exception&) {
      // the force left its finite range during this fit
    }
  }
  model::set_user_effects(saved);
  if (!ok) {
    p.proposed = false;
    p.note = "the proposed force is not finite at the states its fit reached";
    return;
  }
  p.verified_excess = f.heldout_excess;
  p.verified_fit = f;
  for (auto& t : p.terms)
    for (const auto& e : f.estimates) {
      if (!t.gap_parameter.empty() && e.name == p.definition.name + "." + t.gap_parameter) {
        t.gap = e.value;
        for (auto& q : p.definition.parameters)
          if (q.key == t.gap_parameter) q.default_value = e.value;
      }
      if (e.name == p.definition.name + "." + t.parameter) {
        t.coefficient = std::copysign(e.value, t.linear_coefficient);
        t.sd = e.sd;
        for (auto& q : p.definition.parameters)
          if (q.key == t.parameter) {
            q.default_value = e.value;
            q.max_value = std::max(q.max_value, 100.0 * e.value);
          }
      }
    }
  const double gain = base_fit.heldout_excess - f.heldout_excess;
  const double need = 3.0 * std::sqrt(2.0 / std::max(1.0, f.heldout_n)) * (1.0 + std::max(0.0, f.heldout_excess));
  if (!(gain > need)) {
    p.proposed = false;
    p.note = "fitted with the nonlinear model, the proposed force gains " + format_number(gain) +
             " of held-out excess, less than the " + format_number(need, 2) + " the gate needs";
  }
}

model::CustomEffectDefinition dead_zone_definition(const std::string& name, double c0, double x_rms) {
  model::CustomEffectDefinition def;
  def.name = name;
  def.force = "a_dz * min(max(x, -b_dz), b_dz)";
  def.kinks = {"x - b_dz", "x + b_dz"};
  model::EffectParameter a{"a_dz", "N/m", 0.0, 100.0 * c0, c0, 0.0, "stiffness lost inside the gap (term discovery)"};
  model::EffectParameter b{"b_dz", "m", 0.0, 100.0 * x_rms, x_rms, 0.0, "gap of the dead zone (term discovery)"};
  def.parameters = {a, b};
  return def;
}

TermDiscoveryResult fit_dead_zone(const ModelFitter& fitter, const FitResult& base_fit, const TermDiscoveryOptions& opt) {
  TermDiscoveryResult res;
  res.base_effects = base_fit.effects;
  double c0 = fitter.rig().mean_mesh_stiffness_n_per_m;
  for (const auto& e : base_fit.estimates)
    if (e.name == "c0_n_per_m") c0 = e.value;
  double x2 = 0.0, nx = 0.0;
  for (const auto& states : fitter.linearise(base_fit).states)
    for (const auto& st : states) {
      x2 += st.x * st.x;
      nx += 1.0;
    }
  if (!(x2 > 0.0)) {
    res.note = "the model does not move (x is zero on every sample)";
    return res;
  }
  const double x_rms = std::sqrt(x2 / nx);
  res.definition = dead_zone_definition(opt.effect_name, c0, x_rms);
  res.force = res.definition.force;
  const std::vector<model::UserEffect> saved = model::user_effects();
  std::vector<model::UserEffect> with = saved;
  with.push_back({model::make_custom_effect(res.definition), {}});
  model::set_user_effects(with);
  std::vector<std::string> effects = base_fit.effects;
  effects.push_back(opt.effect_name);
  FitResult best;
  bool ok = false;
  // a_dz starts at the c0 the cold fits start from (the rig's): no stiffness left inside the gap, the
  // dead zone proper. Its tail drifts to rest anywhere in the gap, and the rest offset carried into
  // the next window depends steeply on the stiffness left there (c0 - a_dz): started at the linear
  // fit's c0 (a few % below the rig's on a dead-zone record), LM stayed in a basin 10-20 % off.
  const double a_start = fitter.rig().mean_mesh_stiffness_n_per_m;
  for (int k = 0; k < kGapGrid; ++k) {
    const std::vector<std::pair<std::string, double>> starts = {{opt.effect_name + ".a_dz", a_start},
                                                                {opt.effect_name + ".b_dz", x_rms * std::ldexp(1.0, -k)}};
    try {
      FitResult g = fitter.fit(effects, nullptr, starts);
      // The gap's start chosen by the training fit (the same parameters from different starts), so
      // that the held-out impacts judge the proposal without having chosen it.
      if (!ok || g.train_chi2 < best.train_chi2) best = std::move(g);
      ok = true;
    } catch (const std::exception&) {
      // the force left its finite range during this fit
    }
  }
  if (ok) {
    // The best fit's gap and coefficient once more cold (c0, ζ and the pulse from the rig's), as
    // compare refits the pasted block from its defaults: the multi-start's cold fits start a_dz and
    // b_dz far from where they end, and LM can stop with c0 or the pulse length in a corner. With each
    // pulse shape, as compare does: the impact drives the mesh through the gap while the pulse acts,
    // so the pulse's shape shows where its length cannot absorb it.
    std::vector<std::pair<std::string, double>> starts;
    for (const auto& e : best.estimates)
      if (e.name == opt.effect_name + ".a_dz" || e.name == opt.effect_name + ".b_dz") starts.emplace_back(e.name, e.value);
    try {
      FitResult g = fit_pulse_shapes(fitter, effects, nullptr, starts);
      if (g.train_chi2 < best.train_chi2) best = std::move(g);
    } catch (const std::exception&) {
      // keep the multi-start's fit
    }
  }
  model::set_user_effects(saved);
  if (!ok) {
    res.note = "the dead-zone force is not finite at the states its fits reached";
    return res;
  }
  DiscoveredTerm t{"min(max(x, -b_dz), b_dz)", "a_dz", "N/m", 0.0, 0.0, 0.0,
                   std::numeric_limits<double>::quiet_NaN(), "b_dz", 0.0};
  for (const auto& e : best.estimates) {
    if (e.name == opt.effect_name + ".a_dz") {
      t.coefficient = e.value;
      t.sd = e.sd;
      res.definition.parameters[0].default_value = e.value;
    }
    if (e.name == opt.effect_name + ".b_dz") {
      t.gap = e.value;
      res.definition.parameters[1].default_value = e.value;
    }
  }
  res.heldout_excess_before = base_fit.heldout_excess;
  res.heldout_excess_after = res.verified_excess = best.heldout_excess;
  res.heldout_gain = t.heldout_loss = base_fit.heldout_excess - best.heldout_excess;
  res.required_gain =
      3.0 * std::sqrt(2.0 / std::max(1.0, best.heldout_n)) * (1.0 + std::max(0.0, best.heldout_excess));
  res.terms = {t};
  res.verified_fit = std::move(best);
  res.proposed = res.heldout_gain > res.required_gain;
  res.note = res.proposed ? "the dead-zone family fitted by the nonlinear fitter from each gap of the grid"
                          : "the dead-zone force fitted from each gap of the grid gains " + format_number(res.heldout_gain) +
                                " of held-out excess, less than the " + format_number(res.required_gain, 2) +
                                " the gate needs";
  return res;
}

}  // namespace ridgewatch::diagnosis
