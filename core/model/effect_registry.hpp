// The catalogue of effects known to the simulator, and checking a requested effect against it.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/model/effect.hpp"

namespace ridgewatch::model {

/// All registered effects, in a fixed order (the registration list in effect_registry.cpp).
const std::vector<EffectDescriptor>& effect_catalogue();

/// nullptr when no effect has this name (catalogue first, then the user-defined effects).
const EffectDescriptor* find_effect(const std::string& name);
/// The catalogue only.
const EffectDescriptor* find_catalogue_effect(const std::string& name);

/// User-defined effects (a rig file's model.custom_effects, core/model/custom_effect.hpp) with their
/// optional fit starts.
struct UserEffect {
  EffectDescriptor descriptor;
  EffectValues starts;
};
/// Makes `effects` visible to find_effect / resolve_effect (and diagnose's candidates) on the calling
/// thread, replacing the previous set: loading a rig file defines the user effects of the command
/// that loaded it. Pointers from find_effect to an earlier set become invalid. Thread-local, so
/// parallel tests and threads do not see each other's effects.
void set_user_effects(std::vector<UserEffect> effects);
const std::vector<UserEffect>& user_effects();
/// Changes with every set_user_effects (for caches built from the user effects).
std::uint64_t user_effects_generation();

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
