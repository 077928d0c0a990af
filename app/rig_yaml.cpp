#include "app/rig_yaml.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>

#include "app/args.hpp"
#include "app/yaml_reader.hpp"
#include "core/model/custom_effect.hpp"
#include "core/model/effect_registry.hpp"

namespace ridgewatch::app {

namespace {

using Reader = YamlReader;

model::EffectSpec read_effect(const Reader& r, const YAML::Node& node, const std::string& path) {
  model::EffectSpec spec;
  if (node.IsScalar()) {
    try {
      spec = model::parse_effect_spec(node.Scalar());
    } catch (const std::invalid_argument& e) {
      r.fail(path, e.what());
    }
  } else if (node.IsMap()) {
    if (!node["name"]) r.fail(path + ".name", "missing (required)");
    if (!node["name"].IsScalar()) r.fail(path + ".name", "must be a string");
    spec.name = node["name"].Scalar();
    for (const auto& kv : node) {
      const std::string key = kv.first.as<std::string>();
      if (key == "name") continue;
      spec.values[key] = r.number(kv.second, path + "." + key);
    }
  } else {
    r.fail(path, "must be an effect name, \"name:key=value,...\" or a mapping with 'name'");
  }
  try {
    model::resolve_effect(spec);
  } catch (const std::invalid_argument& e) {
    r.fail(path, e.what());
  }
  return spec;
}

/// model.custom_effects[k]: {name, force, parameters: {key: {unit, min, max, default, null, start}},
/// kinks: [switching function, ...]}.
model::UserEffect read_custom_effect(const Reader& r, const YAML::Node& node, const std::string& path) {
  if (!node.IsMap()) r.fail(path, "must be a mapping with name, force and parameters");
  r.check_map(node, path, {"name", "force", "parameters", "kinks"});
  model::CustomEffectDefinition def;
  for (const char* key : {"name", "force"}) {
    if (!node[key]) r.fail(path + "." + key, "missing (required)");
    if (!node[key].IsScalar()) r.fail(path + "." + key, "must be a string");
  }
  def.name = node["name"].Scalar();
  def.force = node["force"].Scalar();
  if (const YAML::Node params = node["parameters"]) {
    if (!params.IsMap()) r.fail(path + ".parameters", "must be a mapping of parameter name to {unit, min, max, default, null, start}");
    for (const auto& kv : params) {
      model::EffectParameter p;
      p.key = kv.first.as<std::string>();
      const std::string ppath = path + ".parameters." + p.key;
      const YAML::Node v = kv.second;
      // Keys read by hand: YAML reads the key `null` (the spelling of the null value) as a
      // null node, not as the string "null".
      if (!v.IsMap()) r.fail(ppath, "must be a mapping {unit, min, max, default, null, start}");
      std::map<std::string, YAML::Node> keys;
      for (const auto& q : v) {
        std::string key;
        if (q.first.IsNull()) key = "null";
        else if (q.first.IsScalar()) key = q.first.Scalar();
        else r.fail(ppath, "keys must be plain names");
        static const std::set<std::string> allowed = {"unit", "min", "max", "default", "null", "start", "description"};
        if (!allowed.count(key))
          r.fail(ppath + "." + key, "unknown key (known: default, description, max, min, null, start, unit)");
        keys[key] = q.second;
      }
      if (keys.count("unit")) {
        if (!keys["unit"].IsScalar()) r.fail(ppath + ".unit", "must be a string");
        p.unit = keys["unit"].Scalar();
      } else {
        p.unit = "1";
      }
      for (const char* key : {"min", "max", "default"})
        if (!keys.count(key)) r.fail(ppath + "." + key, "missing (required)");
      p.min_value = r.number(keys["min"], ppath + ".min");
      p.max_value = r.number(keys["max"], ppath + ".max");
      p.default_value = r.number(keys["default"], ppath + ".default");
      if (keys.count("null")) p.null_value = r.number(keys["null"], ppath + ".null");
      if (keys.count("start")) def.starts[p.key] = r.number(keys["start"], ppath + ".start");
      if (keys.count("description") && keys["description"].IsScalar()) p.description = keys["description"].Scalar();
      def.parameters.push_back(p);
    }
  }
  if (const YAML::Node kinks = node["kinks"]) {
    if (!kinks.IsSequence()) r.fail(path + ".kinks", "must be a list of expressions (switching functions)");
    for (std::size_t k = 0; k < kinks.size(); ++k) {
      if (!kinks[k].IsScalar()) r.fail(path + ".kinks[" + std::to_string(k) + "]", "must be a string");
      def.kinks.push_back(kinks[k].Scalar());
    }
  }
  try {
    return {model::make_custom_effect(def), def.starts};
  } catch (const model::CustomEffectError& e) {
    r.fail(path, e.what());
  }
}

}  // namespace

namespace {
RigConfig parse_rig_yaml_unguarded(const std::string& text, const std::string& name) {
  const Reader r(name);
  const YAML::Node root = r.parse(text);
  r.check_map(root, "", {"gear", "mesh", "operation", "excitation", "sensor", "model"});

  RigConfig cfg;
  model::RigParameters& rig = cfg.rig;

  if (!root["gear"]) r.fail("gear", "missing (required)");
  const YAML::Node gear = root["gear"];
  r.check_map(gear, "gear", {"J1", "J2", "rb1", "rb2", "pinion_teeth", "wheel_teeth"});
  rig.pinion_inertia_kg_m2 = r.required(gear, "gear", "J1", "positive");
  rig.wheel_inertia_kg_m2 = r.required(gear, "gear", "J2", "positive");
  rig.pinion_base_radius_m = r.required(gear, "gear", "rb1", "positive");
  rig.wheel_base_radius_m = r.required(gear, "gear", "rb2", "positive");
  rig.pinion_teeth = r.required_count(gear, "gear", "pinion_teeth");
  rig.wheel_teeth = r.required_count(gear, "gear", "wheel_teeth");

  if (!root["mesh"]) r.fail("mesh", "missing (required)");
  const YAML::Node mesh = root["mesh"];
  r.check_map(mesh, "mesh", {"c0", "harmonics", "damping_ratio", "d_z"});
  rig.mean_mesh_stiffness_n_per_m = r.required(mesh, "mesh", "c0", "positive");
  rig.stiffness_harmonics.clear();
  if (const YAML::Node h = mesh["harmonics"]) {
    if (!h.IsSequence()) r.fail("mesh.harmonics", "must be a list of {c: N/m, gamma: rad}");
    double sum = 0.0;
    for (std::size_t k = 0; k < h.size(); ++k) {
      const std::string path = "mesh.harmonics[" + std::to_string(k) + "]";
      r.check_map(h[k], path, {"c", "gamma"});
      model::StiffnessHarmonic term;
      term.amplitude_n_per_m = r.required(h[k], path, "c", "non-negative");
      term.phase_rad = r.required(h[k], path, "gamma", "any");
      sum += term.amplitude_n_per_m;
      rig.stiffness_harmonics.push_back(term);
    }
    if (sum >= rig.mean_mesh_stiffness_n_per_m)
      r.fail("mesh.harmonics", "sum of c must be < mesh.c0 so that c_z(t) stays > 0 (got " + Reader::format(sum) + ")");
  }
  const bool has_zeta = static_cast<bool>(mesh["damping_ratio"]), has_dz = static_cast<bool>(mesh["d_z"]);
  if (has_zeta == has_dz) r.fail("mesh.damping_ratio", "give exactly one of mesh.damping_ratio and mesh.d_z");
  if (has_zeta) {
    rig.damping_ratio = r.required(mesh, "mesh", "damping_ratio", "non-negative");
    if (rig.damping_ratio >= 1.0) r.fail("mesh.damping_ratio", "must be < 1 (got " + Reader::format(rig.damping_ratio) + ")");
  } else {
    const double dz = r.required(mesh, "mesh", "d_z", "non-negative");
    rig.damping_ratio = dz / (2.0 * std::sqrt(rig.mean_mesh_stiffness_n_per_m * rig.reduced_mass_kg()));  // Eq. A2
    if (rig.damping_ratio >= 1.0) r.fail("mesh.d_z", "gives a damping ratio >= 1 (got " + Reader::format(dz) + ")");
  }

  if (!root["operation"]) r.fail("operation", "missing (required)");
  const YAML::Node op = root["operation"];
  r.check_map(op, "operation", {"pinion_speed_rpm", "load_torque_n_m"});
  rig.pinion_speed_rpm = r.required(op, "operation", "pinion_speed_rpm", "positive");
  rig.load_torque_n_m = r.optional(op, "operation", "load_torque_n_m", "non-negative", rig.load_torque_n_m);

  if (const YAML::Node ex = root["excitation"]) {
    r.check_map(ex, "excitation", {"impact_force_n", "impact_duration_s", "impact_jitter_rel", "crack_angle_rad"});
    rig.impact_force_n = r.optional(ex, "excitation", "impact_force_n", "non-negative", rig.impact_force_n);
    rig.impact_duration_s = r.optional(ex, "excitation", "impact_duration_s", "positive", rig.impact_duration_s);
    rig.impact_jitter_rel = r.optional(ex, "excitation", "impact_jitter_rel", "non-negative", rig.impact_jitter_rel);
    rig.crack_angle_rad = r.optional(ex, "excitation", "crack_angle_rad", "any", rig.crack_angle_rad);
    if (rig.impact_jitter_rel >= 1.0) r.fail("excitation.impact_jitter_rel", "must be < 1 (got " + Reader::format(rig.impact_jitter_rel) + ")");
    if (rig.impact_duration_s >= 0.5 / rig.pinion_speed_hz())
      r.fail("excitation.impact_duration_s", "must be < half a revolution (got " + Reader::format(rig.impact_duration_s) + ")");
  }

  if (const YAML::Node sensor = root["sensor"]) {
    r.check_map(sensor, "sensor", {"quantity", "sensitivity"});
    if (const YAML::Node q = sensor["quantity"]) {
      const std::string v = q.IsScalar() ? q.Scalar() : "";
      if (v == "velocity") rig.sensor_quantity = model::SensorQuantity::kVelocity;
      else if (v == "displacement") rig.sensor_quantity = model::SensorQuantity::kDisplacement;
      else if (v == "acceleration") rig.sensor_quantity = model::SensorQuantity::kAcceleration;
      else r.fail("sensor.quantity", "must be velocity, displacement or acceleration (got '" + v + "')");
    }
    rig.sensor_sensitivity = r.optional(sensor, "sensor", "sensitivity", "positive", rig.sensor_sensitivity);
  }

  // The rig file defines the user effects of the command that loads it (none when it has none).
  model::set_user_effects({});
  if (const YAML::Node m = root["model"]) {
    r.check_map(m, "model", {"effects", "custom_effects"});
    if (const YAML::Node custom = m["custom_effects"]) {
      if (!custom.IsSequence()) r.fail("model.custom_effects", "must be a list");
      std::set<std::string> names;
      for (std::size_t k = 0; k < custom.size(); ++k) {
        const std::string path = "model.custom_effects[" + std::to_string(k) + "]";
        cfg.custom_effects.push_back(read_custom_effect(r, custom[k], path));
        if (!names.insert(cfg.custom_effects.back().descriptor.name).second)
          r.fail(path, "effect " + cfg.custom_effects.back().descriptor.name + " defined twice");
      }
      model::set_user_effects(cfg.custom_effects);
    }
    if (const YAML::Node effects = m["effects"]) {
      if (!effects.IsSequence()) r.fail("model.effects", "must be a list");
      std::set<std::string> names;
      for (std::size_t k = 0; k < effects.size(); ++k) {
        const std::string path = "model.effects[" + std::to_string(k) + "]";
        cfg.effects.push_back(read_effect(r, effects[k], path));
        if (!names.insert(cfg.effects.back().name).second) r.fail(path, "effect " + cfg.effects.back().name + " given twice");
      }
    }
  }

  try {
    rig.validate();  // anything the per-key checks above did not cover
  } catch (const std::invalid_argument& e) {
    r.fail("", e.what());
  }
  return cfg;
}
}  // namespace

RigConfig parse_rig_yaml(const std::string& text, const std::string& name) {
  // Any structure yaml-cpp itself rejects while the keys are read (e.g. a subscript of a scalar, a
  // key that is not a scalar) is a configuration error with the file's name and yaml-cpp's line and
  // column, never an internal error (found by fuzz/fuzz_rig).
  try {
    return parse_rig_yaml_unguarded(text, name);
  } catch (const YAML::Exception& e) {
    throw UsageError(name + ": unexpected YAML structure: " + e.what());
  }
}

RigConfig load_rig_yaml(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw UsageError(path + ": cannot open rig file");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_rig_yaml(text.str(), path);
}

}  // namespace ridgewatch::app
