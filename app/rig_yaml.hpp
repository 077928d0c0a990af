// Rig description files (config/rigs/*.yaml) -> model::RigParameters and the effect list.
// Every problem is a UsageError whose message names the file and the YAML path, e.g.
// "rig.yaml: gear.J1: must be > 0 (got -0.1)". Key by key documentation: config/rigs/paper-rig.yaml;
// user-defined effects (model.custom_effects): config/examples/rig-custom-effect.yaml.
#pragma once

#include <string>
#include <vector>

#include "core/model/effect.hpp"
#include "core/model/effect_registry.hpp"
#include "core/model/rig_parameters.hpp"

namespace ridgewatch::app {

struct RigConfig {
  model::RigParameters rig;
  std::vector<model::EffectSpec> effects;  ///< model.effects, checked against the catalogue
  /// model.custom_effects, compiled and checked (core/model/custom_effect.hpp). Loading the file
  /// also makes them visible to the effect lookups of the calling thread (model::set_user_effects).
  std::vector<model::UserEffect> custom_effects;
};

/// Reads and checks a rig file. Throws UsageError (exit 2) naming the file and key.
RigConfig load_rig_yaml(const std::string& path);

/// Same, from text; `name` is used in messages in place of the file name.
RigConfig parse_rig_yaml(const std::string& text, const std::string& name);

}  // namespace ridgewatch::app
