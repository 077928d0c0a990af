#include "core/model/mesh_dynamics.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace ridgewatch::model {

namespace {
constexpr double kTwoPi = 2.0 * std::numbers::pi;
// Peak of the Hann pulse with the half-sine's impulse: (4/π) F sin²(πu) integrates to 2 F τ / π.
constexpr double kHannPeak = 4.0 / std::numbers::pi;
using cd = std::complex<double>;
int sign_of(double g) { return g >= 0.0 ? 1 : -1; }

// Event location on the grid of step fractions k 2^-30 (<= 5e-15 s at 200 kHz): the smallest grid
// fraction in (lo, hi] that is past the event, with lo not past it and hi past it.
constexpr double kEventGrid = 0x1p-30;

/// Regula falsi (Illinois) on a function g of the fraction, smooth on each side of the event, whose
/// value says whether a fraction is past the event (`past(g)`): trial points snapped to the grid,
/// each narrowing [lo, hi] as a bisection step would; ~6 trials instead of bisection's 30.
template <class G, class Past>
void narrow_by_regula_falsi(const G& g_at, const Past& past, double g_lo, double g_hi, double& lo, double& hi) {
  int side = 0;
  for (int trial = 0; hi - lo > kEventGrid && trial < 12; ++trial) {
    const double f = lo + (hi - lo) * g_lo / (g_lo - g_hi);
    if (!std::isfinite(f)) break;
    const double m = std::clamp(std::round(f / kEventGrid) * kEventGrid, lo + kEventGrid, hi - kEventGrid);
    const double g = g_at(m);
    if (!std::isfinite(g)) break;
    if (past(g)) {
      hi = m;
      g_hi = g;
      if (side == 1) g_lo *= 0.5;  // Illinois: halve the stale end's value
      side = 1;
    } else {
      lo = m;
      g_lo = g;
      if (side == -1) g_hi *= 0.5;
      side = -1;
    }
  }
}

/// Bisection on the grid: the smallest grid fraction in (lo, hi] at which `past_at` holds.
template <class PastAt>
double bisect_on_grid(const PastAt& past_at, double lo, double hi) {
  while (hi - lo > kEventGrid) {
    const double mid = lo + std::floor((hi - lo) / (2.0 * kEventGrid)) * kEventGrid;
    if (past_at(mid))
      hi = mid;
    else
      lo = mid;
  }
  return hi;
}
}  // namespace

const char* to_string(PulseShape shape) { return shape == PulseShape::kHann ? "hann" : "half_sine"; }

MeshModel::MeshModel(const RigParameters& rig, const std::vector<std::unique_ptr<Effect>>& effects,
                     const std::vector<EffectKind>& kinds, double pulse_s, bool phasor_terms,
                     PulseShape pulse_shape)
    : m_red_(rig.reduced_mass_kg()),
      c0_(rig.mean_mesh_stiffness_n_per_m),
      zeta_(rig.damping_ratio),
      crit_(2.0 * std::sqrt(rig.mean_mesh_stiffness_n_per_m * rig.reduced_mass_kg())),
      static_force_(rig.static_mesh_force_n()),
      q_s_(rig.static_deflection_m()),
      teeth_(static_cast<double>(rig.pinion_teeth)),
      pulse_s_(pulse_s),
      pulse_shape_(pulse_shape),
      use_phasors_(phasor_terms) {
  for (std::size_t i = 0; i < effects.size(); ++i) {
    const Effect* e = effects[i].get();
    effects_.push_back(e);
    if (i < kinds.size() && kinds[i] == EffectKind::kKinematics) kinematic_.push_back(i);
    if (e->has_switching()) switching_.push_back(i);
    // A regime stays +1 unless the effect switches: a factor of exactly 1 there leaves the product as it is.
    if (e->has_switching() || e->mesh_force_factor(1) != 1.0) factor_effects_.push_back(i);
    stick_limit_n_ += e->stick_force_limit_n();
    sticks_.push_back(e->stick_force_limit_n() > 0.0 ? 1 : 0);
    const Effect::StepHooks hooks = e->step_hooks();
    if (hooks.resisting_force) resisting_.push_back(i);
    if (hooks.damping_offset) damping_offsets_.push_back(e);
    if (auto m = e->auxiliary_mode()) {
      has_aux_ = true;
      aux_w_ = kTwoPi * m->frequency_hz;
      aux_zeta_ = m->damping_ratio;
      aux_w2_ = aux_w_ * aux_w_;
      aux_2zw_ = 2.0 * m->damping_ratio * aux_w_;
      aux_part_ = m->participation;
    }
  }
  build_phasors();
}

void MeshModel::build_phasors() {
  // Phasors of the mesh-periodic terms over one mesh cycle (orders 1..4; 32 points resolve order 4
  // of the rig's 3-term Eq. B1 and of the catalogue's 3-harmonic transmission error exactly).
  constexpr int kPoints = 32;
  for (int k = 0; k < kPhasorOrders; ++k) e_ph_[k] = de_ph_[k] = dc_ph_[k] = dcs_ph_[k] = 0.0;
  auto hooks = [&](double th) {
    MeshTerms m;
    for (const Effect* eff : effects_) {
      eff->add_transmission_error(th, m.e, m.de);
      m.dc += eff->stiffness_variation_n_per_m(th);
      m.dcs += eff->static_stiffness_variation_n_per_m(th);
    }
    return m;
  };
  for (int j = 0; j < kPoints; ++j) {
    const double th = kTwoPi * j / kPoints;
    const MeshTerms m = hooks(th);
    if (m.e != 0.0 || m.de != 0.0 || m.dc != 0.0) mesh_forcing_ = true;
    for (int k = 0; k < kPhasorOrders; ++k) {
      const cd w = std::polar(2.0 / kPoints, -(k + 1) * th);
      e_ph_[k] += m.e * w;
      de_ph_[k] += m.de * w;
      dc_ph_[k] += m.dc * w;
      dcs_ph_[k] += m.dcs * w;
    }
  }
  // The phasors stand in for the effects' functions when they reproduce them: checked at off-grid
  // angles to 1e-9 of the terms' size (exact for Fourier series of order <= 4; a term of higher
  // order or a mean offset keeps the direct calls).
  if (!mesh_forcing_) return;
  phasors_exact_ = true;
  double e_size = 0.0, dc_size = 0.0, de_size = 0.0, dcs_size = 0.0;
  for (int k = 0; k < kPhasorOrders; ++k) {
    e_size += std::abs(e_ph_[k]);
    de_size += std::abs(de_ph_[k]);
    dc_size += std::abs(dc_ph_[k]);
    dcs_size += std::abs(dcs_ph_[k]);
  }
  for (double th : {0.1234, 1.7, 2.9183, 4.4321, 5.99}) {
    const MeshTerms h = hooks(th);
    const MeshTerms p = phasor_terms(std::cos(th), std::sin(th));
    if (std::abs(p.e - h.e) > 1e-9 * e_size || std::abs(p.de - h.de) > 1e-9 * de_size ||
        std::abs(p.dc - h.dc) > 1e-9 * dc_size || std::abs(p.dcs - h.dcs) > 1e-9 * dcs_size)
      phasors_exact_ = false;
  }
}

double MeshModel::speed_factor(double t_s) const {
  double f = 1.0;
  for (std::size_t i : kinematic_) f *= effects_[i]->speed_factor(t_s);
  return f;
}

double MeshModel::damping_ratio(double t_s) const {
  double z = zeta_;
  for (const Effect* e : damping_offsets_) z += e->damping_ratio_offset(t_s);
  return std::clamp(z, 0.0, 0.99);
}

MeshTerms MeshModel::terms(double th) const {
  if (use_phasors_ && mesh_forcing_ && phasors_exact_) return phasor_terms(std::cos(th), std::sin(th));
  MeshTerms m;
  if (use_phasors_ && !mesh_forcing_) return m;
  for (const Effect* eff : effects_) {
    m.dc += eff->stiffness_variation_n_per_m(th);
    m.dcs += eff->static_stiffness_variation_n_per_m(th);
    eff->add_transmission_error(th, m.e, m.de);
  }
  return m;
}

MeshTerms MeshModel::phasor_terms(double c1, double s1) const {
  // Re(a e^{ikθ}) = Re a cos kθ - Im a sin kθ, with cos kθ, sin kθ by the angle-addition recurrence
  // from c1 = cos θ, s1 = sin θ (real arithmetic: std::complex products carry NaN/inf recovery branches).
  MeshTerms m;
  double ck = c1, sk = s1;
  for (int k = 0; k < kPhasorOrders; ++k) {
    m.dc += dc_ph_[k].real() * ck - dc_ph_[k].imag() * sk;
    m.dcs += dcs_ph_[k].real() * ck - dcs_ph_[k].imag() * sk;
    m.e += e_ph_[k].real() * ck - e_ph_[k].imag() * sk;
    m.de += de_ph_[k].real() * ck - de_ph_[k].imag() * sk;
    const double cn = ck * c1 - sk * s1;
    sk = sk * c1 + ck * s1;
    ck = cn;
  }
  return m;
}

MeshIntegrator::MeshIntegrator(const MeshModel& model, std::span<const ImpactPulse> pulses, double shaft_speed_hz,
                               double origin_s, Options options)
    : model_(model),
      pulses_(pulses),
      shaft_speed_hz_(shaft_speed_hz),
      origin_s_(origin_s),
      options_(options),
      regimes_(model.effects_.size(), 1) {
  update_force_factor();
}

void MeshIntegrator::update_force_factor() {
  force_factor_ = 1.0;
  for (std::size_t i : model_.factor_effects_) force_factor_ *= model_.effects_[i]->mesh_force_factor(regimes_[i]);
}

void MeshIntegrator::use_grid(double t0_s, double h_s, double theta0_rad, double mesh_omega_rad_per_s,
                              std::size_t points) {
  grid_.clear();
  if (!(model_.use_phasors_ && model_.mesh_forcing_ && model_.phasors_exact_) || points < 2) return;
  grid_.resize(points);
  grid_t0_ = t0_s;
  grid_inv_half_h_ = 2.0 / h_s;
  const double dth = mesh_omega_rad_per_s * 0.5 * h_s;
  const double cr = std::cos(dth), sr = std::sin(dth);
  double c1 = std::cos(theta0_rad), s1 = std::sin(theta0_rad);
  for (auto& g : grid_) {
    g = model_.phasor_terms(c1, s1);
    const double cn = c1 * cr - s1 * sr;
    s1 = s1 * cr + c1 * sr;
    c1 = cn;
  }
}

[[gnu::always_inline]] inline MeshTerms MeshIntegrator::terms_at(double t_s, double th) const {
  if (model_.use_phasors_ && !model_.mesh_forcing_) return {};  // as MeshModel::terms, without the call
  if (!grid_.empty()) {
    // Off-grid times (pulse edges, located events) fall back to the model's evaluation.
    // The nearest grid index by truncation of u + 1/2 (u > -1/2; as std::round wherever |u - j| <
    // 1e-6, without its library call).
    const double u = (t_s - grid_t0_) * grid_inv_half_h_;
    if (u > -0.5 && u < static_cast<double>(grid_.size())) {
      const auto j = static_cast<std::size_t>(u + 0.5);
      if (j < grid_.size() && std::abs(u - static_cast<double>(j)) < 1e-6) return grid_[j];
    }
  }
  return model_.terms(th);
}

double MeshIntegrator::impact_force_n(double t_s) const {
  double f = 0.0;
  for (std::size_t k = cursor_; k < pulses_.size(); ++k) {
    const ImpactPulse& imp = pulses_[k];
    if (imp.t_s > t_s) break;
    const double u = (t_s - imp.t_s) / model_.pulse_s_;
    if (u >= 1.0) continue;
    const double s = std::sin(std::numbers::pi * u);
    f += model_.pulse_shape_ == PulseShape::kHann ? kHannPeak * imp.peak_force_n * s * s : imp.peak_force_n * s;
  }
  return f;
}

void MeshIntegrator::advance_cursor(double t_s) {
  while (cursor_ < pulses_.size() && pulses_[cursor_].t_s + model_.pulse_s_ <= t_s) ++cursor_;
}

double MeshIntegrator::next_pulse_boundary(double t_s) const {
  for (std::size_t k = cursor_; k < pulses_.size(); ++k) {
    const double on = pulses_[k].t_s, off = on + model_.pulse_s_;
    if (on > t_s) return on;
    if (off > t_s) return off;
  }
  return INFINITY;
}

double MeshIntegrator::time_since_impact(double t_s) const {
  // The pulses from cursor_ on have not ended before the current step, so the latest onset is the
  // last of them at or before t, or the one before cursor_.
  std::size_t k = cursor_;
  while (k < pulses_.size() && pulses_[k].t_s <= t_s) ++k;
  return k == 0 ? t_s - origin_s_ : t_s - pulses_[k - 1].t_s;
}

MeshState MeshIntegrator::mesh_state(double t_s, const State& s) const {
  MeshState m;
  m.t_s = t_s;
  m.t_since_impact_s = time_since_impact(t_s);
  m.mesh_angle_rad = mesh_angle(s);
  m.x_m = s[kX];
  m.v_m_per_s = s[kV];
  m.deflection_m = model_.q_s_ + s[kX] + terms_at(t_s, m.mesh_angle_rad).e;
  return m;
}

double MeshIntegrator::mesh_coordinate_force_n(double t_s, const State& s, bool include_stick_effects) const {
  return mesh_force(t_s, s, include_stick_effects, kTwoPi * shaft_speed_hz(t_s), impact_force_n(t_s));
}

[[gnu::always_inline]] inline double MeshIntegrator::mesh_force(double t_s, const State& s, bool include_stick_effects, double theta_dot,
                                  double impact_force) const {
  const auto& effects = model_.effects_;
  const double mesh_angle_rad = mesh_angle(s);
  const MeshTerms mt = terms_at(t_s, mesh_angle_rad);
  const double deflection = model_.q_s_ + s[kX] + mt.e;  // δ = q_s + x + e
  const double deflection_rate = s[kV] + mt.de * model_.teeth_ * theta_dot;
  const double damping = model_.damping_ratio(t_s) * model_.crit_;
  // Eq. A1: c_z(t) (q + e) + d_z (q̇ + ė), switched off (in part) while the teeth are separated;
  // the static deflection sees only the variation's static part (equal to Δc unless relieved).
  const double c0 = model_.c0_;
  const double elastic = mt.dcs == mt.dc ? (c0 + mt.dc) * deflection
                                         : (c0 + mt.dc) * (s[kX] + mt.e) + (c0 + mt.dcs) * model_.q_s_;
  double force = model_.static_force_ + impact_force - force_factor_ * (elastic + damping * deflection_rate);
  if (model_.resisting_.empty()) return force;
  const MeshState m{.t_s = t_s,
                    .mesh_angle_rad = mesh_angle_rad,
                    .x_m = s[kX],
                    .v_m_per_s = s[kV],
                    .deflection_m = deflection,
                    .t_since_impact_s = time_since_impact(t_s)};
  for (std::size_t i : model_.resisting_) {
    if (!include_stick_effects && model_.sticks_[i]) continue;
    force -= effects[i]->resisting_force_n(m, regimes_[i]);
  }
  return force;
}

[[gnu::always_inline]] inline MeshIntegrator::State MeshIntegrator::derivative(double t_s, const State& s) const {
  // The pulse and the shaft speed once for both modes and the angle.
  const double impact_force = impact_force_n(t_s);
  const double theta_dot = kTwoPi * shaft_speed_hz(t_s);
  State d{};
  if (!stuck_) {
    d[kX] = s[kV];
    d[kV] = mesh_force(t_s, s, true, theta_dot, impact_force) / model_.m_red_;
  }
  d[kP] = s[kPdot];
  d[kPdot] = model_.aux_part_ * impact_force / model_.m_red_ - model_.aux_2zw_ * s[kPdot] - model_.aux_w2_ * s[kP];
  d[kTheta] = theta_dot;
  return d;
}

MeshIntegrator::State MeshIntegrator::rk4(double t_s, const State& s, double h) const {
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

bool MeshIntegrator::regime_violated(double t_s, const State& s) const {
  if (model_.switching_.empty()) return false;
  const MeshState m = mesh_state(t_s, s);
  for (std::size_t i : model_.switching_) {
    if (stuck_ && model_.effects_[i]->stick_force_limit_n() > 0.0) continue;
    if (sign_of(model_.effects_[i]->switching_function(m)) != regimes_[i]) return true;
  }
  return false;
}

void MeshIntegrator::update_regimes(double t_s, State& s, bool velocity_reversal) {
  // Regimes from the state; for effects that can stick, a stick test when q̇ has just changed sign
  // (or is zero): the mesh coordinate stays at rest while the other forces stay within the static
  // friction limit.
  const MeshState m = mesh_state(t_s, s);
  for (std::size_t i : model_.switching_) regimes_[i] = sign_of(model_.effects_[i]->switching_function(m));
  update_force_factor();
  if (model_.stick_limit_n_ > 0.0 && velocity_reversal) {
    State rest = s;
    rest[kV] = 0.0;
    if (std::abs(mesh_coordinate_force_n(t_s, rest, false)) <= model_.stick_limit_n_) {
      stuck_ = true;
      s[kV] = 0.0;
    }
  }
}

void MeshIntegrator::check_release(double t_s, const State& s) {
  // While stuck: release when the other forces exceed the static limit; slide in their direction.
  if (!stuck_) return;
  const double other = mesh_coordinate_force_n(t_s, s, false);
  if (std::abs(other) > model_.stick_limit_n_) {
    stuck_ = false;
    for (std::size_t i : model_.switching_)
      if (model_.effects_[i]->stick_force_limit_n() > 0.0) regimes_[i] = sign_of(other);
    update_force_factor();
  }
}

double MeshIntegrator::step_length(double t_s, double t_end) const {
  double step = t_end - t_s;
  const double boundary = next_pulse_boundary(t_s);
  if (boundary < t_end) step = boundary - t_s;
  return step;
}

std::size_t MeshIntegrator::single_switching_effect() const {
  // The one switching effect whose regime can change now (a stuck effect's cannot), or npos.
  std::size_t found = static_cast<std::size_t>(-1);
  for (std::size_t i : model_.switching_) {
    if (stuck_ && model_.effects_[i]->stick_force_limit_n() > 0.0) continue;
    if (found != static_cast<std::size_t>(-1)) return static_cast<std::size_t>(-1);
    found = i;
  }
  return found;
}

double MeshIntegrator::event_fraction(double t_s, double step, const State& s, const State& end) const {
  // The step fraction just past the regime change: the smallest grid fraction at which the step ends
  // in the new regime. Bisection finds it in 30 trial steps. With one switching effect, its switching
  // function g (smooth in the fraction within a regime) gives regula falsi trial points; every trial
  // still tests the regime exactly as bisection does, so both give the same fraction whenever the
  // regime changes once within the step (the only case bisection is defined for).
  double lo = 0.0, hi = 1.0;
  auto violated_at = [&](double f) { return regime_violated(t_s + f * step, rk4(t_s, s, f * step)); };
  const std::size_t i = single_switching_effect();
  if (i != static_cast<std::size_t>(-1)) {
    const Effect& eff = *model_.effects_[i];
    auto g_at = [&](double f) {
      const double tf = t_s + f * step;
      return eff.switching_function(mesh_state(tf, f == 0.0 ? s : f == 1.0 ? end : rk4(t_s, s, f * step)));
    };
    const double g_lo = g_at(0.0), g_hi = g_at(1.0);
    // Bracketing values of opposite regimes, else bisection from the start.
    if (std::isfinite(g_lo) && std::isfinite(g_hi) && sign_of(g_lo) == regimes_[i] && sign_of(g_hi) != regimes_[i])
      narrow_by_regula_falsi(g_at, [&](double g) { return sign_of(g) != regimes_[i]; }, g_lo, g_hi, lo, hi);
  }
  // Bisection on the grid (the whole search when there are several switching effects).
  return bisect_on_grid(violated_at, lo, hi);
}

double MeshIntegrator::release_fraction(double t_s, double step, const State& s, double direction) const {
  // While stuck, x and q̇ stay as they are over the step (only θ and the auxiliary mode move), and the
  // force the friction must hold, F(t) = the mesh coordinate's force without the sticking effects,
  // changes smoothly with t (the pulse, the mesh angle). Release where direction · F(t) first exceeds
  // the static limit: g(f) = direction · F - limit, not past the release at f = 0 (check_release held
  // the mesh there), past it at f = 1.
  auto g_at = [&](double f) {
    return direction * mesh_coordinate_force_n(t_s + f * step, f == 0.0 ? s : rk4(t_s, s, f * step), false) -
           model_.stick_limit_n_;
  };
  auto past = [](double g) { return g > 0.0; };
  double lo = 0.0, hi = 1.0;
  const double g_lo = g_at(0.0), g_hi = g_at(1.0);
  if (std::isfinite(g_lo) && std::isfinite(g_hi) && !past(g_lo) && past(g_hi))
    narrow_by_regula_falsi(g_at, past, g_lo, g_hi, lo, hi);
  return bisect_on_grid([&](double f) { return past(g_at(f)); }, lo, hi);
}

void MeshIntegrator::locate_event(double& t_s, double step, State& s, const State& end, std::uint64_t& events) {
  // The step to just past the regime change, then the new regimes.
  const double hi = event_fraction(t_s, step, s, end);
  const bool was_moving = !stuck_;
  const int v_sign_before = sign_of(s[kV]);
  s = rk4(t_s, s, hi * step);
  t_s += hi * step;
  ++events;
  update_regimes(t_s, s, was_moving && sign_of(s[kV]) != v_sign_before);
}

void MeshIntegrator::advance(double& t_s, State& s, double h_s, std::uint64_t& events) {
  const double t_end = t_s + h_s;
  int splits = 0;
  while (t_s < t_end) {
    advance_cursor(t_s);
    check_release(t_s, s);
    if (++splits > 64) {
      // Chattering between regimes (never seen in the catalogue): finish the step with the regimes
      // frozen rather than loop; the error is then that of an unlocated switch within one step.
      s = rk4(t_s, s, t_end - t_s);
      break;
    }
    double step = step_length(t_s, t_end);
    State next = rk4(t_s, s, step);
    if (options_.locate_release && stuck_) {
      // The step ends where the mesh breaks loose, located like a regime change; the next pass's
      // check_release frees it there (and a regime change of another effect before it is located
      // within the shortened step as usual).
      const double other = mesh_coordinate_force_n(t_s + step, next, false);
      if (std::abs(other) > model_.stick_limit_n_) {
        const double f = release_fraction(t_s, step, s, other > 0.0 ? 1.0 : -1.0);
        if (f < 1.0) {
          step *= f;
          next = rk4(t_s, s, step);
        }
        ++events;
      }
    }
    if (!regime_violated(t_s + step, next)) {
      s = next;
      t_s = (step == t_end - t_s) ? t_end : t_s + step;
      continue;
    }
    locate_event(t_s, step, s, next, events);
  }
  t_s = t_end;
}

void MeshIntegrator::initialise(double t_s, State& s) { update_regimes(t_s, s, s[kV] == 0.0); }

double MeshIntegrator::output_quantity(double t_s, const State& s, SensorQuantity q) const {
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

}  // namespace ridgewatch::model
