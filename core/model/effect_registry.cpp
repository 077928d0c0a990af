// The registration list: one declaration and one table entry per effect (core/model/effects/*.cpp).
#include "core/model/effect_registry.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace ridgewatch::model {

EffectDescriptor mesh_stiffness_variation_descriptor();
EffectDescriptor transmission_error_descriptor();
EffectDescriptor coulomb_friction_descriptor();
EffectDescriptor quadratic_damping_descriptor();
EffectDescriptor second_mode_descriptor();
EffectDescriptor contact_loss_descriptor();
EffectDescriptor stiffness_nonlinearity_descriptor();
EffectDescriptor damping_drift_descriptor();
EffectDescriptor speed_variation_descriptor();
EffectDescriptor noise_descriptor();
EffectDescriptor hum_descriptor();
EffectDescriptor spikes_descriptor();

const std::vector<EffectDescriptor>& effect_catalogue() {
  static const std::vector<EffectDescriptor> catalogue = {
      mesh_stiffness_variation_descriptor(),
      transmission_error_descriptor(),
      coulomb_friction_descriptor(),
      quadratic_damping_descriptor(),
      second_mode_descriptor(),
      contact_loss_descriptor(),
      stiffness_nonlinearity_descriptor(),
      damping_drift_descriptor(),
      speed_variation_descriptor(),
      noise_descriptor(),
      hum_descriptor(),
      spikes_descriptor(),
  };
  return catalogue;
}

namespace {
struct UserRegistry {
  std::vector<UserEffect> effects;
  std::uint64_t generation = 0;
};
UserRegistry& user_registry() {
  thread_local UserRegistry r;
  return r;
}
}  // namespace

void set_user_effects(std::vector<UserEffect> effects) {
  UserRegistry& r = user_registry();
  r.effects = std::move(effects);
  ++r.generation;
}
const std::vector<UserEffect>& user_effects() { return user_registry().effects; }
std::uint64_t user_effects_generation() { return user_registry().generation; }

const EffectDescriptor* find_catalogue_effect(const std::string& name) {
  for (const auto& d : effect_catalogue())
    if (d.name == name) return &d;
  return nullptr;
}

const EffectDescriptor* find_effect(const std::string& name) {
  if (const EffectDescriptor* d = find_catalogue_effect(name)) return d;
  for (const auto& u : user_effects())
    if (u.descriptor.name == name) return &u.descriptor;
  return nullptr;
}

ResolvedEffect resolve_effect(const EffectSpec& spec) {
  const EffectDescriptor* d = find_effect(spec.name);
  if (d == nullptr) {
    std::string known;
    for (const auto& e : effect_catalogue()) known += (known.empty() ? "" : ", ") + e.name;
    for (const auto& u : user_effects()) known += ", " + u.descriptor.name;
    throw std::invalid_argument("unknown effect '" + spec.name + "' (known: " + known + ")");
  }
  ResolvedEffect r{d, {}};
  for (const auto& p : d->parameters) r.values[p.key] = p.default_value;
  for (const auto& [key, value] : spec.values) {
    const EffectParameter* param = nullptr;
    for (const auto& p : d->parameters)
      if (p.key == key) param = &p;
    if (param == nullptr) {
      std::string known;
      for (const auto& p : d->parameters) known += (known.empty() ? "" : ", ") + p.key;
      throw std::invalid_argument("effect " + spec.name + ": unknown parameter '" + key + "' (known: " +
                                  known + ")");
    }
    if (!std::isfinite(value) || value < param->min_value || value > param->max_value) {
      std::ostringstream os;
      os << "effect " << spec.name << ": " << key << ": must be in [" << param->min_value << ", "
         << param->max_value << "] " << param->unit << " (got " << value << ")";
      throw std::invalid_argument(os.str());
    }
    r.values[key] = value;
  }
  return r;
}

EffectValues null_values(const EffectDescriptor& descriptor) {
  EffectValues v;
  for (const auto& p : descriptor.parameters) v[p.key] = p.null_value.value_or(p.default_value);
  return v;
}

}  // namespace ridgewatch::model
