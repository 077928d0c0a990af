// Shared by `ridgewatch compare` and `ridgewatch diagnose`: flags, loading the rig and the recording,
// and the JSON of a fit (cli/compare.cpp, cli/diagnose.cpp).
#pragma once

#include <nlohmann/json.hpp>
#include <cmath>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>

#include "cli/app_names.hpp"
#include "app/args.hpp"
#include "cli/replay_flags.hpp"
#include "app/rig_yaml.hpp"
#include "core/diagnosis/diagnose.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli::diag {

struct Loaded {
  RigConfig rig;
  std::vector<std::string> effects;  ///< model effects: rig model.effects (diagnosable ones) + --with
  /// --with NAME:key=value (a start) and key=value! (fixed), by "<effect>.<key>".
  std::map<std::string, diagnosis::ModelFitter::ParameterSetting> settings;
  std::vector<std::string> ignored;  ///< rig model.effects that are not fitted (sensor/kinematics)
  std::string path;
  std::vector<double> y;
  diagnosis::Segmentation seg;
};

inline Loaded load(const Args& args) {
  Loaded l;
  const auto rig_path = args.value("--rig");
  if (!rig_path) throw UsageError("--rig RIG.yaml is required");
  l.path = single_file(args);
  l.rig = load_rig_yaml(*rig_path);
  for (const auto& e : l.rig.effects) {
    if (diagnosis::find_candidate(e.name)) l.effects.push_back(e.name);
    else l.ignored.push_back(e.name);
  }
  for (const auto& text : args.values("--with")) {
    // NAME or NAME:key=value,key=value! ('!' fixes the value; without it the value is the start).
    const auto colon = text.find(':');
    const std::string name = text.substr(0, colon);
    if (!diagnosis::find_candidate(name)) {
      std::string known;
      for (const auto& c : diagnosis::candidate_names()) known += (known.empty() ? "" : ", ") + c;
      throw UsageError("--with: '" + name + "' is not a model effect that can be fitted (known: " + known + ")");
    }
    if (colon != std::string::npos) {
      const std::string rest = text.substr(colon + 1);
      std::size_t pos = 0;
      while (true) {
        const auto comma = rest.find(',', pos);
        std::string item = rest.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
        const auto eq = item.find('=');
        if (eq == std::string::npos || eq == 0)
          throw UsageError("--with " + name + ": '" + item + "' is not key=value (or key=value! to fix it)");
        diagnosis::ModelFitter::ParameterSetting setting;
        std::string value = item.substr(eq + 1);
        if (!value.empty() && value.back() == '!') {
          setting.fixed = true;
          value.pop_back();
        }
        char* end = nullptr;
        setting.value = std::strtod(value.c_str(), &end);
        if (value.empty() || end != value.c_str() + value.size() || !std::isfinite(setting.value))
          throw UsageError("--with " + name + ": " + item.substr(0, eq) + ": '" + value + "' is not a number");
        if (!l.settings.emplace(name + "." + item.substr(0, eq), setting).second)
          throw UsageError("--with " + name + ": " + item.substr(0, eq) + " given twice");
        if (comma == std::string::npos) break;
        pos = comma + 1;
      }
    }
    if (std::find(l.effects.begin(), l.effects.end(), name) == l.effects.end()) l.effects.push_back(name);
  }
  auto source = drivers::open_replay(l.path, replay_options(args));
  const double fs = source->info().sample_rate_hz;
  l.y = drivers::read_all(*source);
  try {
    l.seg = diagnosis::segment_recording(l.y, fs, l.rig.rig);
  } catch (const std::invalid_argument& e) {
    throw UsageError(*rig_path + ": " + e.what() + " (with the sample rate of " + l.path + ")");
  }
  if (l.seg.windows.size() < 4)
    throw drivers::InputError(l.path + ": found " + std::to_string(l.seg.windows.size()) +
                              " usable impacts; compare/diagnose need at least 4 (2 to fit, 2 to hold out)");
  return l;
}

/// Applies --with's parameter values to a fitter (exit 2 naming the flag when one does not fit).
inline void apply_settings(diagnosis::ModelFitter& fitter, const Loaded& l) {
  try {
    fitter.set_parameter_settings(l.settings);
  } catch (const std::invalid_argument& e) {
    throw UsageError(std::string("--with: ") + e.what());
  }
}

/// Runs a fit (or the diagnose loop); a user-defined effect whose force turns non-finite during the
/// fit stops the command with exit 2 naming the rig file (the model, not the data, is at fault).
template <class F>
auto guard_user_effects(const std::string& rig_path, F&& f) {
  try {
    return f();
  } catch (const std::domain_error& e) {
    throw UsageError(rig_path + ": " + e.what());
  }
}

inline nlohmann::json estimate_json(const diagnosis::ParameterEstimate& e) {
  return {{"name", e.name}, {"value", e.value}, {"sd", e.sd}, {"ci95", {e.ci95_lo, e.ci95_hi}}, {"at_bound", e.at_bound}};
}

inline nlohmann::json nan_null(const std::vector<double>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (double x : v) a.push_back(std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr));
  return a;
}

inline nlohmann::json report_json(const diagnosis::ResidualReport& r) {
  nlohmann::json peaks = nlohmann::json::array();
  for (const auto& p : r.peaks) peaks.push_back({{"f_hz", p.f_hz}, {"level", p.level}, {"marker", p.marker}});
  nlohmann::json markers = nlohmann::json::object();
  for (const auto& [n, f] : r.markers) markers[n] = f;
  return {{"f0_hz", r.f0_hz},
          {"mesh_frequency_hz", r.fz_hz},
          {"excess_vs_time", {{"dt_ms", r.dt_ms}, {"excess", nan_null(r.excess_vs_time)}}},
          {"impacts", {{"t_s", r.impact_time_s}, {"amplitude_rel", r.impact_amplitude}, {"excess", r.impact_excess}}},
          {"spectrum", {{"f_hz", r.spectrum_f_hz}, {"level", r.spectrum_level}, {"peaks", peaks}, {"markers", markers}}},
          {"whiteness", {{"ljung_box_q", r.ljung_box_q}, {"limit_999", r.ljung_box_limit}, {"white", r.white}}},
          {"backbone",
           {{"amplitude_rel", r.measured.amplitude_rel},
            {"measured", {{"zeta", nan_null(r.measured.zeta)}, {"f_hz", nan_null(r.measured.f_hz)}}},
            {"model", {{"zeta", nan_null(r.model.zeta)}, {"f_hz", nan_null(r.model.f_hz)}}}}},
          {"spikes", r.spikes},
          {"dropouts", r.dropouts}};
}

}  // namespace ridgewatch::cli::diag
