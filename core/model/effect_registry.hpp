// The catalogue of effects known to the simulator, and checking a requested effect against it.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/model/effect.hpp"

namespace ridgewatch::model {

/// All registered effects, in a fixed order (the registration list in effect_registry.cpp).
const std::vector<EffectDescriptor>& effect_catalogue();

/// nullptr when no effect has this name.
const EffectDescriptor* find_effect(const std::string& name);

/// An effect with every parameter value filled in and checked.
struct ResolvedEffect {
  const EffectDescriptor* descriptor = nullptr;
  EffectValues values;  ///< every key of the descriptor
};

/// Fills defaults and checks names and bounds. Throws std::invalid_argument with a message such as
/// "effect coulomb_friction: force_n: must be in [0, 10000] (got -1)" or "unknown effect 'x'".
ResolvedEffect resolve_effect(const EffectSpec& spec);

/// The values of `descriptor` at which the effect vanishes: the null value where there is one, the
/// default otherwise.
EffectValues null_values(const EffectDescriptor& descriptor);

}  // namespace ridgewatch::model
