// Physical and sensor effects as plug-ins of the gear-pair simulator (core/model/simulator.hpp).
//
// An effect is a constant descriptor (stable name, parameters with unit, bounds, default and null
// value, explanation, expected signature) plus a factory returning an Effect. The Effect overrides
// only the hooks it needs; every hook defaults to "no change". An effect vanishes when every parameter
// that has a null value is set to it.
//
// Adding an effect: write core/model/effects/<name>.cpp defining `EffectDescriptor
// <name>_descriptor()`, then add its declaration and one table entry in core/model/effect_registry.cpp.
// Without C++: a force expression in a rig file (core/model/custom_effect.hpp).
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "core/model/random.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::model {

enum class EffectKind { kDynamics, kKinematics, kSensor };
const char* to_string(EffectKind kind);

struct EffectParameter {
  std::string key;
  std::string unit;  ///< "1" for dimensionless
  double min_value = 0.0;
  double max_value = 0.0;
  double default_value = 0.0;
  std::optional<double> null_value;  ///< the value at which this parameter switches the effect off
  std::string description;
};

/// Parameter values by key. Resolved values contain every key of the descriptor.
using EffectValues = std::map<std::string, double>;

/// What an effect sees of the dynamic state during integration (Eq. A1/A2 quantities).
struct MeshState {
  double t_s = 0.0;
  double mesh_angle_rad = 0.0;  ///< θ_z = z1 × pinion angle; Eq. B1's ω_z t at constant speed
  double x_m = 0.0;             ///< dynamic deflection: q minus the static deflection q_s
  double v_m_per_s = 0.0;       ///< q̇
  double deflection_m = 0.0;    ///< total mesh deflection δ = q_s + x + e (e: transmission error)
  double t_since_impact_s = 0.0;  ///< time since the onset of the latest impact pulse (t_s before the first)
};

/// A further linear mode (modal superposition), excited by the impacts and seen by the sensor.
struct AuxiliaryMode {
  double frequency_hz = 0.0;
  double damping_ratio = 0.0;
  double participation = 0.0;  ///< modal force per impact force, relative to the gear mesh mode
};

class Effect {
 public:
  virtual ~Effect() = default;

  // Kinematics.
  /// Factor on the nominal pinion speed at time t.
  virtual double speed_factor(double /*t_s*/) const { return 1.0; }

  // Dynamics (Eq. A1/A2).
  /// Added to the damping ratio ζ at time t.
  virtual double damping_ratio_offset(double /*t_s*/) const { return 0.0; }
  /// Added to the mean mesh stiffness c0: a function of the mesh angle (Eq. B1), N/m.
  virtual double stiffness_variation_n_per_m(double /*mesh_angle_rad*/) const { return 0.0; }
  /// The part of that variation that multiplies the static deflection q_s (N/m): the source of the
  /// load-driven lines at k f_z. Equal to the whole variation unless the effect says otherwise (a
  /// profile relieved for the nominal load cancels the static part; mesh_stiffness_variation's
  /// `static_coupling`).
  virtual double static_stiffness_variation_n_per_m(double mesh_angle_rad) const {
    return stiffness_variation_n_per_m(mesh_angle_rad);
  }
  /// Adds the transmission error e (m) and its derivative de/dθ_z (m/rad) at a mesh angle (Eq. A1).
  virtual void add_transmission_error(double /*mesh_angle_rad*/, double& /*e_m*/,
                                      double& /*de_dangle_m_per_rad*/) const {}
  /// Force opposing the mesh motion (acts like d_z q̇ in Eq. A1), N. `regime` is the sign of the
  /// switching function, frozen over an integration step.
  virtual double resisting_force_n(const MeshState& /*s*/, int /*regime*/) const { return 0.0; }
  /// Factor on the mesh force c_z δ + d_z δ̇ in a regime (contact loss).
  virtual double mesh_force_factor(int /*regime*/) const { return 1.0; }
  /// True when the effect has a discontinuity located by the integrator (event location).
  virtual bool has_switching() const { return false; }
  /// The regime is the sign of this function (>= 0 -> +1, < 0 -> -1).
  virtual double switching_function(const MeshState& /*s*/) const { return 1.0; }
  /// Static friction: the largest force (N) with which this effect can hold q̇ = 0 (stick).
  virtual double stick_force_limit_n() const { return 0.0; }
  virtual std::optional<AuxiliaryMode> auxiliary_mode() const { return std::nullopt; }
  /// Which of the per-step hooks above this effect can make non-zero: the integrator's right-hand
  /// side (core/model/mesh_dynamics.cpp, evaluated four times per RK4 step) calls only those. The
  /// default, every hook, is always correct; an effect that overrides resisting_force_n or
  /// damping_ratio_offset must keep that flag true (test_model_effects checks the catalogue).
  struct StepHooks {
    bool resisting_force = true;  ///< resisting_force_n can be non-zero
    bool damping_offset = true;   ///< damping_ratio_offset can be non-zero
  };
  virtual StepHooks step_hooks() const { return {}; }

  // Sensor.
  /// Changes the sensor output in place (output units). `clean_peak` is max |output| before any
  /// sensor effect. Returns the times (s) of discrete events it added (e.g. spikes), else empty.
  virtual std::vector<double> apply_to_output(std::span<double> /*samples*/, double /*rate_hz*/,
                                              double /*clean_peak*/, Rng& /*rng*/) const {
    return {};
  }
};

struct EffectDescriptor {
  std::string name;  ///< stable identifier used on the command line and in YAML
  EffectKind kind = EffectKind::kDynamics;
  std::string explanation;  ///< one paragraph: the physics
  std::string signature;    ///< what it looks like in the measured signal
  std::vector<EffectParameter> parameters;
  /// `values` holds every parameter key, checked against the bounds; `rig` is validated.
  /// A function (not a plain pointer) so that a user-defined effect (core/model/custom_effect.hpp)
  /// can carry its compiled expression.
  std::function<std::unique_ptr<Effect>(const EffectValues& values, const RigParameters& rig)> create;
};

/// A requested effect: name plus the parameters that differ from the defaults.
struct EffectSpec {
  std::string name;
  EffectValues values;
};

/// Parses "name" or "name:key=value,key=value" (command-line form). Throws std::invalid_argument.
EffectSpec parse_effect_spec(const std::string& text);

}  // namespace ridgewatch::model
