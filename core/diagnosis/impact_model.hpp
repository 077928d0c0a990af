// Per-impact simulation of the gear-pair model for model-vs-measurement fitting (issue 5).
//
// The full simulator (core/model/simulator.hpp) integrates a whole record; fitting needs the response
// of one impact window many times per optimiser step. Both run the same integrator of Eq. A1/A2
// (core/model/mesh_dynamics.hpp: RK4, steps split at the pulse edges, event location on switching
// effects with the stick test, the catalogue's and the rig file's effects as plug-ins); this file adds
// the window conventions below. Numerical settings of the fit: the RK4 step (ω h <= 0.25 at the highest
// modelled frequency), mesh terms from their phasors on the half-step grid, and the release of a mesh
// held by dry friction located within the step (MeshIntegrator::Options::locate_release).
//
// Window conventions (what makes the fit identifiable; README "Model vs measurement"):
//  * the impact is a half-sine force pulse of the rig's duration starting at `onset_s` with peak
//    `force_n` (the two per-impact nuisances);
//  * mesh-periodic terms run on the mesh angle referenced to the impact: θ_z(t) = φ_z + 2π f_z
//    (t - onset), φ_z shared by all impacts (the cracked tooth meets at the same shaft angle each
//    revolution, so the mesh angle at the impact repeats), f_z = z1 / (local revolution period);
//  * the state at the window start is the linear steady-state response to the mesh-periodic forcing
//    (transmission error and stiffness variation times the static deflection; present before the
//    impact, it does not decay) plus the free transient left by the previous impact, propagated
//    through the gap by the closed-form free decay (zero when dry friction has stopped it).
#pragma once

#include <complex>
#include <memory>
#include <string>
#include <vector>

#include "core/model/effect.hpp"
#include "core/model/mesh_dynamics.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::diagnosis {

/// How a free physics parameter is mapped from the optimiser's unbounded u to its value.
enum class Transform {
  kLog,      ///< v = exp(u), clamped to [lo, hi] (lo > 0): positive, scale-free
  kBounded,  ///< v = lo + (hi - lo) / (1 + exp(-u)): both bounds, smooth
  kAngle,    ///< v = u (an angle; reported wrapped to (-π, π])
};

double to_value(Transform t, double lo, double hi, double u);
double to_u(Transform t, double lo, double hi, double value);

struct FreeParameter {
  std::string key;  ///< effect parameter key
  Transform transform = Transform::kLog;
  double lo = 0.0, hi = 0.0;  ///< within the catalogue's bounds
  double start = 0.0;         ///< value the optimiser starts from
  /// The range's ends are values the effect physically takes (contact_loss's loss_fraction = 1:
  /// complete tooth separation), so a fit there is not "stuck at a bound" (diagnose's plausibility).
  bool bounds_attainable = false;
  /// Fitted only when this other parameter of the same effect is fixed by the user (`--with
  /// NAME:key=value!`): damping_drift's step is identifiable only at a known step time.
  const char* needs_fixed = nullptr;
  /// Never fitted, only set: a fixed user setting puts its value into the model (damping_drift's step
  /// time moves the model discontinuously, no derivative to follow); otherwise `fixed` holds it.
  bool set_only = false;
};

/// A diagnosable effect: which of its catalogue parameters are fitted and which are held fixed.
struct CandidateSpec {
  std::string effect;
  std::vector<FreeParameter> free;
  model::EffectValues fixed;  ///< the remaining parameters (at their null value or a fixed reference)
  bool mesh_periodic = false; ///< uses the shared mesh phase φ_z
  /// User-defined effects: free parameters the user gave no start for (diagnose tries several).
  std::vector<std::string> unknown_starts;
};

/// The dynamics effects `diagnose` can try, in catalogue order. Sensor effects (noise, hum, spikes)
/// and kinematics (speed_variation: the local revolution period is measured per impact) are not
/// candidates.
const std::vector<CandidateSpec>& candidate_table();
/// The catalogue's candidates, then the user-defined effects of this thread
/// (model::set_user_effects), every parameter with a range fitted.
const CandidateSpec* find_candidate(const std::string& name);
/// Names of every candidate: candidate_table() then the user-defined effects.
std::vector<std::string> candidate_names();

/// Physical values of the model's global parameters.
struct PhysicsValues {
  double c0_n_per_m = 0.0;
  double zeta = 0.0;
  double mesh_phase_rad = 0.0;  ///< φ_z (used only by mesh-periodic effects)
  /// Length of the half-sine impact pulse (s); 0: the rig's impact_duration_s. Fitted: a real impact
  /// is no exact half-sine, and a short pulse's shape acts on the response through its length and
  /// second moment (a Hann pulse of length τ equals a half-sine of 0.83 τ to second order in ωτ).
  double pulse_s = 0.0;
  /// Shape of the impact pulse (core/model/mesh_dynamics.hpp): a choice of the fit, not fitted by LM.
  model::PulseShape pulse_shape = model::PulseShape::kHalfSine;
  std::vector<std::pair<std::string, model::EffectValues>> effects;  ///< complete value sets
};

/// Dynamic state of the window model (mesh mode x, q̇ and the auxiliary mode p, ṗ).
struct ModelState {
  double x = 0.0, v = 0.0, p = 0.0, pd = 0.0;
};

/// The model's mesh state at one output sample (the variables of a user-defined force, custom_effect.hpp):
/// x (m, dynamic deflection), v (m/s), θ_z (rad), time since the latest impact and since the record start (s).
struct TraceSample {
  double x = 0.0, v = 0.0, theta = 0.0, t = 0.0, t_abs = 0.0;
};

class WindowSimulator {
 public:
  /// Throws std::invalid_argument if an effect rejects its values.
  WindowSimulator(const model::RigParameters& rig, const PhysicsValues& physics, double sample_rate_hz);
  ~WindowSimulator();
  WindowSimulator(const WindowSimulator&) = delete;
  WindowSimulator& operator=(const WindowSimulator&) = delete;

  struct Impact {
    double onset_s = 0.0;    ///< absolute time of the pulse start
    double force_n = 0.0;    ///< peak of the half-sine pulse
    double mesh_hz = 0.0;    ///< f_z for this impact
    double polarity = 1.0;   ///< sensor sign (+1 / -1)
  };
  struct End {
    ModelState transient;  ///< state at the window end minus the steady state
    bool stopped = false;  ///< dry friction holds the mesh at rest
  };

  /// Simulates samples [first, first + n) (absolute sample indices) into out[0..n). `carry` is the
  /// free transient of the previous impact at the window start (zero if none). A user-defined force
  /// that turns non-finite gives a window of 1e10 (see the .cpp). `trace` (optional) receives the
  /// mesh state at each of the n samples (term discovery, term_discovery.hpp).
  void simulate(std::uint64_t first, std::size_t n, const Impact& impact, const ModelState& carry,
                double* out, End& end, std::vector<TraceSample>* trace = nullptr) const;

  /// Closed-form free decay of a transient over dt seconds (both modes linear, Eq. A2 with constant ζ).
  ModelState propagate(const ModelState& s, double dt_s, double t_abs_s) const;
  bool has_dry_friction() const { return model_->stick_limit_n() > 0.0; }
  /// The largest force dry friction holds the mesh against at rest (N; 0 without dry friction): the
  /// mesh can rest anywhere in |x| <= stick_limit_n / c0.
  double stick_limit_n() const { return model_->stick_limit_n(); }
  /// Whether the motion between two windows must be integrated (ModelFitter's carried state) rather
  /// than decayed in closed form: the closed form is the linear mesh's, right for the small leftover
  /// tail of a model that is linear near rest. Not so with dry friction (the mesh sticks at an offset
  /// in the friction band) or a user-defined force with declared kinks (a dead zone or clearance
  /// around the loaded contact: the tail falls into the gap, where the spring force vanishes, and
  /// drifts to rest at an offset anywhere in it). The catalogue's other switching effect, contact loss,
  /// switches only when the dynamic deflection exceeds the static one, never in a small tail.
  bool integrates_gaps() const { return integrate_gaps_; }
  double damping_ratio_at(double t_abs_s) const { return model_->damping_ratio(t_abs_s); }

 private:
  static constexpr int kSteadyOrders = 8;
  struct Steady {
    double x0 = 0.0;                            ///< mean of x_ss
    std::complex<double> x[kSteadyOrders];      ///< phasors of x_ss for mesh orders 1..kSteadyOrders
  };
  Steady steady_state(double mesh_hz) const;
  /// simulate without the guard against a non-finite user-defined force: one Run over the window.
  void simulate_unguarded(std::uint64_t first, std::size_t n, const Impact& impact, const ModelState& carry,
                          double* out, End& end, std::vector<TraceSample>* trace) const;
  /// One window's integration (the shared integrator, core/model/mesh_dynamics.hpp) from the steady
  /// state plus the carried transient, with the output and trace (the .cpp).
  struct Run;

  model::RigParameters rig_;
  PhysicsValues physics_;
  double fs_ = 0.0;
  int substeps_ = 1;
  bool integrate_gaps_ = false;
  double m_red_ = 0.0, crit_ = 0.0, q_s_ = 0.0, sens_ = 0.0;
  std::vector<std::unique_ptr<model::Effect>> effects_;
  std::unique_ptr<model::MeshModel> model_;
};

}  // namespace ridgewatch::diagnosis
