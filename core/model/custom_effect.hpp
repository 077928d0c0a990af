// User-defined effects without C++: an extra force on the mesh coordinate written as an expression
// (a rig file's model.custom_effects), compiled once by muparser and evaluated in the equation of
// motion (Eq. A1) like a catalogue effect's resisting force:
//
//   m_red ẍ = ... + F_user(x, v, theta, t, t_abs; parameters)
//
// Variables (SI units): x (m, dynamic deflection q - q_s), v (m/s, q̇), theta (rad, mesh angle θ_z),
// t (s since the onset of the latest impact; since the record start before the first), t_abs (s since
// the record start). Parameters are named by the user, with unit, bounds, default, optional null value
// (where the effect vanishes) and optional fit start. Operators and functions are muparser's: + - * /
// ^, sin cos tan exp ln log10 sqrt abs sign min max, comparisons and `cond ? a : b`, constants _pi, _e.
//
// The expression library stays behind this header (the .cpp is the only file that includes
// muParser.h): pure computation, no I/O.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/model/effect.hpp"

namespace ridgewatch::model {

struct CustomEffectDefinition {
  std::string name;        ///< [a-z_][a-z0-9_]*, not a catalogue name
  std::string force;       ///< expression, N, added to the mesh force (negative opposes motion)
  std::vector<EffectParameter> parameters;
  EffectValues starts;     ///< optional optimiser starts for diagnose/compare, by key
  /// Optional switching functions (expressions in the same variables and parameters) whose zeros are
  /// the force's kinks, e.g. "x - b_dz" and "x + b_dz" for min(max(x, -b_dz), b_dz). The integrator
  /// locates a sign change of any of them within an RK4 step and restarts the step there, as it does
  /// for the catalogue's regime changes, instead of stepping over the kink.
  std::vector<std::string> kinks;
};

/// A definition that does not compile or check. `where` is the part of the definition at fault
/// ("force", "parameters.c3", "name"); `position` the 1-based column in the expression (0 if none).
class CustomEffectError : public std::invalid_argument {
 public:
  CustomEffectError(const std::string& what, std::string where, int position)
      : std::invalid_argument(what), where_(std::move(where)), position_(position) {}
  const std::string& where() const { return where_; }
  int position() const { return position_; }

 private:
  std::string where_;
  int position_;
};

/// The expression variables, in the order documented above.
const std::vector<std::string>& custom_effect_variables();

/// Checks the definition (names, bounds), compiles the expression and the kinks' switching functions
/// (syntax, unknown names) and evaluates them on a grid of states with the parameters at their
/// defaults and at their bounds (a non-finite value is an error). Returns a dynamics descriptor whose effect adds the force.
/// Throws CustomEffectError naming the effect, the part at fault ("force", "kinks[1]", ...) and the column.
EffectDescriptor make_custom_effect(const CustomEffectDefinition& definition);

}  // namespace ridgewatch::model
