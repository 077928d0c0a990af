#include "core/model/simulator.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <numbers>
#include <set>
#include <sstream>
#include <stdexcept>

namespace ridgewatch::model {

void SimulationSettings::validate() const {
  auto fail = [](const std::string& field, const std::string& rule, double got) {
    std::ostringstream os;
    os << field << ": must be " << rule << " (got " << got << ")";
    throw std::invalid_argument(os.str());
  };
  if (!std::isfinite(duration_s) || !(duration_s > 0.0)) fail("duration_s", "> 0", duration_s);
  if (!std::isfinite(sample_rate_hz) || !(sample_rate_hz > 0.0)) fail("sample_rate_hz", "> 0", sample_rate_hz);
  if (!std::isfinite(min_internal_rate_hz) || !(min_internal_rate_hz > 0.0))
    fail("min_internal_rate_hz", "> 0", min_internal_rate_hz);
  if (duration_s * sample_rate_hz > 2.0e9) fail("duration_s * sample_rate_hz", "<= 2e9", duration_s * sample_rate_hz);
  if (!std::isfinite(initial_displacement_m)) fail("initial_displacement_m", "finite", initial_displacement_m);
  if (!std::isfinite(initial_velocity_m_per_s)) fail("initial_velocity_m_per_s", "finite", initial_velocity_m_per_s);
  if (!std::isfinite(truth_interval_s) || !(truth_interval_s > 0.0)) fail("truth_interval_s", "> 0", truth_interval_s);
  if (!std::isfinite(tacho_pulse_s) || tacho_pulse_s < 0.0) fail("tacho_pulse_s", ">= 0", tacho_pulse_s);
}

namespace {

// State vector: x, q̇, p, ṗ, θ1.
using State = std::array<double, 5>;
constexpr std::size_t kX = 0, kV = 1, kP = 2, kPdot = 3, kTheta = 4;

int sign_of(double g) { return g >= 0.0 ? 1 : -1; }

struct Impact {
  double t_s;
  double peak_force_n;
};

class Dynamics {
 public:
  Dynamics(const RigParameters& rig, std::vector<std::unique_ptr<Effect>>& effects)
      : effects_(effects),
        m_red_kg_(rig.reduced_mass_kg()),
        c0_n_per_m_(rig.mean_mesh_stiffness_n_per_m),
        zeta_(rig.damping_ratio),
        critical_n_s_per_m_(2.0 * std::sqrt(rig.mean_mesh_stiffness_n_per_m * rig.reduced_mass_kg())),
        static_force_n_(rig.static_mesh_force_n()),
        static_deflection_m_(rig.static_deflection_m()),
        teeth_(static_cast<double>(rig.pinion_teeth)),
        speed_hz_(rig.pinion_speed_hz()),
        pulse_s_(rig.impact_duration_s) {
    for (std::size_t i = 0; i < effects_.size(); ++i) {
      if (effects_[i]->has_switching()) switching_.push_back(i);
      stick_limit_n_ += effects_[i]->stick_force_limit_n();
      if (auto m = effects_[i]->auxiliary_mode()) {
        const double w = 2.0 * std::numbers::pi * m->frequency_hz;
        aux_w2_ = w * w;
        aux_2zw_ = 2.0 * m->damping_ratio * w;
        aux_participation_ = m->participation;
      }
    }
    regimes_.assign(effects_.size(), 1);
  }

  double speed_factor(double t_s) const {
    double f = 1.0;
    for (const auto& e : effects_) f *= e->speed_factor(t_s);
    return f;
  }
  double shaft_speed_hz(double t_s) const { return speed_hz_ * speed_factor(t_s); }

  /// ζ(t), clamped to [0, 0.99] so that a drift never makes the mesh unstable or overdamped.
  double damping_ratio(double t_s) const {
    double z = zeta_;
    for (const auto& e : effects_) z += e->damping_ratio_offset(t_s);
    return std::clamp(z, 0.0, 0.99);
  }

  void set_impacts(const std::vector<Impact>* impacts) { impacts_ = impacts; }

  /// Half-sine pulses: F_k sin(π (t - t_k)/τ) on [t_k, t_k + τ]. `cursor_` is the first pulse that
  /// has not ended before the current step.
  double impact_force_n(double t_s) const {
    if (impacts_ == nullptr) return 0.0;
    double f = 0.0;
    for (std::size_t k = cursor_; k < impacts_->size(); ++k) {
      const Impact& imp = (*impacts_)[k];
      if (imp.t_s > t_s) break;
      const double u = (t_s - imp.t_s) / pulse_s_;
      if (u < 1.0) f += imp.peak_force_n * std::sin(std::numbers::pi * u);
    }
    return f;
  }
  void advance_cursor(double t_s) {
    if (impacts_ == nullptr) return;
    while (cursor_ < impacts_->size() && (*impacts_)[cursor_].t_s + pulse_s_ <= t_s) ++cursor_;
  }
  /// The next pulse boundary (onset or end) strictly after t, or +inf.
  double next_pulse_boundary(double t_s) const {
    if (impacts_ == nullptr) return INFINITY;
    for (std::size_t k = cursor_; k < impacts_->size(); ++k) {
      const double on = (*impacts_)[k].t_s, off = on + pulse_s_;
      if (on > t_s) return on;
      if (off > t_s) return off;
    }
    return INFINITY;
  }

  /// Time since the onset of the latest pulse at or before t (t itself before the first). The pulses
  /// from `cursor_` on have not ended before the current step, so the latest onset is the last of
  /// them at or before t, or the one before `cursor_`.
  double time_since_impact(double t_s) const {
    if (impacts_ == nullptr) return t_s;
    std::size_t k = cursor_;
    while (k < impacts_->size() && (*impacts_)[k].t_s <= t_s) ++k;
    return k == 0 ? t_s : t_s - (*impacts_)[k - 1].t_s;
  }

  MeshState mesh_state(double t_s, const State& s) const {
    MeshState m;
    m.t_s = t_s;
    m.t_since_impact_s = time_since_impact(t_s);
    m.mesh_angle_rad = teeth_ * s[kTheta];
    m.x_m = s[kX];
    m.v_m_per_s = s[kV];
    double e = 0.0, de = 0.0;
    for (const auto& eff : effects_) eff->add_transmission_error(m.mesh_angle_rad, e, de);
    m.deflection_m = static_deflection_m_ + s[kX] + e;
    return m;
  }

  /// Net force on the mesh coordinate (N), Eq. A1, with the regimes frozen. `include_stick_effects`
  /// false leaves out the resisting force of effects that can stick (for the stick test).
  double mesh_coordinate_force_n(double t_s, const State& s, bool include_stick_effects) const {
    const double theta_dot = 2.0 * std::numbers::pi * shaft_speed_hz(t_s);
    const double mesh_angle = teeth_ * s[kTheta];
    double dc = 0.0, dc_static = 0.0, e = 0.0, de_dangle = 0.0;
    double factor = 1.0;
    for (std::size_t i = 0; i < effects_.size(); ++i) {
      dc += effects_[i]->stiffness_variation_n_per_m(mesh_angle);
      dc_static += effects_[i]->static_stiffness_variation_n_per_m(mesh_angle);
      effects_[i]->add_transmission_error(mesh_angle, e, de_dangle);
      factor *= effects_[i]->mesh_force_factor(regimes_[i]);
    }
    MeshState m;
    m.t_s = t_s;
    m.t_since_impact_s = time_since_impact(t_s);
    m.mesh_angle_rad = mesh_angle;
    m.x_m = s[kX];
    m.v_m_per_s = s[kV];
    m.deflection_m = static_deflection_m_ + s[kX] + e;  // δ = q_s + x + e
    const double deflection_rate = s[kV] + de_dangle * teeth_ * theta_dot;
    const double damping = damping_ratio(t_s) * critical_n_s_per_m_;
    // Eq. A1: c_z(t) (q + e) + d_z (q̇ + ė), switched off (in part) while the teeth are separated;
    // the static deflection sees only the variation's static part (equal to dc unless relieved).
    const double elastic = dc_static == dc ? (c0_n_per_m_ + dc) * m.deflection_m
                                           : (c0_n_per_m_ + dc) * (s[kX] + e) + (c0_n_per_m_ + dc_static) * static_deflection_m_;
    double force = static_force_n_ + impact_force_n(t_s) - factor * (elastic + damping * deflection_rate);
    for (std::size_t i = 0; i < effects_.size(); ++i) {
      if (!include_stick_effects && effects_[i]->stick_force_limit_n() > 0.0) continue;
      force -= effects_[i]->resisting_force_n(m, regimes_[i]);
    }
    return force;
  }

  State derivative(double t_s, const State& s) const {
    State d{};
    if (stuck_) {
      d[kX] = 0.0;
      d[kV] = 0.0;
    } else {
      d[kX] = s[kV];
      d[kV] = mesh_coordinate_force_n(t_s, s, true) / m_red_kg_;
    }
    // Auxiliary mode (second_mode): p̈ + 2ζ2ω2 ṗ + ω2² p = participation F_imp / m_red.
    d[kP] = s[kPdot];
    d[kPdot] = aux_participation_ * impact_force_n(t_s) / m_red_kg_ - aux_2zw_ * s[kPdot] - aux_w2_ * s[kP];
    d[kTheta] = 2.0 * std::numbers::pi * shaft_speed_hz(t_s);
    return d;
  }

  State rk4(double t_s, const State& s, double h) const {
    const State k1 = derivative(t_s, s);
    State tmp;
    for (std::size_t i = 0; i < s.size(); ++i) tmp[i] = s[i] + 0.5 * h * k1[i];
    const State k2 = derivative(t_s + 0.5 * h, tmp);
    for (std::size_t i = 0; i < s.size(); ++i) tmp[i] = s[i] + 0.5 * h * k2[i];
    const State k3 = derivative(t_s + 0.5 * h, tmp);
    for (std::size_t i = 0; i < s.size(); ++i) tmp[i] = s[i] + h * k3[i];
    const State k4 = derivative(t_s + h, tmp);
    State out;
    for (std::size_t i = 0; i < s.size(); ++i) out[i] = s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    return out;
  }

  /// True when a switching function has left the sign of its frozen regime at `s`.
  bool regime_violated(double t_s, const State& s) const {
    if (switching_.empty()) return false;
    const MeshState m = mesh_state(t_s, s);
    for (std::size_t i : switching_) {
      if (stuck_ && effects_[i]->stick_force_limit_n() > 0.0) continue;
      if (sign_of(effects_[i]->switching_function(m)) != regimes_[i]) return true;
    }
    return false;
  }

  /// Sets the regimes from the state; for effects that can stick, a stick test when q̇ has just
  /// changed sign (or is zero): the mesh coordinate stays at rest while the other forces stay within
  /// the static friction limit.
  void update_regimes(double t_s, State& s, bool velocity_reversal) {
    const MeshState m = mesh_state(t_s, s);
    for (std::size_t i : switching_) regimes_[i] = sign_of(effects_[i]->switching_function(m));
    if (stick_limit_n_ > 0.0 && velocity_reversal) {
      State rest = s;
      rest[kV] = 0.0;
      const double other = mesh_coordinate_force_n(t_s, rest, false);
      if (std::abs(other) <= stick_limit_n_) {
        stuck_ = true;
        s[kV] = 0.0;
      }
    }
  }

  /// While stuck: release when the other forces exceed the static limit; slide in their direction.
  void check_release(double t_s, const State& s) {
    if (!stuck_) return;
    const double other = mesh_coordinate_force_n(t_s, s, false);
    if (std::abs(other) > stick_limit_n_) {
      stuck_ = false;
      for (std::size_t i : switching_)
        if (effects_[i]->stick_force_limit_n() > 0.0) regimes_[i] = sign_of(other);
    }
  }

  /// Advances `s` from t to t + h, splitting at pulse boundaries and located regime changes.
  void advance(double& t_s, State& s, double h, std::uint64_t& events) {
    const double t_end = t_s + h;
    int splits = 0;
    while (t_s < t_end) {
      advance_cursor(t_s);
      check_release(t_s, s);
      double step = t_end - t_s;
      if (++splits > 64) {
        // Chattering between regimes (never seen in the catalogue): finish the step with the regimes
        // frozen rather than loop; the error is then that of an unlocated switch within one step.
        s = rk4(t_s, s, step);
        break;
      }
      const double boundary = next_pulse_boundary(t_s);
      if (boundary < t_end) step = boundary - t_s;
      State next = rk4(t_s, s, step);
      if (!regime_violated(t_s + step, next)) {
        s = next;
        t_s = (step == t_end - t_s) ? t_end : t_s + step;
        continue;
      }
      // Event location: bisection on the step fraction until the crossing is bracketed within
      // 2^-30 of the step (<= 5e-15 s at 200 kHz), then continue from just past it.
      double lo = 0.0, hi = 1.0;
      for (int it = 0; it < 30; ++it) {
        const double mid = 0.5 * (lo + hi);
        if (regime_violated(t_s + mid * step, rk4(t_s, s, mid * step)))
          hi = mid;
        else
          lo = mid;
      }
      const bool was_moving = !stuck_;
      const int v_sign_before = sign_of(s[kV]);
      s = rk4(t_s, s, hi * step);
      t_s += hi * step;
      ++events;
      update_regimes(t_s, s, was_moving && sign_of(s[kV]) != v_sign_before);
    }
    t_s = t_end;
  }

  /// Initial regimes, with a stick test when the system starts at rest.
  void initialise(double t_s, State& s) {
    update_regimes(t_s, s, s[kV] == 0.0);
  }

  double output_quantity(double t_s, const State& s, SensorQuantity q) const {
    switch (q) {
      case SensorQuantity::kDisplacement: return s[kX] + s[kP];
      case SensorQuantity::kAcceleration: {
        const State d = derivative(t_s, s);
        return d[kV] + d[kPdot];
      }
      case SensorQuantity::kVelocity: break;
    }
    return s[kV] + s[kPdot];
  }

 private:
  std::vector<std::unique_ptr<Effect>>& effects_;
  double m_red_kg_, c0_n_per_m_, zeta_, critical_n_s_per_m_, static_force_n_, static_deflection_m_;
  double teeth_, speed_hz_, pulse_s_;
  std::vector<std::size_t> switching_;
  std::vector<int> regimes_;
  double stick_limit_n_ = 0.0;
  bool stuck_ = false;
  double aux_w2_ = 0.0, aux_2zw_ = 0.0, aux_participation_ = 0.0;
  const std::vector<Impact>* impacts_ = nullptr;
  std::size_t cursor_ = 0;
};

}  // namespace

SimulationResult simulate(const RigParameters& rig, const std::vector<EffectSpec>& specs,
                          const SimulationSettings& settings) {
  rig.validate();
  settings.validate();

  SimulationResult result;
  std::vector<std::unique_ptr<Effect>> effects;
  std::set<std::string> names;
  int aux_modes = 0;
  for (const auto& spec : specs) {
    if (!names.insert(spec.name).second)
      throw std::invalid_argument("effect " + spec.name + " given twice");
    ResolvedEffect resolved = resolve_effect(spec);
    effects.push_back(resolved.descriptor->create(resolved.values, rig));
    if (effects.back()->auxiliary_mode()) ++aux_modes;
    result.effects.push_back({std::move(resolved), {}});
  }
  if (aux_modes > 1) throw std::invalid_argument("at most one effect may add an auxiliary mode");

  Dynamics dyn(rig, effects);
  const double rate_hz = settings.sample_rate_hz;
  const auto n_samples = static_cast<std::size_t>(std::llround(settings.duration_s * rate_hz));
  const int substeps = std::max(1, static_cast<int>(std::ceil(settings.min_internal_rate_hz / rate_hz - 1e-9)));
  const double h_s = 1.0 / (rate_hz * substeps);
  const double duration_s = static_cast<double>(n_samples) / rate_hz;
  result.sample_rate_hz = rate_hz;
  result.substeps_per_sample = substeps;

  // Pre-pass: pinion angle θ1(t) = 2π ∫ n(t) dt (same RK4 step), revolution marks at θ1 = 2πk, impact
  // onsets at θ1 = crack angle + 2πk; crossings interpolated linearly within a step.
  std::vector<Impact> impacts;
  Rng jitter_rng = Rng::stream(settings.seed, 0);
  {
    const double two_pi = 2.0 * std::numbers::pi;
    const double crack = std::fmod(std::fmod(rig.crack_angle_rad, two_pi) + two_pi, two_pi);
    double theta = 0.0;
    double next_mark = 0.0, next_impact = crack;
    const auto total_steps = static_cast<std::uint64_t>(n_samples) * static_cast<std::uint64_t>(substeps);
    for (std::uint64_t n = 0; n <= total_steps; ++n) {
      const double t0 = static_cast<double>(n) * h_s;
      const double w0 = two_pi * dyn.shaft_speed_hz(t0);
      const double wm = two_pi * dyn.shaft_speed_hz(t0 + 0.5 * h_s);
      const double w1 = two_pi * dyn.shaft_speed_hz(t0 + h_s);
      const double theta1 = theta + h_s / 6.0 * (w0 + 4.0 * wm + w1);
      while (next_mark <= theta1) {
        const double t = t0 + h_s * std::clamp((next_mark - theta) / (theta1 - theta), 0.0, 1.0);
        if (t < duration_s) result.revolution_times_s.push_back(t);
        next_mark += two_pi;
      }
      while (next_impact <= theta1) {
        const double t = t0 + h_s * std::clamp((next_impact - theta) / (theta1 - theta), 0.0, 1.0);
        if (t < duration_s && settings.impacts) {
          const double amplitude = std::max(0.0, 1.0 + rig.impact_jitter_rel * jitter_rng.normal());
          impacts.push_back({t, rig.impact_force_n * amplitude});
        }
        next_impact += two_pi;
      }
      theta = theta1;
    }
  }
  for (const Impact& imp : impacts)
    result.impacts.push_back({imp.t_s, imp.peak_force_n, 2.0 * imp.peak_force_n * rig.impact_duration_s / std::numbers::pi,
                              dyn.damping_ratio(imp.t_s), dyn.shaft_speed_hz(imp.t_s)});
  dyn.set_impacts(&impacts);

  // Main integration.
  State s{settings.initial_displacement_m, settings.initial_velocity_m_per_s, 0.0, 0.0, 0.0};
  double t_s = 0.0;
  dyn.initialise(t_s, s);
  result.clean_output.resize(n_samples);
  for (std::size_t i = 0; i < n_samples; ++i) {
    const double t_sample = static_cast<double>(i) / rate_hz;
    result.clean_output[i] = rig.sensor_sensitivity * dyn.output_quantity(t_sample, s, rig.sensor_quantity);
    for (int k = 0; k < substeps; ++k) {
      t_s = t_sample + static_cast<double>(k) * h_s;
      dyn.advance(t_s, s, h_s, result.located_events);
    }
  }
  for (double v : result.clean_output) result.clean_peak = std::max(result.clean_peak, std::abs(v));

  // Sensor effects, in the order given, each with its own random stream.
  result.output = result.clean_output;
  for (std::size_t i = 0; i < effects.size(); ++i)
    if (result.effects[i].effect.descriptor->kind == EffectKind::kSensor) {
      Rng rng = Rng::stream(settings.seed, i + 1);
      result.effects[i].event_times_s = effects[i]->apply_to_output(result.output, rate_hz, result.clean_peak, rng);
    }

  // Tacho channel and truth series.
  result.tacho.assign(n_samples, 0.0);
  for (double t : result.revolution_times_s) {
    const auto first = static_cast<std::size_t>(std::ceil(t * rate_hz));
    const auto last = static_cast<std::size_t>(std::ceil((t + settings.tacho_pulse_s) * rate_hz));
    for (std::size_t j = first; j < std::min(last, n_samples); ++j) result.tacho[j] = 1.0;
  }
  const double f0_hz = rig.natural_frequency_hz();
  for (double t = 0.0; t < duration_s; t += settings.truth_interval_s) {
    const double n_hz = dyn.shaft_speed_hz(t);
    result.truth.push_back({t, dyn.damping_ratio(t), f0_hz, n_hz, n_hz * rig.pinion_teeth});
  }
  return result;
}

}  // namespace ridgewatch::model
