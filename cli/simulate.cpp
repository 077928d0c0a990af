// `ridgewatch simulate`: runs the gear-pair model (core/model/simulator.hpp) for a rig file and writes
// BASE.wav (float32; channel 1 the sensor, optional channel 2 a once-per-revolution tacho pulse, or
// with --channels vib,shafts channels 2 and 3 the shaft speeds φ̇1, φ̇2 in rad/s, see shaft_split) and
// BASE.truth.json (every parameter, the effects and their values, each impact, true ζ and f0 over
// time). Same arguments and seed -> the same bytes.
#include <charconv>
#include <cmath>
#include <fstream>
#include <ostream>
#include <sstream>
#include <set>
#include <stdexcept>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "app/rig_yaml.hpp"
#include "core/model/effect_registry.hpp"
#include "core/model/simulator.hpp"
#include "drivers/wav_writer.hpp"

namespace ridgewatch::cli {

namespace {

/// Shortest round-trip representation: deterministic and exact.
std::string num(double x) {
  char buf[32];
  const auto res = std::to_chars(buf, buf + sizeof buf, x);
  return std::string(buf, res.ptr);
}

std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
      continue;
    }
    out += c;
  }
  return out + "\"";
}

const char* quantity_name(model::SensorQuantity q) {
  switch (q) {
    case model::SensorQuantity::kDisplacement: return "displacement";
    case model::SensorQuantity::kAcceleration: return "acceleration";
    case model::SensorQuantity::kVelocity: break;
  }
  return "velocity";
}

void write_catalogue(std::ostream& out) {
  out << "{\"effects\":[";
  bool first = true;
  for (const auto& d : model::effect_catalogue()) {
    out << (first ? "" : ",") << "\n {\"name\":" << quoted(d.name) << ",\"kind\":" << quoted(model::to_string(d.kind))
        << ",\"explanation\":" << quoted(d.explanation) << ",\"signature\":" << quoted(d.signature) << ",\"parameters\":[";
    first = false;
    bool first_p = true;
    for (const auto& p : d.parameters) {
      out << (first_p ? "" : ",") << "{\"key\":" << quoted(p.key) << ",\"unit\":" << quoted(p.unit)
          << ",\"min\":" << num(p.min_value) << ",\"max\":" << num(p.max_value) << ",\"default\":" << num(p.default_value)
          << ",\"null\":" << (p.null_value ? num(*p.null_value) : "null") << ",\"description\":" << quoted(p.description) << "}";
      first_p = false;
    }
    out << "]}";
  }
  out << "\n]}\n";
}

/// The shaft speeds behind q̇ (paper Appendix A, Eq. A1): with the shaft torques constant, only the mesh
/// force F oscillates, J1 φ̈1 = -r_b1 F and J2 φ̈2 = -r_b2 F, so the oscillating speeds are in the fixed
/// ratio φ̇1 : φ̇2 = r_b1/J1 : r_b2/J2 and q̇ = r_b1 φ̇1 + r_b2 φ̇2 gives
///   φ̇1 = q̇ m_red r_b1 / J1,   φ̇2 = q̇ m_red r_b2 / J2,   m_red = 1 / (r_b1²/J1 + r_b2²/J2).
/// Split from the sensor output (q̇ times sensor.sensitivity, noise included), in rad/s.
struct ShaftSplit {
  double k1 = 0, k2 = 0;  ///< φ̇1 = k1 y, φ̇2 = k2 y, y the sensor output
};
ShaftSplit shaft_split(const model::RigParameters& rig) {
  const double m = rig.reduced_mass_kg();
  return {m * rig.pinion_base_radius_m / rig.pinion_inertia_kg_m2 / rig.sensor_sensitivity,
          m * rig.wheel_base_radius_m / rig.wheel_inertia_kg_m2 / rig.sensor_sensitivity};
}

void write_truth(const std::string& path, const std::string& rig_file, const model::RigParameters& rig,
                 const model::SimulationSettings& settings, const model::SimulationResult& r, bool tacho,
                 double noise_rel, bool shafts) {
  std::ostringstream o;
  o << "{\n\"format\":\"ridgewatch-simulate-truth/1\",\n";
  o << "\"rig_file\":" << quoted(rig_file) << ",\n";
  o << "\"sample_rate_hz\":" << num(r.sample_rate_hz) << ",\"frames\":" << r.output.size()
    << ",\"duration_s\":" << num(static_cast<double>(r.output.size()) / r.sample_rate_hz)
    << ",\"channels\":" << (tacho ? "[\"vib\",\"tacho\"]" : shafts ? "[\"vib\",\"phi1_dot\",\"phi2_dot\"]" : "[\"vib\"]")
    << ",\"seed\":" << settings.seed
    << ",\"noise_rel\":" << num(noise_rel) << ",\n";
  o << "\"integrator\":{\"method\":\"rk4\",\"substeps_per_sample\":" << r.substeps_per_sample
    << ",\"internal_rate_hz\":" << num(r.sample_rate_hz * r.substeps_per_sample)
    << ",\"located_events\":" << r.located_events << "},\n";
  o << "\"rig\":{\"J1_kg_m2\":" << num(rig.pinion_inertia_kg_m2) << ",\"J2_kg_m2\":" << num(rig.wheel_inertia_kg_m2)
    << ",\"rb1_m\":" << num(rig.pinion_base_radius_m) << ",\"rb2_m\":" << num(rig.wheel_base_radius_m)
    << ",\"pinion_teeth\":" << rig.pinion_teeth << ",\"wheel_teeth\":" << rig.wheel_teeth
    << ",\"c0_n_per_m\":" << num(rig.mean_mesh_stiffness_n_per_m) << ",\"harmonics\":[";
  for (std::size_t k = 0; k < rig.stiffness_harmonics.size(); ++k)
    o << (k ? "," : "") << "{\"c_n_per_m\":" << num(rig.stiffness_harmonics[k].amplitude_n_per_m)
      << ",\"gamma_rad\":" << num(rig.stiffness_harmonics[k].phase_rad) << "}";
  o << "],\"damping_ratio\":" << num(rig.damping_ratio) << ",\"pinion_speed_rpm\":" << num(rig.pinion_speed_rpm)
    << ",\"load_torque_n_m\":" << num(rig.load_torque_n_m) << ",\"impact_force_n\":" << num(rig.impact_force_n)
    << ",\"impact_duration_s\":" << num(rig.impact_duration_s) << ",\"impact_jitter_rel\":" << num(rig.impact_jitter_rel)
    << ",\"crack_angle_rad\":" << num(rig.crack_angle_rad) << ",\"sensor_quantity\":" << quoted(quantity_name(rig.sensor_quantity))
    << ",\"sensor_sensitivity\":" << num(rig.sensor_sensitivity) << "},\n";
  o << "\"derived\":{\"m_red_kg\":" << num(rig.reduced_mass_kg())
    << ",\"omega0_rad_per_s\":" << num(rig.natural_angular_frequency_rad_per_s()) << ",\"f0_hz\":" << num(rig.natural_frequency_hz())
    << ",\"fd_hz\":" << num(rig.damped_frequency_hz()) << ",\"d_z_n_s_per_m\":" << num(rig.mesh_damping_n_s_per_m())
    << ",\"shaft_hz\":" << num(rig.pinion_speed_hz()) << ",\"mesh_frequency_hz\":" << num(rig.mesh_frequency_hz())
    << ",\"static_force_n\":" << num(rig.static_mesh_force_n()) << ",\"static_deflection_m\":" << num(rig.static_deflection_m())
    << ",\"clean_peak\":" << num(r.clean_peak) << "},\n";
  if (shafts) {
    const ShaftSplit k = shaft_split(rig);
    o << "\"shaft_split\":{\"rule\":\"phi_dot_i = vib / sensor_sensitivity * m_red * rb_i / J_i (rad/s)\",\"phi1_per_vib\":"
      << num(k.k1) << ",\"phi2_per_vib\":" << num(k.k2) << "},\n";
  }
  o << "\"effects\":[";
  for (std::size_t i = 0; i < r.effects.size(); ++i) {
    const auto& e = r.effects[i];
    o << (i ? "," : "") << "\n {\"name\":" << quoted(e.effect.descriptor->name) << ",\"kind\":"
      << quoted(model::to_string(e.effect.descriptor->kind)) << ",\"values\":{";
    bool first = true;
    for (const auto& p : e.effect.descriptor->parameters) {
      o << (first ? "" : ",") << quoted(p.key) << ":" << num(e.effect.values.at(p.key));
      first = false;
    }
    o << "},\"units\":{";
    first = true;
    for (const auto& p : e.effect.descriptor->parameters) {
      o << (first ? "" : ",") << quoted(p.key) << ":" << quoted(p.unit);
      first = false;
    }
    o << "},\"events_s\":[";
    for (std::size_t k = 0; k < e.event_times_s.size(); ++k) o << (k ? "," : "") << num(e.event_times_s[k]);
    o << "]}";
  }
  o << "],\n\"impacts\":[";
  for (std::size_t k = 0; k < r.impacts.size(); ++k) {
    const auto& imp = r.impacts[k];
    o << (k ? "," : "") << "\n {\"t_s\":" << num(imp.t_s)
      << ",\"sample_index\":" << static_cast<std::uint64_t>(std::ceil(imp.t_s * r.sample_rate_hz))
      << ",\"peak_force_n\":" << num(imp.peak_force_n) << ",\"impulse_n_s\":" << num(imp.impulse_n_s)
      << ",\"zeta\":" << num(imp.damping_ratio) << ",\"shaft_hz\":" << num(imp.shaft_speed_hz) << "}";
  }
  o << "],\n\"revolutions_s\":[";
  for (std::size_t k = 0; k < r.revolution_times_s.size(); ++k) o << (k ? "," : "") << num(r.revolution_times_s[k]);
  o << "],\n\"truth\":[";
  for (std::size_t k = 0; k < r.truth.size(); ++k) {
    const auto& t = r.truth[k];
    o << (k ? "," : "") << "\n {\"t_s\":" << num(t.t_s) << ",\"zeta\":" << num(t.damping_ratio) << ",\"f0_hz\":" << num(t.f0_hz)
      << ",\"shaft_hz\":" << num(t.shaft_speed_hz) << ",\"mesh_frequency_hz\":" << num(t.mesh_frequency_hz) << "}";
  }
  o << "]\n}\n";
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f << o.str();
  f.close();
  if (!f) throw std::runtime_error(path + ": cannot write");
}

}  // namespace

int run_simulate(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--rig", "--effect", "--duration", "--rate", "--noise", "--seed", "--channels", "--out"},
                  {"--list-effects"});
  if (!args.positional().empty()) throw UsageError("unexpected argument '" + args.positional().front() + "'");
  if (args.has("--list-effects")) {
    write_catalogue(out);
    return kExitOk;
  }
  const auto rig_path = args.value("--rig");
  if (!rig_path) throw UsageError("--rig RIG.yaml is required");
  const auto base = args.value("--out");
  if (!base || base->empty()) throw UsageError("--out BASE is required");

  model::SimulationSettings settings;
  settings.duration_s = args.number("--duration", 2.0, 1e-3, 3600.0);
  settings.sample_rate_hz = args.number("--rate", 51200.0, 1000.0, 1e6);
  if (settings.sample_rate_hz != std::floor(settings.sample_rate_hz))
    throw UsageError("--rate: must be a whole number of hertz (WAV stores an integer rate)");
  settings.seed = static_cast<std::uint64_t>(args.integer("--seed", 1, 0, (1LL << 62)));
  const double noise_rel = args.number("--noise", 0.0, 0.0, 10.0);

  const std::string channels = args.value("--channels").value_or("vib");
  bool tacho = false, shafts = false;
  if (channels == "vib,tacho") tacho = true;
  else if (channels == "vib,shafts") shafts = true;
  else if (channels != "vib")
    throw UsageError("--channels: must be 'vib', 'vib,tacho' or 'vib,shafts' (got '" + channels + "')");

  RigConfig cfg = load_rig_yaml(*rig_path);
  std::set<std::string> cli_names;
  for (const std::string& text : args.values("--effect")) {
    model::EffectSpec spec;
    try {
      spec = model::parse_effect_spec(text);
      model::resolve_effect(spec);
    } catch (const std::invalid_argument& e) {
      throw UsageError(std::string("--effect: ") + e.what());
    }
    if (!cli_names.insert(spec.name).second) throw UsageError("--effect: " + spec.name + " given twice");
    bool replaced = false;
    for (auto& existing : cfg.effects)
      if (existing.name == spec.name) {
        existing = spec;  // the command line replaces the rig file's entry of the same name
        replaced = true;
      }
    if (!replaced) cfg.effects.push_back(spec);
  }
  if (noise_rel > 0.0) {
    for (const auto& e : cfg.effects)
      if (e.name == "noise") throw UsageError("--noise: the noise effect is already given (use one of them)");
    cfg.effects.push_back({"noise", {{"std_rel", noise_rel}}});
  }

  model::SimulationResult result;
  try {
    result = model::simulate(cfg.rig, cfg.effects, settings);
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }

  std::vector<double> samples;
  if (tacho) {
    samples.resize(2 * result.output.size());
    for (std::size_t i = 0; i < result.output.size(); ++i) {
      samples[2 * i] = result.output[i];
      samples[2 * i + 1] = result.tacho[i];
    }
  } else if (shafts) {
    if (cfg.rig.sensor_quantity != model::SensorQuantity::kVelocity)
      throw UsageError("--channels vib,shafts: the rig's sensor.quantity must be velocity (the split is of q̇)");
    const ShaftSplit k = shaft_split(cfg.rig);
    samples.resize(3 * result.output.size());
    for (std::size_t i = 0; i < result.output.size(); ++i) {
      samples[3 * i] = result.output[i];
      samples[3 * i + 1] = k.k1 * result.output[i];
      samples[3 * i + 2] = k.k2 * result.output[i];
    }
  } else {
    samples = result.output;
  }
  try {
    drivers::write_wav(*base + ".wav", samples, settings.sample_rate_hz, shafts ? 3 : tacho ? 2 : 1);
    write_truth(*base + ".truth.json", *rig_path, cfg.rig, settings, result, tacho, noise_rel, shafts);
  } catch (const std::runtime_error& e) {
    throw UsageError(std::string("--out: ") + e.what());
  }
  err << "simulate: wrote " << *base << ".wav (" << result.output.size() << " frames, " << (shafts ? 3 : tacho ? 2 : 1)
      << " channel(s), " << result.impacts.size() << " impacts, f0 " << cfg.rig.natural_frequency_hz() << " Hz) and "
      << *base << ".truth.json\n";
  return kExitOk;
}

}  // namespace ridgewatch::cli
