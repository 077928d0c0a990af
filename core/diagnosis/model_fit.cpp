#include "core/diagnosis/model_fit.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include <unsupported/Eigen/NonLinearOptimization>

namespace ridgewatch::diagnosis {

ModelFitter::ModelFitter(std::span<const double> y, const Segmentation& seg, const model::RigParameters& rig)
    : y_(y), seg_(seg), rig_(rig) {
  if (seg_.windows.size() < 4)
    throw std::invalid_argument("need at least 4 impacts to fit and hold out (found " +
                                std::to_string(seg_.windows.size()) + ")");
}

std::vector<GlobalParameter> ModelFitter::layout(const std::vector<std::string>& effects, bool pulse_with_mesh) const {
  std::vector<GlobalParameter> g;
  // c0 within ±50 % of nominal and ζ in [1e-4, 0.5]: far wider than any plausible rig (the paper's
  // gap is 0.6 % in f0), narrow enough to keep the optimiser away from nonsense.
  g.push_back({"c0_n_per_m", "", "", Transform::kBounded, std::log(0.5), std::log(1.5)});
  g.push_back({"zeta", "", "", Transform::kLog, 1e-4, 0.5});
  bool mesh = false;
  for (const auto& name : effects) {
    const CandidateSpec* c = find_candidate(name);
    if (c == nullptr) throw std::invalid_argument("effect '" + name + "' cannot be fitted (not a diagnosable dynamics effect)");
    const auto fixed_by_user = [&](const std::string& key) {
      const auto it = settings_.find(name + "." + key);
      return it != settings_.end() && it->second.fixed;
    };
    for (const auto& f : c->free) {
      if (f.set_only || fixed_by_user(f.key)) continue;
      if (f.needs_fixed != nullptr && !fixed_by_user(f.needs_fixed)) continue;
      g.push_back({name + "." + f.key, name, f.key, f.transform, f.lo, f.hi});
    }
    mesh = mesh || c->mesh_periodic;
  }
  if (mesh) g.push_back({"mesh_phase_rad", "", "", Transform::kAngle, 0.0, 0.0});
  // The impact pulse length (last, so that the effects' parameters keep their places): between 0.5
  // and 2 times the rig's (wider lets a wrong model use it to mimic other physics). Measured on records of an independent generator with a Hann pulse: with
  // the length fixed, the held-out excess of a control stays at 0.04-0.12 (the pulse shape alone);
  // fitted, at the noise (issue 14).
  // With a mesh-periodic effect only on request (pulse_with_mesh): there the steady forced response
  // is up to 1000x the noise, and fitted from the start the extra global left a held-out excess of
  // 1.5-5 where the fixed pulse leaves 0.1 (measured on both generators). Freed from the converged
  // fixed-pulse fit it brings the no-load-lines stiffness variation to the noise (diagnose.cpp).
  if (!mesh || pulse_with_mesh) g.push_back({"pulse_duration_s", "", "", Transform::kLog, 0.5 * rig_.impact_duration_s, 2.0 * rig_.impact_duration_s});
  return g;
}

PhysicsValues ModelFitter::physics(const std::vector<GlobalParameter>& layout, const Eigen::VectorXd& u) const {
  PhysicsValues p;
  for (std::size_t i = 0; i < layout.size(); ++i) {
    const auto& g = layout[i];
    const double v = to_value(g.transform, g.lo, g.hi, u[static_cast<Eigen::Index>(i)]);
    if (g.name == "c0_n_per_m") p.c0_n_per_m = rig_.mean_mesh_stiffness_n_per_m * std::exp(v);
    else if (g.name == "zeta") p.zeta = v;
    else if (g.name == "mesh_phase_rad") p.mesh_phase_rad = v;
    else if (g.name == "pulse_duration_s") p.pulse_s = v;
    else {
      auto it = std::find_if(p.effects.begin(), p.effects.end(), [&](const auto& e) { return e.first == g.effect; });
      if (it == p.effects.end()) {
        const CandidateSpec* c = find_candidate(g.effect);
        p.effects.push_back({g.effect, c->fixed});
        it = p.effects.end() - 1;
      }
      it->second[g.key] = v;
    }
  }
  // Fixed settings: into the effects fitted above, and effects with every parameter fixed (absent
  // from the layout) added with their fixed values (they belong to every model; see the header).
  const std::size_t fitted_effects = p.effects.size();
  for (const auto& [name, s] : settings_) {
    if (!s.fixed) continue;
    const auto dot = name.find('.');
    const std::string effect = name.substr(0, dot), key = name.substr(dot + 1);
    auto it = std::find_if(p.effects.begin(), p.effects.end(), [&](const auto& e) { return e.first == effect; });
    if (it == p.effects.end()) {
      p.effects.push_back({effect, find_candidate(effect)->fixed});
      it = p.effects.end() - 1;
    }
    it->second[key] = s.value;
  }
  // An effect the settings fix only in part and the layout does not fit is not in this model
  // (diagnose keeps a chosen step time in its settings while it fits models without damping_drift).
  const auto incomplete = [](const auto& e) {
    for (const auto& f : find_candidate(e.first)->free)
      if (e.second.find(f.key) == e.second.end()) return true;
    return false;
  };
  p.effects.erase(std::remove_if(p.effects.begin() + static_cast<std::ptrdiff_t>(fitted_effects), p.effects.end(), incomplete),
                  p.effects.end());
  for (auto& [effect, values] : p.effects) {
    // Every free key of a fully fixed effect must now have a value.
    for (const auto& f : find_candidate(effect)->free)
      if (values.find(f.key) == values.end())
        throw std::logic_error("effect " + effect + ": parameter " + f.key + " neither fitted nor fixed");
  }
  return p;
}

PhysicsValues ModelFitter::physics(const std::vector<GlobalParameter>& layout, const FitParams& p) const {
  PhysicsValues v = physics(layout, p.u);
  v.pulse_shape = p.pulse_shape;
  return v;
}

bool ModelFitter::frees_heldout_nuisances(const FitResult& f) const {
  return friction_carry_fit_ && WindowSimulator(rig_, physics(f.layout, f.params), seg_.sample_rate_hz).has_dry_friction();
}

void ModelFitter::set_parameter_settings(const std::map<std::string, ParameterSetting>& settings) {
  for (const auto& [name, s] : settings) {
    const auto dot = name.find('.');
    if (dot == std::string::npos) throw std::invalid_argument("'" + name + "' is not <effect>.<key>");
    const std::string effect = name.substr(0, dot), key = name.substr(dot + 1);
    const CandidateSpec* c = find_candidate(effect);
    if (c == nullptr) throw std::invalid_argument("effect '" + effect + "' cannot be fitted");
    const FreeParameter* f = nullptr;
    std::string known;
    for (const auto& q : c->free) {
      if (q.key == key) f = &q;
      known += (known.empty() ? "" : ", ") + q.key;
    }
    if (f == nullptr)
      throw std::invalid_argument("effect " + effect + ": '" + key + "' is not a fitted parameter (fitted: " + known + ")");
    if (f->set_only && !s.fixed)
      throw std::invalid_argument("effect " + effect + ": " + key +
                                  " is not fitted, only set: give it with '!' (" + key + "=VALUE!)");
    if (f->set_only) {
      // A time in the record (s from its start) with fitted impacts on both sides; otherwise what it
      // switches (damping_drift's step) acts on no window, or on all alike, and cannot be fitted.
      const auto& w = seg_.windows;
      const bool both_sides = !w.empty() && w.front().onset_s < s.value && s.value < w.back().onset_s;
      if (!both_sides) {
        std::ostringstream o;
        o << "effect " << effect << ": " << key << " = " << s.value << " s is not between the first and the last fitted impact ("
          << (w.empty() ? 0.0 : w.front().onset_s) << " .. " << (w.empty() ? 0.0 : w.back().onset_s) << " s)";
        throw std::invalid_argument(o.str());
      }
    }
    const bool angle = f->transform == Transform::kAngle;
    if (!std::isfinite(s.value) || (!angle && (s.value < f->lo || s.value > f->hi))) {
      std::ostringstream o;
      o << "effect " << effect << ": " << key << " = " << s.value << " is outside the fit range [" << f->lo << ", "
        << f->hi << "]";
      throw std::invalid_argument(o.str());
    }
  }
  settings_ = settings;
}

WindowSimulator::Impact ModelFitter::impact(std::size_t w, const FitParams& p) const {
  const auto& win = seg_.windows[w];
  const double fs = seg_.sample_rate_hz;
  // The onset may move from the detector's by -1 ms (the window starts 1 ms before it) to +2 ms: the
  // detector is within 0.1 ms on the simulated rig, but at 3 % noise it can trigger on the rising
  // noise-plus-response more than a millisecond early (seen: 1.3 ms).
  const double shift = std::clamp(p.shift[w], -0.001 * fs, 0.002 * fs);
  return {win.onset_s + shift / fs, rig_.impact_force_n * std::exp(std::clamp(p.ln_force[w], -30.0, 30.0)),
          win.mesh_hz, p.polarity};
}

ModelState ModelFitter::carry(const WindowSimulator& sim, std::size_t w, const Chain& c) const {
  const int pred = seg_.windows[w].predecessor;
  if (pred < 0 || c.end.size() <= static_cast<std::size_t>(pred)) return {};
  const auto& e = c.end[static_cast<std::size_t>(pred)];
  const double fs = seg_.sample_rate_hz;
  const auto& pw = seg_.windows[static_cast<std::size_t>(pred)];
  if (sim.integrates_gaps()) {
    // Dry friction: the leftover motion stops somewhere in the gap and the mesh stays stuck at an
    // offset within the friction band, which shapes the next response (up to F_c/c0 ω of velocity,
    // a few % of the peak). A dead zone (a user-defined force with kinks) lets the tail drift to rest
    // anywhere in its gap. The closed-form decay cannot say where it stops: integrate the gap.
    if (e.stopped) {
      // Stuck at an offset: the mesh stays there until the impact, but an auxiliary mode (second_mode)
      // keeps ringing down through the gap (it is not held by the friction).
      const double t_end = static_cast<double>(pw.end - 1) / fs;
      const double t_begin = static_cast<double>(seg_.windows[w].begin) / fs;
      ModelState s = e.transient;
      const ModelState decayed = sim.propagate(s, t_begin - t_end, t_end);
      s.p = decayed.p;
      s.pd = decayed.pd;
      return s;
    }
    const std::uint64_t first = pw.end - 1;
    const std::size_t n = static_cast<std::size_t>(seg_.windows[w].begin - first) + 1;
    std::vector<double> scratch(n);
    WindowSimulator::End gap_end;
    // No pulse (force 0); the mesh angle is referenced to this window's detected onset.
    const WindowSimulator::Impact none{seg_.windows[w].onset_s, 0.0, seg_.windows[w].mesh_hz, 1.0};
    sim.simulate(first, n, none, e.transient, scratch.data(), gap_end);
    return gap_end.transient;
  }
  const double t_end = static_cast<double>(pw.end - 1) / fs;
  const double t_begin = static_cast<double>(seg_.windows[w].begin) / fs;
  return sim.propagate(e.transient, t_begin - t_end, t_end);
}

void ModelFitter::simulate_window(const WindowSimulator& sim, std::size_t w, const FitParams& p, const Chain& c,
                                  std::vector<double>& out, WindowSimulator::End& end,
                                  std::vector<TraceSample>* trace) const {
  ModelState carried = carry(sim, w, c);
  // A window without a predecessor starts at rest; p.start_offset_m holds it at an offset instead
  // (a static deflection at v = 0: dry friction keeps it until the pulse releases the mesh).
  if (seg_.windows[w].predecessor < 0 && w < p.start_offset_m.size()) carried.x += p.start_offset_m[w];
  simulate_window(sim, w, p, carried, out, end, trace);
}

void ModelFitter::simulate_window(const WindowSimulator& sim, std::size_t w, const FitParams& p,
                                  const ModelState& carried, std::vector<double>& out, WindowSimulator::End& end,
                                  std::vector<TraceSample>* trace) const {
  const auto& win = seg_.windows[w];
  out.resize(win.end - win.begin);
  sim.simulate(win.begin, out.size(), impact(w, p), carried, out.data(), end, trace);
}

ModelFitter::Linearisation ModelFitter::linearise(const FitResult& fit) const {
  const WindowSimulator sim(rig_, physics(fit.layout, fit.params), seg_.sample_rate_hz);
  const std::size_t nw = seg_.windows.size();
  Linearisation lin;
  lin.states.resize(nw);
  lin.d_ln_force.resize(nw);
  lin.d_shift.resize(nw);
  Chain c;
  c.out.resize(nw);
  c.end.resize(nw);
  std::vector<double> m;
  WindowSimulator::End end;
  for (std::size_t w = 0; w < nw; ++w) {
    const ModelState carried = carry(sim, w, c);
    simulate_window(sim, w, fit.params, carried, c.out[w], c.end[w], &lin.states[w]);
    // The steps of FitProblem::df: 1e-6 in ln F, 1e-4 samples of onset.
    for (int which = 0; which < 2; ++which) {
      FitParams q = fit.params;
      const double h = which == 0 ? 1e-6 : 1e-4;
      if (which == 0) q.ln_force[w] += h;
      else q.shift[w] += h;
      simulate_window(sim, w, q, carried, m, end);
      auto& d = which == 0 ? lin.d_ln_force[w] : lin.d_shift[w];
      d.resize(m.size());
      for (std::size_t i = 0; i < m.size(); ++i) d[i] = (m[i] - c.out[w][i]) / h;
    }
  }
  return lin;
}

ModelFitter::Chain ModelFitter::evaluate(const std::vector<GlobalParameter>& layout, const FitParams& p) const {
  const WindowSimulator sim(rig_, physics(layout, p), seg_.sample_rate_hz);
  Chain c;
  c.out.resize(seg_.windows.size());
  c.end.resize(seg_.windows.size());
  for (std::size_t w = 0; w < seg_.windows.size(); ++w) simulate_window(sim, w, p, c, c.out[w], c.end[w]);
  return c;
}

void ModelFitter::initialise_nuisances(FitParams& p, const std::vector<GlobalParameter>& layout) const {
  // Grid over the onset shift (-0.6 .. +1.5 ms in 0.1 ms steps: the detector's onset accuracy, early
  // triggers at high noise included; a step is 0.54 rad at 860 Hz, well inside the LM basin of half a
  // period) with the amplitude by linear projection (exact for the linear model) at the starting physics.
  const std::size_t nw = seg_.windows.size();
  p.ln_force.assign(nw, 0.0);
  p.shift.assign(nw, 0.0);
  const WindowSimulator sim(rig_, physics(layout, p), seg_.sample_rate_hz);
  const double fs = seg_.sample_rate_hz;
  std::vector<double> m;
  double proj_sum = 0.0;
  std::vector<double> best_a(nw, 0.0);
  for (std::size_t w = 0; w < nw; ++w) {
    const auto& win = seg_.windows[w];
    m.resize(win.end - win.begin);
    double best = INFINITY;
    for (int k = -6; k <= 15; ++k) {
      const double shift = k * 0.0001 * fs;
      WindowSimulator::Impact imp{win.onset_s + shift / fs, rig_.impact_force_n, win.mesh_hz, 1.0};
      WindowSimulator::End end;
      sim.simulate(win.begin, m.size(), imp, {}, m.data(), end);
      double sy = 0.0, ss = 0.0;
      for (std::size_t i = 0; i < m.size(); ++i) {
        const double wt = seg_.weight[win.begin + i];
        sy += wt * y_[win.begin + i] * m[i];
        ss += wt * m[i] * m[i];
      }
      if (ss <= 0.0) continue;
      const double a = sy / ss;
      double rss = 0.0;
      for (std::size_t i = 0; i < m.size(); ++i) {
        const double r = y_[win.begin + i] - a * m[i];
        rss += seg_.weight[win.begin + i] * r * r;
      }
      if (rss < best) {
        best = rss;
        best_a[w] = a;
        p.shift[w] = shift;
      }
    }
    proj_sum += best_a[w];
  }
  p.polarity = proj_sum < 0.0 ? -1.0 : 1.0;
  for (std::size_t w = 0; w < nw; ++w)
    p.ln_force[w] = std::log(std::max(1e-6, p.polarity * best_a[w]));
}

// Least-squares problem over a subset of the parameters, in Eigen's MINPACK-style functor form.
struct FitProblem {
  enum { InputsAtCompileTime = Eigen::Dynamic, ValuesAtCompileTime = Eigen::Dynamic };
  using Scalar = double;
  using InputType = Eigen::VectorXd;
  using ValueType = Eigen::VectorXd;
  using JacobianType = Eigen::MatrixXd;

  const ModelFitter* fitter = nullptr;
  std::vector<GlobalParameter> layout;
  FitParams base;                  // values of the parameters not being fitted
  bool globals_free = true;
  std::vector<std::size_t> free_windows;  // nuisances fitted
  std::vector<std::size_t> row_windows;   // residual rows
  std::vector<std::size_t> row_offset;    // by window index, npos if not a row
  Eigen::Index rows = 0;
  double inv_sigma = 1.0;
  // Windows simulated per evaluation: the row windows and, back along the chain, the predecessors
  // whose carried tails they start from. A held-out window that carries into no row window (the last
  // of each run of impacts) cannot change a residual: skipping it leaves every number as it was.
  std::vector<char> needed;
  // The chain at the parameters of the latest residual evaluation: LM evaluates the residuals at a
  // point and then its Jacobian there, which starts from the same chain (compared exactly).
  mutable FitParams cached_p;
  mutable ModelFitter::Chain cached_chain;
  mutable bool cached = false;

  void setup() {
    const auto& seg = fitter->segmentation();
    row_offset.assign(seg.windows.size(), static_cast<std::size_t>(-1));
    needed.assign(seg.windows.size(), 0);
    rows = 0;
    for (std::size_t w : row_windows) {
      row_offset[w] = static_cast<std::size_t>(rows);
      rows += static_cast<Eigen::Index>(seg.windows[w].end - seg.windows[w].begin);
      needed[w] = 1;
    }
    // A predecessor always comes earlier in the record: one backward pass closes the set.
    for (std::size_t w = seg.windows.size(); w-- > 0;)
      if (needed[w] && seg.windows[w].predecessor >= 0) needed[static_cast<std::size_t>(seg.windows[w].predecessor)] = 1;
    inv_sigma = 1.0 / seg.noise_sd;
    cached = false;
  }
  /// Model output of the needed windows (ModelFitter::evaluate restricted to `needed`).
  ModelFitter::Chain chain(const FitParams& p) const {
    const auto& seg = fitter->segmentation();
    const WindowSimulator sim(fitter->rig(), fitter->physics(layout, p), seg.sample_rate_hz);
    ModelFitter::Chain c;
    c.out.resize(seg.windows.size());
    c.end.resize(seg.windows.size());
    for (std::size_t w = 0; w < seg.windows.size(); ++w)
      if (needed[w]) fitter->simulate_window(sim, w, p, c, c.out[w], c.end[w]);
    return c;
  }
  static bool same(const FitParams& a, const FitParams& b) {
    return a.polarity == b.polarity && a.pulse_shape == b.pulse_shape && a.u.size() == b.u.size() && a.u == b.u && a.ln_force == b.ln_force &&
           a.shift == b.shift && a.start_offset_m == b.start_offset_m;
  }
  const ModelFitter::Chain& chain_cached(const FitParams& p) const {
    if (!cached || !same(p, cached_p)) {
      cached_chain = chain(p);
      cached_p = p;
      cached = true;
    }
    return cached_chain;
  }
  int inputs() const {
    return (globals_free ? static_cast<int>(layout.size()) : 0) + 2 * static_cast<int>(free_windows.size());
  }
  int values() const { return static_cast<int>(rows); }

  FitParams unpack(const Eigen::VectorXd& x) const {
    FitParams p = base;
    Eigen::Index k = 0;
    if (globals_free)
      for (Eigen::Index i = 0; i < p.u.size(); ++i) p.u[i] = x[k++];
    for (std::size_t w : free_windows) {
      p.ln_force[w] = x[k++];
      p.shift[w] = x[k++];
    }
    return p;
  }
  Eigen::VectorXd pack(const FitParams& p) const {
    Eigen::VectorXd x(inputs());
    Eigen::Index k = 0;
    if (globals_free)
      for (Eigen::Index i = 0; i < p.u.size(); ++i) x[k++] = p.u[i];
    for (std::size_t w : free_windows) {
      x[k++] = p.ln_force[w];
      x[k++] = p.shift[w];
    }
    return x;
  }
  void fill_rows(std::size_t w, const std::vector<double>& m, double* dst) const {
    const auto& win = fitter->segmentation().windows[w];
    const auto y = fitter->data();
    const auto& wt = fitter->segmentation().weight;
    for (std::size_t i = 0; i < m.size(); ++i) dst[i] = wt[win.begin + i] * (y[win.begin + i] - m[i]) * inv_sigma;
  }
  void residuals(const ModelFitter::Chain& c, Eigen::VectorXd& f) const {
    for (std::size_t w : row_windows) fill_rows(w, c.out[w], f.data() + row_offset[w]);
  }
  int operator()(const Eigen::VectorXd& x, Eigen::VectorXd& f) const {
    residuals(chain_cached(unpack(x)), f);
    return 0;
  }
  int df(const Eigen::VectorXd& x, Eigen::MatrixXd& J) const {
    const FitParams p = unpack(x);
    const ModelFitter::Chain& c = chain_cached(p);
    Eigen::VectorXd f0(rows), f1(rows);
    residuals(c, f0);
    J.setZero(rows, inputs());
    Eigen::Index col = 0;
    // Forward differences. Steps: 1e-6 in u for globals (a relative change of 1e-6 in a ln/logistic
    // parameter, ~1e4 times the round-off of the residuals in σ units) and for ln F; 1e-4 samples for
    // the onset (a phase change of 1e-5 rad at 860 Hz, 51.2 kHz).
    if (globals_free) {
      for (Eigen::Index i = 0; i < p.u.size(); ++i, ++col) {
        FitParams q = p;
        const double h = 1e-6 * std::max(1.0, std::abs(p.u[i]));
        q.u[i] += h;
        // A ln parameter beyond the clamp at its bound (LM may step there) keeps its value under the
        // step, so every residual stays as it is: the column is exactly zero, as simulating would give.
        const GlobalParameter& g = layout[static_cast<std::size_t>(i)];
        if (to_value(g.transform, g.lo, g.hi, q.u[i]) == to_value(g.transform, g.lo, g.hi, p.u[i])) continue;
        residuals(chain(q), f1);
        J.col(col) = (f1 - f0) / h;
      }
    }
    const auto& seg = fitter->segmentation();
    const WindowSimulator sim(fitter->rig(), fitter->physics(layout, p), seg.sample_rate_hz);
    std::vector<double> m, m2;
    std::vector<double> r;
    for (std::size_t w : free_windows) {
      const ModelState carried = fitter->carry(sim, w, c);
      for (int which = 0; which < 2; ++which, ++col) {
        FitParams q = p;
        const double h = which == 0 ? 1e-6 : 1e-4;
        if (which == 0) q.ln_force[w] += h;
        else q.shift[w] += h;
        ModelFitter::Chain cq;
        cq.end = c.end;
        WindowSimulator::End end;
        fitter->simulate_window(sim, w, q, carried, m, end);
        if (row_offset[w] != static_cast<std::size_t>(-1)) {
          r.resize(m.size());
          fill_rows(w, m, r.data());
          for (std::size_t i = 0; i < m.size(); ++i) {
            const auto row = static_cast<Eigen::Index>(row_offset[w] + i);
            J(row, col) = (r[i] - f0[row]) / h;
          }
        }
        // The next window carries this impact's tail.
        if (w + 1 < seg.windows.size() && seg.windows[w + 1].predecessor == static_cast<int>(w) &&
            row_offset[w + 1] != static_cast<std::size_t>(-1)) {
          cq.end[w] = end;
          WindowSimulator::End end2;
          fitter->simulate_window(sim, w + 1, q, cq, m2, end2);
          r.resize(m2.size());
          fill_rows(w + 1, m2, r.data());
          for (std::size_t i = 0; i < m2.size(); ++i) {
            const auto row = static_cast<Eigen::Index>(row_offset[w + 1] + i);
            J(row, col) = (r[i] - f0[row]) / h;
          }
        }
      }
    }
    return 0;
  }
};

// The two nuisances of one window with the physics frozen and the carried tail of its predecessor
// given: residual rows of that window only (a few hundred rows, 2 unknowns).
struct WindowProblem {
  enum { InputsAtCompileTime = Eigen::Dynamic, ValuesAtCompileTime = Eigen::Dynamic };
  using Scalar = double;
  using InputType = Eigen::VectorXd;
  using ValueType = Eigen::VectorXd;
  using JacobianType = Eigen::MatrixXd;

  const ModelFitter* fitter = nullptr;
  const WindowSimulator* sim = nullptr;
  ModelState carried;  // into window w from the chain (fixed while its nuisances are fitted)
  FitParams* p = nullptr;
  std::size_t w = 0;
  Eigen::Index rows = 0;
  double inv_sigma = 1.0;
  mutable std::vector<double> m;
  // The output at the point of the latest residual evaluation: LM evaluates a point and then its
  // Jacobian there, and the refit ends with the output at its final point (compared exactly).
  mutable bool cached = false;
  mutable double cached_ln_force = 0.0, cached_shift = 0.0;
  mutable std::vector<double> cached_out;
  mutable WindowSimulator::End cached_end;

  int inputs() const { return 2; }
  int values() const { return static_cast<int>(rows); }
  /// Model output of window w at the nuisances (ln F, onset shift in samples).
  void simulate(double ln_force, double shift, std::vector<double>& out, WindowSimulator::End& end) const {
    const double keep_f = p->ln_force[w], keep_s = p->shift[w];
    p->ln_force[w] = ln_force;
    p->shift[w] = shift;
    fitter->simulate_window(*sim, w, *p, carried, out, end);
    p->ln_force[w] = keep_f;
    p->shift[w] = keep_s;
  }
  /// simulate at the point of the latest call, or the cached output if it is the same point.
  const std::vector<double>& output_at(double ln_force, double shift, WindowSimulator::End& end) const {
    if (!cached || ln_force != cached_ln_force || shift != cached_shift) {
      simulate(ln_force, shift, cached_out, cached_end);
      cached_ln_force = ln_force;
      cached_shift = shift;
      cached = true;
    }
    end = cached_end;
    return cached_out;
  }
  void residual(const std::vector<double>& out, double* dst) const {
    const auto& win = fitter->segmentation().windows[w];
    const auto y = fitter->data();
    const auto& wt = fitter->segmentation().weight;
    for (std::size_t i = 0; i < out.size(); ++i) dst[i] = wt[win.begin + i] * (y[win.begin + i] - out[i]) * inv_sigma;
  }
  int operator()(const Eigen::VectorXd& x, Eigen::VectorXd& f) const {
    WindowSimulator::End end;
    residual(output_at(x[0], x[1], end), f.data());
    return 0;
  }
  int df(const Eigen::VectorXd& x, Eigen::MatrixXd& J) const {
    // Forward differences with the steps of FitProblem::df (1e-6 in ln F, 1e-4 samples of onset).
    Eigen::VectorXd f0(rows), f1(rows);
    WindowSimulator::End end;
    residual(output_at(x[0], x[1], end), f0.data());
    J.resize(rows, 2);
    simulate(x[0] + 1e-6, x[1], m, end);
    residual(m, f1.data());
    J.col(0) = (f1 - f0) / 1e-6;
    simulate(x[0], x[1] + 1e-4, m, end);
    residual(m, f1.data());
    J.col(1) = (f1 - f0) / 1e-4;
    return 0;
  }
};

namespace {

/// Whether u puts global parameter g at a bound of its range: a ln parameter within 1e-3 of its ln
/// range of a bound (or beyond it, where the value is clamped), a logistic one within 1e-3 of its
/// range (|u| > 6.9). An angle has no bound.
bool at_bound(const GlobalParameter& g, double u) {
  if (g.transform == Transform::kLog)
    return u < std::log(g.lo) + 1e-3 * (std::log(g.hi) - std::log(g.lo)) ||
           u > std::log(g.hi) - 1e-3 * (std::log(g.hi) - std::log(g.lo));
  if (g.transform == Transform::kBounded) return std::abs(u) > 6.9;
  return false;
}

bool run_lm(FitProblem& prob, FitParams& p, int max_fev) {
  prob.setup();
  Eigen::VectorXd x = prob.pack(p);
  Eigen::LevenbergMarquardt<FitProblem> lm(prob);
  lm.parameters.maxfev = max_fev;
  // Relative tolerances of 1e-8 on the parameters and on the sum of squares: far below the
  // statistical uncertainty (a held-out χ² changes by < 1e-6 of its value).
  lm.parameters.xtol = 1e-6;
  lm.parameters.ftol = 1e-6;
  // Eigen's minimize(), one iteration at a time, with one more stop (kBoundCreepGain): a fit with a
  // global parameter at a bound of its range (at_bound) ends after two successive iterations that
  // each reduce χ² by less than that fraction. There the remaining progress is a creep: a logistic
  // parameter nears its bound only exponentially in u, and beyond the clamp of a ln amplitude its
  // phases are nearly flat directions, so MINPACK's test (1e-6) took 30-80 more iterations for a few
  // 1e-4 of χ² in all; the parameter is reported at its bound either way. A run still gaining
  // 1e-4 or more per iteration goes on, as before.
  constexpr double kBoundCreepGain = 1e-4;
  auto status = lm.minimizeInit(x);
  if (status == Eigen::LevenbergMarquardtSpace::ImproperInputParameters) {
    p = prob.unpack(x);
    return false;
  }
  int small_gains = 0;
  bool creep_stop = false;
  do {
    const double chi2_before = lm.fnorm * lm.fnorm;
    status = lm.minimizeOneStep(x);
    if (status != Eigen::LevenbergMarquardtSpace::Running) break;
    const double gain = 1.0 - lm.fnorm * lm.fnorm / chi2_before;
    small_gains = gain < kBoundCreepGain ? small_gains + 1 : 0;
    if (small_gains >= 2 && prob.globals_free) {
      for (std::size_t i = 0; i < prob.layout.size(); ++i)
        if (at_bound(prob.layout[i], x[static_cast<Eigen::Index>(i)])) creep_stop = true;
    }
  } while (!creep_stop);
  p = prob.unpack(x);
  return creep_stop || status == Eigen::LevenbergMarquardtSpace::RelativeReductionTooSmall ||
         status == Eigen::LevenbergMarquardtSpace::RelativeErrorTooSmall ||
         status == Eigen::LevenbergMarquardtSpace::RelativeErrorAndReductionTooSmall ||
         status == Eigen::LevenbergMarquardtSpace::CosinusTooSmall;
}

double chi2_of(const FitProblem& prob, const FitParams& p) {
  Eigen::VectorXd f(prob.rows);
  prob(prob.pack(p), f);
  return f.squaredNorm();
}

}  // namespace

bool ModelFitter::onset_grid(const WindowSimulator& sim, std::size_t w, const FitParams& p,
                             const ModelState& carried, double& ln_force, double& shift) const {
  // As initialise_nuisances, for one window at the given physics and carried tail: onset grid -0.6 ..
  // +1.5 ms in 0.1 ms steps, force by projection. Returns false if no grid point projects positively.
  const auto& win = seg_.windows[w];
  double best = INFINITY;
  std::vector<double> m;
  FitParams q = p;
  for (int k = -6; k <= 15; ++k) {
    q.ln_force[w] = 0.0;
    q.shift[w] = k * 0.0001 * seg_.sample_rate_hz;
    WindowSimulator::End end;
    simulate_window(sim, w, q, carried, m, end);
    double sy = 0.0, ss = 0.0;
    for (std::size_t i = 0; i < m.size(); ++i) {
      sy += seg_.weight[win.begin + i] * y_[win.begin + i] * m[i];
      ss += seg_.weight[win.begin + i] * m[i] * m[i];
    }
    if (!(ss > 0.0) || !(sy > 0.0)) continue;
    const double rss = -sy * sy / ss;  // Σ y² - (Σ y m)² / Σ m² up to the constant Σ y²
    if (rss < best) {
      best = rss;
      ln_force = std::log(sy / ss);
      shift = q.shift[w];
    }
  }
  return std::isfinite(best);
}

bool ModelFitter::start_values(const std::vector<GlobalParameter>& L, const FitResult* warm,
                               const std::vector<std::pair<std::string, double>>& start_overrides, FitParams& p) const {
  // Start values: the rig's ζ and c0, the candidates' starts, the user's settings; then a warm
  // start's values by name and the overrides. Returns whether the mesh phase came from `warm`.
  p.u = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(L.size()));
  p.pulse_shape = pulse_shape_;
  bool phase_known = false;
  for (std::size_t i = 0; i < L.size(); ++i) {
    double start = 0.0;
    if (L[i].name == "zeta") start = rig_.damping_ratio > 0.0 ? rig_.damping_ratio : 0.02;
    else if (L[i].name == "c0_n_per_m") start = 0.0;
    else if (L[i].name == "mesh_phase_rad") start = 0.0;
    else if (L[i].name == "pulse_duration_s") start = rig_.impact_duration_s;
    else {
      const CandidateSpec* c = find_candidate(L[i].effect);
      for (const auto& f : c->free)
        if (f.key == L[i].key) start = f.start;
      if (const auto it = settings_.find(L[i].name); it != settings_.end()) start = it->second.value;
    }
    double u = to_u(L[i].transform, L[i].lo, L[i].hi, start);
    if (warm != nullptr)
      for (std::size_t j = 0; j < warm->layout.size(); ++j)
        if (warm->layout[j].name == L[i].name) {
          u = warm->params.u[static_cast<Eigen::Index>(j)];
          if (L[i].name == "mesh_phase_rad") phase_known = true;
        }
    for (const auto& [name, value] : start_overrides)
      if (name == L[i].name) u = to_u(L[i].transform, L[i].lo, L[i].hi, value);
    p.u[static_cast<Eigen::Index>(i)] = u;
  }
  if (warm != nullptr) {
    p.ln_force = warm->params.ln_force;
    p.shift = warm->params.shift;
    p.polarity = warm->params.polarity;
  } else {
    initialise_nuisances(p, L);
  }
  return phase_known;
}

void ModelFitter::restart_bad_windows(FitProblem& train, FitParams& p, int budget, FitResult& res) const {
  const auto& L = res.layout;
  // Training windows left well above the noise (2x its power) may sit in a wrong onset basin: their
  // start came from the grid at the starting physics (a Duffing start far from the truth, say). Each
  // is restarted from the onset grid at the fitted physics if that fits it better, then LM again.
  {
    const WindowSimulator sim(rig_, physics(L, p), seg_.sample_rate_hz);
    // The training windows and their predecessors at p: LM's latest evaluation, as a rule.
    const Chain& c = train.chain_cached(p);
    bool changed = false;
    std::vector<double> scratch;
    auto power_of = [&](std::size_t w, const std::vector<double>& m) {
      const auto& win = seg_.windows[w];
      double r2 = 0.0, n = 0.0;
      for (std::size_t i = 0; i < m.size(); ++i) {
        const double r = y_[win.begin + i] - m[i];
        r2 += seg_.weight[win.begin + i] * r * r;
        n += seg_.weight[win.begin + i];
      }
      return r2 / std::max(1.0, n) / (seg_.noise_sd * seg_.noise_sd);
    };
    for (std::size_t w : train.row_windows) {
      const double power = power_of(w, c.out[w]);
      if (power <= 2.0) continue;
      const ModelState carried = carry(sim, w, c);
      FitParams q = p;
      if (!onset_grid(sim, w, p, carried, q.ln_force[w], q.shift[w])) continue;
      WindowSimulator::End end;
      simulate_window(sim, w, q, carried, scratch, end);
      if (power_of(w, scratch) < power) {
        p.ln_force[w] = q.ln_force[w];
        p.shift[w] = q.shift[w];
        changed = true;
      }
    }
    if (changed) {
      train.base = p;
      const bool conv = run_lm(train, p, budget);
      res.converged = res.converged || conv;
      train.base = p;
    }
  }
}

void ModelFitter::training_statistics(const FitProblem& train, const FitParams& p, FitResult& res) const {
  const auto& L = res.layout;
  // Training statistics, covariance from the Jacobian at the optimum.
  {
    Eigen::VectorXd f(train.rows);
    const Eigen::VectorXd x = train.pack(p);
    train(x, f);
    Eigen::MatrixXd J;
    train.df(x, J);
    res.train_chi2 = f.squaredNorm();
    double n_used = 0.0;
    for (std::size_t w : train.row_windows)
      for (std::uint64_t i = seg_.windows[w].begin; i < seg_.windows[w].end; ++i) n_used += seg_.weight[i];
    res.train_n = n_used;
    // Globals and the training windows' nuisances: held-out nuisances freed for dry friction (fit())
    // reach these rows only through the carried offset, and counting them would charge a friction
    // candidate 2 ln n per held-out impact that the linear model it is compared with does not pay.
    res.free_parameters = train.inputs() - 2 * static_cast<int>(train.free_windows.size() - train.row_windows.size());
    // A value chosen from the data by a scan (diagnose's step time) is a parameter as well.
    for (const auto& [name, s] : settings_)
      if (s.chosen_from_data && std::find(res.effects.begin(), res.effects.end(), name.substr(0, name.find('.'))) != res.effects.end())
        ++res.free_parameters;
    res.bic = n_used * std::log(res.train_chi2 / n_used) + res.free_parameters * std::log(n_used);
    const double s2 = res.train_chi2 / std::max(1.0, n_used - res.free_parameters);
    const Eigen::MatrixXd jtj = J.transpose() * J;
    const Eigen::MatrixXd jtj_inv = jtj.completeOrthogonalDecomposition().pseudoInverse();
    Eigen::MatrixXd cov = s2 * jtj_inv;
    const auto ng = static_cast<Eigen::Index>(L.size());
    // The held start offset of dry friction, a systematic term. A window without a predecessor starts
    // at rest at x = 0 in the model, but in a record that begins mid-run (or after a gap) the impact
    // before it has left the mesh held anywhere in the friction band |x| <= F_c / c0, and that offset
    // shapes the window's response by up to F_c / c0 of its peak (6 % at 50 N). It cannot be fitted: in
    // one window the released offset adds a cosine-phase free oscillation that the onset and the force
    // already describe almost exactly (README "Interval coverage"). Its effect on the estimate is
    // propagated instead: x0_k uniform on the band (sd b / sqrt 3, b = F_c / c0), independent per
    // window, moves the least-squares optimum by δu_k = -(JᵀJ)⁺ Jᵀ j_k sd_x0, j_k the residuals'
    // change per metre of offset in window k's start (a central secant over ±sd_x0, the average slope
    // over the band where the stick/slip makes it nonlinear), and cov += Σ_k δu_k δu_kᵀ. Costs two
    // evaluations of the training chain per such window.
    std::vector<double> offset_var(static_cast<std::size_t>(ng), 0.0);
    const WindowSimulator sim(rig_, physics(L, p), seg_.sample_rate_hz);
    const double band_m = sim.has_dry_friction() ? sim.stick_limit_n() / physics(L, p).c0_n_per_m : 0.0;
    if (band_m > 0.0 && train.globals_free) {
      const double sd_x0 = band_m / std::sqrt(3.0);
      Eigen::VectorXd fp(train.rows), fm(train.rows);
      for (std::size_t w = 0; w < seg_.windows.size(); ++w) {
        // Every window without a predecessor whose output reaches a training row (its own, or through
        // the carried state of its successors).
        if (seg_.windows[w].predecessor >= 0 || !train.needed[w]) continue;
        FitParams q = p;
        q.start_offset_m.assign(seg_.windows.size(), 0.0);
        q.start_offset_m[w] = sd_x0;
        train.residuals(train.chain(q), fp);
        q.start_offset_m[w] = -sd_x0;
        train.residuals(train.chain(q), fm);
        // Residual change for an offset of one sd: (f(+sd) - f(-sd)) / 2.
        const Eigen::VectorXd j = 0.5 * (fp - fm);
        const Eigen::VectorXd du = -jtj_inv * (J.transpose() * j);
        cov += du * du.transpose();
        for (Eigen::Index i = 0; i < ng; ++i) offset_var[static_cast<std::size_t>(i)] += du[i] * du[i];
      }
    }
    res.correlation = Eigen::MatrixXd::Identity(ng, ng);
    for (Eigen::Index i = 0; i < ng; ++i) {
      const auto& g = L[static_cast<std::size_t>(i)];
      const double u = p.u[i];
      const double sdu = std::sqrt(std::max(0.0, cov(i, i)));
      ParameterEstimate e;
      e.name = g.name;
      auto value_of = [&](double uu) {
        const double v = to_value(g.transform, g.lo, g.hi, uu);
        return g.name == "c0_n_per_m" ? rig_.mean_mesh_stiffness_n_per_m * std::exp(v) : v;
      };
      e.value = value_of(u);
      if (g.name == "mesh_phase_rad") e.value = std::remainder(e.value, 2.0 * std::numbers::pi);
      const double dv = (value_of(u + 1e-6) - value_of(u - 1e-6)) / 2e-6;
      e.sd = std::abs(dv) * sdu;
      e.offset_var = dv * dv * offset_var[static_cast<std::size_t>(i)];
      const double a = value_of(u - 1.96 * sdu), b = value_of(u + 1.96 * sdu);
      e.ci95_lo = std::min(a, b) + (g.name == "mesh_phase_rad" ? e.value - u : 0.0);
      e.ci95_hi = std::max(a, b) + (g.name == "mesh_phase_rad" ? e.value - u : 0.0);
      e.at_bound = at_bound(g, u);
      res.estimates.push_back(e);
      for (Eigen::Index j = 0; j < ng; ++j) {
        const double d = std::sqrt(cov(i, i) * cov(j, j));
        res.correlation(i, j) = d > 0.0 ? cov(i, j) / d : (i == j ? 1.0 : 0.0);
      }
    }
  }
}

ModelFitter::Chain ModelFitter::heldout_refit(const std::vector<GlobalParameter>& L, FitParams& p) const {
  const std::size_t nw = seg_.windows.size();
  // Held-out: physics frozen, every impact's nuisances refitted (so the carried tails are right),
  // error on held-out rows only. Window by window in time order, each with its predecessor's final
  // tail: the nuisances of a window reach the next one only through that small tail, so this is the
  // joint optimum up to the tail's second-order effect, at a cost linear in the number of impacts
  // (the joint problem's dense QR grows with its cube).
  {
    const WindowSimulator sim(rig_, physics(L, p), seg_.sample_rate_hz);
    Chain chain;
    chain.out.resize(nw);
    chain.end.resize(nw);
    for (std::size_t w = 0; w < nw; ++w) {
      WindowProblem wp;
      wp.fitter = this;
      wp.sim = &sim;
      wp.carried = carry(sim, w, chain);
      wp.p = &p;
      wp.w = w;
      wp.rows = static_cast<Eigen::Index>(seg_.windows[w].end - seg_.windows[w].begin);
      wp.inv_sigma = 1.0 / seg_.noise_sd;
      auto solve = [&](Eigen::VectorXd& x) {
        Eigen::LevenbergMarquardt<WindowProblem> lm(wp);
        lm.parameters.maxfev = 60;  // 20 Jacobians' worth, as the joint refit's budget per unknown
        lm.parameters.xtol = 1e-6;
        lm.parameters.ftol = 1e-6;
        lm.minimize(x);
        Eigen::VectorXd f(wp.rows);
        wp(x, f);
        double n_used = 0.0;
        for (std::uint64_t i = seg_.windows[w].begin; i < seg_.windows[w].end; ++i) n_used += seg_.weight[i];
        return f.squaredNorm() / std::max(1.0, n_used);
      };
      Eigen::VectorXd x(2);
      x << p.ln_force[w], p.shift[w];
      const double power = solve(x);
      // A window left well above the noise (2x its power) may sit in a wrong onset basin (its start
      // came from a fit at other physics): restart it from the onset grid at the fitted physics.
      if (power > 2.0) {
        Eigen::VectorXd g(2);
        if (onset_grid(sim, w, p, wp.carried, g[0], g[1]) && solve(g) < power) x = g;
      }
      chain.out[w] = wp.output_at(x[0], x[1], chain.end[w]);
      p.ln_force[w] = x[0];
      p.shift[w] = x[1];
    }
    return chain;
  }
}

void ModelFitter::heldout_statistics(const FitParams& p, const Chain& c, FitResult& res) const {
  const std::size_t nw = seg_.windows.size();
  res.params = p;
  res.model = c.out;
  res.impact_power.assign(nw, 0.0);
  double sum_r2 = 0.0, sum_n = 0.0, sum_y = 0.0, sum_y2 = 0.0;
  const double var = seg_.noise_sd * seg_.noise_sd;
  for (std::size_t w = 0; w < nw; ++w) {
    const auto& win = seg_.windows[w];
    double r2 = 0.0, n = 0.0;
    for (std::size_t i = 0; i < c.out[w].size(); ++i) {
      const double wt = seg_.weight[win.begin + i];
      const double r = y_[win.begin + i] - c.out[w][i];
      r2 += wt * r * r;
      n += wt;
      if (is_heldout(w)) {
        sum_y += wt * y_[win.begin + i];
        sum_y2 += wt * y_[win.begin + i] * y_[win.begin + i];
      }
    }
    res.impact_power[w] = n > 0.0 ? r2 / n / var : 0.0;
    if (is_heldout(w)) {
      sum_r2 += r2;
      sum_n += n;
    }
  }
  res.heldout_n = sum_n;
  res.heldout_excess = sum_n > 0.0 ? sum_r2 / sum_n / var - 1.0 : 0.0;
  const double ss_tot = sum_y2 - (sum_n > 0.0 ? sum_y * sum_y / sum_n : 0.0);
  res.fit_percent = ss_tot > 0.0 ? 100.0 * (1.0 - std::sqrt(sum_r2 / ss_tot)) : 0.0;
}

FitResult ModelFitter::fit(const std::vector<std::string>& effects, const FitResult* warm,
                           const std::vector<std::pair<std::string, double>>& start_overrides,
                           bool pulse_with_mesh) const {
  FitResult res;
  res.effects = effects;
  res.layout = layout(effects, pulse_with_mesh);
  const auto& L = res.layout;
  FitParams p;
  const bool phase_known = start_values(L, warm, start_overrides, p);

  const std::size_t nw = seg_.windows.size();
  FitProblem train;
  train.fitter = this;
  train.layout = L;
  // With dry friction the held-out windows' nuisances are free in the training fit too (their rows
  // stay out of it). Each training window starts from its held-out predecessor's final state, and
  // where dry friction stops the mesh that state is an offset anywhere in the friction band (up to
  // F_c / c0), set by the predecessor's force and onset: a few % of the next response's peak, not the
  // small decayed tail of a smooth model. Held at their starting values (the onset grid at the
  // starting physics) they fed wrong offsets into every training window, and the physics absorbed
  // them: force_n 3-4 % low and ζ 5-6 % high on every seed, about five standard deviations, also on
  // ridgewatch's own simulator; at the true held-out nuisances the same fit lands on the truth.
  // Their rows stay held out, so the held-out judgement is unchanged; they reach the training
  // rows only through the carried state.
  const bool free_heldout = friction_carry_fit_ && WindowSimulator(rig_, physics(L, p), seg_.sample_rate_hz).has_dry_friction();
  for (std::size_t w = 0; w < nw; ++w) {
    if (!is_heldout(w)) train.row_windows.push_back(w);
    if (!is_heldout(w) || free_heldout) train.free_windows.push_back(w);
  }
  // Budget: 40 Jacobians' worth of evaluations is ample for this smooth problem (typically 5–15 LM
  // steps) and bounds the time of a pathological candidate.
  const int budget = 40 * (train.inputs() + 1);

  // Mesh phase φ_z: the fit is periodic and multimodal in it; start from the best of four phases.
  std::size_t phase_index = L.size();
  for (std::size_t i = 0; i < L.size(); ++i)
    if (L[i].name == "mesh_phase_rad") phase_index = i;
  if (phase_index < L.size() && !phase_known) {
    double best = INFINITY;
    FitParams best_p = p;
    for (int k = 0; k < 4; ++k) {
      FitParams q = p;
      q.u[static_cast<Eigen::Index>(phase_index)] = k * std::numbers::pi / 2.0 - std::numbers::pi * 0.75;
      train.base = q;
      run_lm(train, q, 8 * (train.inputs() + 1));
      const double c2 = chi2_of(train, q);
      if (c2 < best) {
        best = c2;
        best_p = q;
      }
    }
    p = best_p;
  }
  train.base = p;
  res.converged = run_lm(train, p, budget);
  train.base = p;
  restart_bad_windows(train, p, budget, res);

  training_statistics(train, p, res);

  const Chain heldout = heldout_refit(L, p);
  heldout_statistics(p, heldout, res);
  return res;
}

FitResult fit_pulse_shapes(const ModelFitter& fitter, const std::vector<std::string>& effects, const FitResult* warm,
                           const std::vector<std::pair<std::string, double>>& start_overrides, bool pulse_with_mesh) {
  FitResult best;
  bool have = false;
  for (const model::PulseShape shape : {model::PulseShape::kHalfSine, model::PulseShape::kHann}) {
    ModelFitter f = fitter;
    f.set_pulse_shape(shape);
    FitResult r = f.fit(effects, warm, start_overrides, pulse_with_mesh);
    if (!have || r.train_chi2 < best.train_chi2) best = std::move(r);
    have = true;
  }
  return best;
}

}  // namespace ridgewatch::diagnosis
