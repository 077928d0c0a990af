// The one integrator of the gear-pair model: Eq. A1/A2 of the paper (Appendix A) with the rig of
// Appendix B and the effects of the catalogue or of a rig file (core/model/effect.hpp,
// core/model/custom_effect.hpp). `simulate` (core/model/simulator.hpp) runs it over a whole record and
// the model fit (core/diagnosis/impact_model.hpp) over one impact window at a time, so physics added
// here is in both.
//
// State: x = q - q_s (dynamic mesh deflection about the static one q_s = W/c0, m), q̇ (m/s), the
// auxiliary mode p, ṗ (second_mode) and the pinion angle θ1 (rad). Equation of motion (Eq. A1 with
// F = W + impacts, W = M1/r_b1 the static tooth force):
//
//   m_red ẍ = W + F_imp(t) - g(regime) [c_z(θ_z) δ + d_z(t) δ̇] - sum of resisting forces,
//   δ = q_s + x + e(θ_z),  c_z = c0 + Δc(θ_z) (Eq. B1 on the mesh angle θ_z = z1 θ1),
//   d_z(t) = 2 ζ(t) sqrt(c0 m_red)  (Eq. A2's ζ, with d_z constant over a mesh cycle as in Eq. A1),
//   p̈ + 2 ζ2 ω2 ṗ + ω2² p = participation F_imp / m_red,   θ̇1 = 2π n(t).
//
// Integration: classical RK4 over the steps the caller asks for, each split at the start and end of
// every impact pulse (half-sine pulses). Non-smooth terms (Coulomb friction sign, contact loss) by
// event location: the regime of each switching effect is frozen over a step, a sign change of its
// switching function is located by bisection on the step length, and the step restarts there with the
// new regime, with a stick test for dry friction. Pure computation: no I/O, no clock, no threads.
#pragma once

#include <array>
#include <complex>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "core/model/effect.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::model {

/// Shape of the impact force pulse on [t_s, t_s + τ], u = (t - t_s)/τ, both with the impulse 2 F τ / π
/// of a half-sine of peak F (the impact's size F means the same in both):
///   kHalfSine  F sin(π u)            (the simulator's pulse; a force that jumps in slope at the edges)
///   kHann      (4/π) F sin²(π u)     (raised cosine: force and slope start and end at zero, as a
///                                     contact that loads and unloads smoothly)
enum class PulseShape { kHalfSine, kHann };
const char* to_string(PulseShape shape);

/// A force pulse of peak-equivalent F (PulseShape) on [t_s, t_s + τ] (the cracked tooth's impact).
struct ImpactPulse {
  double t_s = 0.0;           ///< onset (s)
  double peak_force_n = 0.0;  ///< F (N)
};

/// The mesh-periodic terms of Eq. A1/B1 at one mesh angle, summed over the effects.
struct MeshTerms {
  double dc = 0.0;   ///< Δc, stiffness variation (N/m)
  double e = 0.0;    ///< transmission error (m)
  double de = 0.0;   ///< de/dθ_z (m/rad)
  double dcs = 0.0;  ///< the part of Δc that multiplies the static deflection q_s (N/m)
};

/// What does not change during an integration: the rig's constants and the effects, with their
/// auxiliary mode, switching effects and dry-friction limit collected once.
class MeshModel {
 public:
  static constexpr int kPhasorOrders = 4;  ///< mesh orders of the phasor representation

  /// `effects` (their kinds in `kinds`, same order) must outlive the model; the rig must be valid.
  /// `pulse_s`: length of the impact pulse (s), `pulse_shape` its shape. `phasor_terms`: evaluate the mesh-periodic
  /// terms from their Fourier phasors of orders 1..4 (one sin/cos per evaluation instead of a call per
  /// harmonic and effect) when these reproduce the effects' own functions to 1e-9 of the terms' size;
  /// false: always call the effects' functions (simulate: its records stay byte-identical).
  MeshModel(const RigParameters& rig, const std::vector<std::unique_ptr<Effect>>& effects,
            const std::vector<EffectKind>& kinds, double pulse_s, bool phasor_terms,
            PulseShape pulse_shape = PulseShape::kHalfSine);

  /// Factor on the nominal shaft speed at time t (kinematic effects).
  double speed_factor(double t_s) const;
  /// ζ(t) (Eq. A2) with the effects' offsets, clamped to [0, 0.99] so that a drift never makes the
  /// mesh unstable or overdamped.
  double damping_ratio(double t_s) const;
  /// Δc, e, de/dθ and the static Δc at mesh angle θ_z (phasors when exact, else the effects' functions).
  MeshTerms terms(double mesh_angle_rad) const;
  /// The phasor sums for cos θ = c1, sin θ = s1 (phasor representation only).
  MeshTerms phasor_terms(double c1, double s1) const;

  /// True when some effect makes Δc, e or de/dθ non-zero (checked on 32 angles of a mesh cycle).
  bool mesh_forcing() const { return mesh_forcing_; }
  bool phasors_exact() const { return phasors_exact_; }
  /// Phasors (real amplitude: term = Re Σ_k a_k e^{ikθ}, k = 1..4) of Δc, its static part, e, de/dθ.
  const std::complex<double>* dc_phasors() const { return dc_ph_; }
  const std::complex<double>* dcs_phasors() const { return dcs_ph_; }
  const std::complex<double>* e_phasors() const { return e_ph_; }
  const std::complex<double>* de_phasors() const { return de_ph_; }

  bool has_auxiliary_mode() const { return has_aux_; }
  double auxiliary_omega() const { return aux_w_; }
  double auxiliary_damping_ratio() const { return aux_zeta_; }
  /// Static friction limit summed over the effects (N); > 0 when something can stick.
  double stick_limit_n() const { return stick_limit_n_; }
  double reduced_mass_kg() const { return m_red_; }
  double pulse_s() const { return pulse_s_; }
  double teeth() const { return teeth_; }

 private:
  friend class MeshIntegrator;
  void build_phasors();

  std::vector<const Effect*> effects_;
  std::vector<std::size_t> kinematic_;  // effects whose speed_factor can differ from 1
  std::vector<std::size_t> switching_;
  std::vector<std::size_t> factor_effects_;  // effects whose mesh_force_factor can differ from 1
  // The right-hand side's per-step hooks, only for the effects that use them (Effect::step_hooks).
  std::vector<std::size_t> resisting_;       // effects with a resisting force
  std::vector<char> sticks_;                 // by effect: stick_force_limit_n() > 0
  std::vector<const Effect*> damping_offsets_;  // effects that offset ζ
  double m_red_, c0_, zeta_, crit_, static_force_, q_s_, teeth_, pulse_s_;
  PulseShape pulse_shape_ = PulseShape::kHalfSine;
  double stick_limit_n_ = 0.0;
  bool has_aux_ = false;
  double aux_w_ = 0.0, aux_zeta_ = 0.0, aux_w2_ = 0.0, aux_2zw_ = 0.0, aux_part_ = 0.0;
  bool use_phasors_ = false, mesh_forcing_ = false, phasors_exact_ = false;
  std::complex<double> e_ph_[kPhasorOrders], de_ph_[kPhasorOrders], dc_ph_[kPhasorOrders], dcs_ph_[kPhasorOrders];
};

/// One integration run: the state that changes with time (switching regimes, sticking, the current
/// pulse) over a list of impact pulses. Not thread-safe; one run per window or record.
class MeshIntegrator {
 public:
  using State = std::array<double, 5>;
  static constexpr std::size_t kX = 0, kV = 1, kP = 2, kPdot = 3, kTheta = 4;

  struct Options {
    /// While dry friction holds the mesh, locate its release (the other forces reaching the static
    /// limit, e.g. as the impact pulse rises) within the step, on the grid of step fractions of the
    /// other events. Tested at step starts only, the release lags by up to a step (an O(h) phase
    /// error) and, worse for a fit, jumps by a whole step when a parameter moves it across a step
    /// start: the output is then discontinuous in the parameters, and a finite-difference Jacobian
    /// whose step crosses such a jump has columns orders of magnitude too long, which makes the
    /// fit's intervals too narrow. Off in `simulate` (steps of 5 µs at most), so that its records
    /// stay byte-identical with earlier releases.
    bool locate_release = false;
  };

  /// `pulses` sorted by onset, must outlive the run. `shaft_speed_hz`: nominal pinion speed (times
  /// the kinematic effects' factors). `origin_s`: the time since the impact (an effect's
  /// t_since_impact) is t - origin_s before the first pulse.
  MeshIntegrator(const MeshModel& model, std::span<const ImpactPulse> pulses, double shaft_speed_hz, double origin_s,
                 Options options);

  /// Mesh terms on the grid t0 + j h/2, j = 0..points-1, where every regular RK4 stage of steps h
  /// from t0 falls; θ_z(t0) = theta0, θ_z advancing by `mesh_omega` (rad/s) at constant speed. Needs
  /// exact phasors (else ignored): the phasor sums are then done once per grid point instead of per
  /// stage, with cos/sin by rotation (rounding grows by ~1e-16 per step).
  void use_grid(double t0_s, double h_s, double theta0_rad, double mesh_omega_rad_per_s, std::size_t points);

  /// Initial regimes at t, with a stick test when q̇ = 0.
  void initialise(double t_s, State& s);
  /// Advances `s` from t to t + h, splitting at pulse edges and located regime changes; counts the
  /// located events in `events`.
  void advance(double& t_s, State& s, double h_s, std::uint64_t& events);

  /// The sensed quantity (before the sensitivity): x + p, q̇ + ṗ or q̈ + p̈.
  double output_quantity(double t_s, const State& s, SensorQuantity q) const;
  double mesh_angle(const State& s) const { return model_.teeth_ * s[kTheta]; }
  double shaft_speed_hz(double t_s) const { return shaft_speed_hz_ * model_.speed_factor(t_s); }
  double time_since_impact(double t_s) const;
  bool stuck() const { return stuck_; }
  /// The force on the mesh coordinate (Eq. A1, N) at the current regimes.
  double mesh_coordinate_force_n(double t_s, const State& s, bool include_stick_effects) const;
  State derivative(double t_s, const State& s) const;

 private:
  MeshTerms terms_at(double t_s, double mesh_angle_rad) const;
  /// mesh_coordinate_force_n with θ̇ (rad/s) and the pulse force (N) at t given.
  double mesh_force(double t_s, const State& s, bool include_stick_effects, double theta_dot,
                    double impact_force) const;
  MeshState mesh_state(double t_s, const State& s) const;
  double impact_force_n(double t_s) const;
  void advance_cursor(double t_s);
  double next_pulse_boundary(double t_s) const;
  double step_length(double t_s, double t_end) const;
  State rk4(double t_s, const State& s, double h) const;
  bool regime_violated(double t_s, const State& s) const;
  void update_regimes(double t_s, State& s, bool velocity_reversal);
  void check_release(double t_s, const State& s);
  /// `end`: the state after the whole step (in the regimes frozen at its start).
  void locate_event(double& t_s, double step, State& s, const State& end, std::uint64_t& events);
  double event_fraction(double t_s, double step, const State& s, const State& end) const;
  /// While stuck: the step fraction just past the release, where `direction` (±1) times the force
  /// the friction must hold first exceeds the static limit (it does at the step's end).
  double release_fraction(double t_s, double step, const State& s, double direction) const;
  std::size_t single_switching_effect() const;
  /// The product of the effects' mesh_force_factor at the current regimes (Eq. A1's g(regime)),
  /// kept in force_factor_: set wherever the regimes change, read by every right-hand side.
  void update_force_factor();

  const MeshModel& model_;
  std::span<const ImpactPulse> pulses_;
  double shaft_speed_hz_, origin_s_;
  Options options_;
  std::size_t cursor_ = 0;  // first pulse that has not ended before the current step
  std::vector<int> regimes_;
  double force_factor_ = 1.0;
  bool stuck_ = false;
  double grid_t0_ = 0.0, grid_inv_half_h_ = 0.0;
  std::vector<MeshTerms> grid_;
};

}  // namespace ridgewatch::model
