// The survey's report (core/survey/survey.hpp) as text or JSON, the proposed `pipeline:` block and
// --write-config, shared by `ridgewatch survey` and `ridgewatchd --survey SECONDS`.
#include "app/survey_report.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <ostream>
#include <sstream>
#include <stdexcept>

#include "app/args.hpp"
#include "app/config_yaml.hpp"
#include "app/yaml_reader.hpp"
#include "drivers/sample_source.hpp"

namespace ridgewatch::app {

namespace {

using nlohmann::json;

json num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

std::string f3(double v, int digits = 4) {
  if (!std::isfinite(v)) return "n/a";
  char b[64];
  std::snprintf(b, sizeof b, "%.*g", digits, v);
  return b;
}

json to_json(const survey::SurveyResult& r, const std::string& name) {
  json j;
  j["file"] = name;
  j["sample_rate_hz"] = r.sample_rate_hz;
  j["samples"] = r.samples;
  j["spikes_removed"] = r.spikes_removed;
  j["peak_abs"] = num(r.peak_abs);
  j["impacts_found"] = r.impacts_found;
  j["evidence"] = r.evidence;
  json band;
  band["lo_hz"] = num(r.band_lo_hz);
  band["hi_hz"] = num(r.band_hi_hz);
  band["kurtosis"] = num(r.band_kurtosis);
  band["z"] = num(r.band_z);
  for (const auto& c : r.kurtogram.cells)
    if (c.f_lo_hz == r.band_lo_hz && c.f_hi_hz == r.band_hi_hz) band["level"] = c.level;
  j["band"] = band;
  json cells = json::array();
  for (const auto& c : r.kurtogram.cells) cells.push_back({c.level, c.f_lo_hz, c.f_hi_hz, num(c.kurtosis)});
  j["kurtogram"] = {{"columns", {"level", "f_lo_hz", "f_hi_hz", "kurtosis"}}, {"cells", cells}};
  json imp;
  imp["period_s"] = num(r.period_s);
  imp["rate_hz"] = num(r.rate_hz);
  imp["speed_variation_pct"] = num(r.speed_variation_pct);
  imp["regular_fraction"] = num(r.regular_fraction);
  imp["acf_peak"] = num(r.acf_peak);
  imp["contrast_db"] = num(10 * std::log10(r.contrast));
  imp["shaft_order"] = num(r.shaft_order);
  imp["count"] = r.impact_times_s.size();
  imp["times_s"] = r.impact_times_s;
  j["impacts"] = imp;
  json modes = json::array();
  for (const auto& m : r.modes)
    modes.push_back({{"f_hz", num(m.f_hz)}, {"zeta", num(m.zeta)}, {"zeta_quartiles", {num(m.zeta_q1), num(m.zeta_q3)}},
                     {"amplitude", num(m.amplitude)}, {"segments", m.segments}, {"averaged_over", m.averaged_over}, {"eta0_needed", num(m.eta0_needed)}});
  j["modes"] = modes;
  j["segments_analysed"] = r.segments_analysed;
  j["decay_left_at_next_impact"] = num(r.decay_per_period);
  j["trigger_headroom"] = num(r.trigger_headroom);
  j["lines_hz"] = r.line_hz;
  j["mean_envelope"] = {{"rate_hz", num(r.envelope_rate_hz)}, {"values", r.mean_envelope}};
  if (r.proposal) {
    const auto& p = *r.proposal;
    json d = {{"band_lo_hz", p.detector.band_lo_hz}, {"band_hi_hz", p.detector.band_hi_hz},
              {"trigger_ratio", p.detector.trigger_ratio}, {"holdoff_s", p.detector.holdoff_s},
              {"trigger_innovation", p.detector.trigger_innovation}, {"trigger_noise_ratio", p.detector.trigger_noise_ratio}};
    json a = {{"f_expected_hz", p.analyzer.f_expected_hz}, {"band_rel", p.analyzer.band_rel}, {"eta0", p.analyzer.eta0},
              {"ml_band_rel", p.analyzer.ml_band_rel}, {"window_s", p.analyzer.window_s},
              {"clip_level", p.analyzer.clip_level}};
    j["proposal"] = {{"pipeline", {{"detector", d}, {"analyzer", a}}}, {"notes", p.notes}};
  } else {
    j["proposal"] = nullptr;
  }
  return j;
}

std::string text_report(const survey::SurveyResult& r, const std::string& name) {
  std::ostringstream o;
  o << "survey: " << name << ": " << f3(r.sample_rate_hz, 6) << " Hz, " << f3(static_cast<double>(r.samples) / r.sample_rate_hz)
    << " s, " << r.spikes_removed << " spikes removed\n";
  o << "band of the periodic bursts (fast kurtogram): " << f3(r.band_lo_hz, 5) << " - " << f3(r.band_hi_hz, 5)
    << " Hz, spectral kurtosis " << f3(r.band_kurtosis, 3) << " (z " << f3(r.band_z, 3) << ")\n";
  if (std::isfinite(r.period_s)) {
    o << "band-envelope period: " << f3(r.period_s * 1e3) << " ms (" << f3(r.rate_hz) << " per second), autocorrelation "
      << f3(r.acf_peak, 2) << ", " << r.impact_times_s.size() << " bursts, " << f3(100 * r.regular_fraction, 3)
      << " % regular, speed variation +-" << f3(r.speed_variation_pct, 2) << " %";
    if (std::isfinite(r.shaft_order)) o << ", " << f3(r.shaft_order, 3) << " x the pinion shaft speed";
    o << "\n";
  }
  for (std::size_t i = 0; i < r.modes.size(); ++i) {
    const auto& m = r.modes[i];
    o << (i == 0 ? "ringing mode: " : "further mode: ") << f3(m.f_hz, 6) << " Hz, zeta " << f3(m.zeta, 3);
    if (m.averaged_over > 0)  // no single free response holds it: a first zeta from the averaged decay
      o << ", from the spectra and band power averaged over " << m.averaged_over << " impacts\n";
    else
      o << " (quartiles " << f3(m.zeta_q1, 3) << " .. " << f3(m.zeta_q3, 3) << "), in " << m.segments << " of "
        << r.segments_analysed << " free responses\n";
  }
  o << "evidence:\n";
  for (const auto& e : r.evidence) o << "  " << e << "\n";
  if (!r.impacts_found) {
    o << "no repeated impacts found: no proposal\n";
  } else if (r.proposal) {
    o << "repeated impacts: " << f3(r.rate_hz) << " per second ringing at " << f3(r.modes[0].f_hz, 5) << " Hz\n";
    o << "proposal (ridgewatch analyze --config / ridgewatchd):\n" << proposal_yaml(*r.proposal);
    for (const auto& n : r.proposal->notes) o << "note: " << n << "\n";
  }
  return o.str();
}

// `rig:` is read relative to the configuration file's directory (cli/config_yaml.hpp); the copy may
// be written to another directory, so a relative rig path of the base file is rewritten relative to
// the copy's directory (absolute when no relative path leads there, e.g. another drive root).
std::string rig_path_for_copy(const std::string& rig, const std::optional<std::string>& base, const std::string& out) {
  namespace fs = std::filesystem;
  if (rig.empty() || fs::path(rig).is_absolute() || !base) return rig;
  const fs::path target = fs::absolute(fs::path(*base).parent_path() / rig).lexically_normal();
  const fs::path out_dir = fs::absolute(fs::path(out)).parent_path().lexically_normal();
  const fs::path rel = target.lexically_relative(out_dir);
  return rel.empty() ? target.string() : rel.string();
}

}  // namespace

std::string proposal_yaml(const survey::Proposal& p) {
  auto f = [](double v) { return YamlReader::format(v); };
  std::ostringstream o;
  o << "pipeline:\n  detector:\n"
    << "    band_lo_hz: " << f(p.detector.band_lo_hz) << "\n"
    << "    band_hi_hz: " << f(p.detector.band_hi_hz) << "\n"
    << "    trigger_ratio: " << f(p.detector.trigger_ratio) << "\n"
    << "    holdoff_s: " << f(p.detector.holdoff_s) << "\n"
    << "    trigger_innovation: " << (p.detector.trigger_innovation ? "true" : "false") << "\n"
    << "    trigger_noise_ratio: " << f(p.detector.trigger_noise_ratio) << "\n"
    << "  analyzer:\n"
    << "    f_expected_hz: " << f(p.analyzer.f_expected_hz) << "\n"
    << "    band_rel: " << f(p.analyzer.band_rel) << "\n"
    << "    eta0: " << f(p.analyzer.eta0) << "\n"
    << "    ml_band_rel: " << f(p.analyzer.ml_band_rel) << "\n"
    << "    window_s: " << f(p.analyzer.window_s) << "\n"
    << "    clip_level: " << f(p.analyzer.clip_level) << "\n";
  return o.str();
}

void check_survey_output(const SurveyOutput& out) {
  if (out.write_config) {
    if (out.write_config->empty()) throw UsageError("--write-config: needs a file name");
    std::error_code ec;
    if (out.base_config && std::filesystem::equivalent(*out.base_config, *out.write_config, ec))
      throw UsageError("--write-config: '" + *out.write_config + "' is the --config file itself; the proposal is written to a copy");
  }
}

int survey_and_report(const std::vector<double>& samples, double fs, const std::string& name,
                      const survey::SurveyOptions& options, const SurveyOutput& output, std::ostream& out,
                      std::ostream& err) {
  // Base configuration first: a bad --config is exit 2 before the work.
  RidgewatchConfig base = output.base_config ? load_config_file(*output.base_config) : default_config();
  survey::SurveyResult r;
  try {
    r = survey::run_survey(samples, fs, options);
  } catch (const std::invalid_argument& e) {
    throw drivers::InputError(name + ": " + e.what());
  }
  const std::string text = text_report(r, name);
  if (output.json) {
    out << to_json(r, name).dump() << "\n";
  } else {
    out << text;
  }
  out.flush();
  if (output.write_plots) output.write_plots(r, name, text);
  if (output.write_config) {
    if (!r.proposal) {
      err << "survey: no repeated impacts found: " << *output.write_config << " not written\n";
      return kExitOk;
    }
    RidgewatchConfig c = base;
    const auto& p = *r.proposal;
    c.pipeline.detector.band_lo_hz = p.detector.band_lo_hz;
    c.pipeline.detector.band_hi_hz = p.detector.band_hi_hz;
    c.pipeline.detector.trigger_ratio = p.detector.trigger_ratio;
    c.pipeline.detector.holdoff_s = p.detector.holdoff_s;
    c.pipeline.detector.trigger_innovation = p.detector.trigger_innovation;
    c.pipeline.detector.trigger_noise_ratio = p.detector.trigger_noise_ratio;
    c.pipeline.analyzer.f_expected_hz = p.analyzer.f_expected_hz;
    c.pipeline.analyzer.band_rel = p.analyzer.band_rel;
    c.pipeline.analyzer.eta0 = p.analyzer.eta0;
    c.pipeline.analyzer.ml_band_rel = p.analyzer.ml_band_rel;
    c.pipeline.analyzer.window_s = p.analyzer.window_s;
    c.pipeline.analyzer.clip_level = p.analyzer.clip_level;
    c.rig = rig_path_for_copy(c.rig, output.base_config, *output.write_config);
    std::ofstream f(*output.write_config, std::ios::binary | std::ios::trunc);
    f << "# ridgewatch configuration: " << (output.base_config ? *output.base_config : std::string("the defaults"))
      << " with the pipeline proposed by `ridgewatch survey` on " << name << "\n"
      << "# Every key is documented in config/ridgewatch.yaml.\n"
      << to_yaml(c);
    f.close();
    if (!f) throw UsageError("--write-config: cannot write " + *output.write_config);
    // The written file must read back as a valid configuration for this sample rate.
    RidgewatchConfig back = load_config_file(*output.write_config);
    back.pipeline.sample_rate_hz = fs;
    try {
      pipeline::validate(back.pipeline);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(std::string("proposal rejected by the pipeline: ") + e.what());
    }
    err << "survey: wrote " << *output.write_config << "\n";
  }
  return kExitOk;
}

}  // namespace ridgewatch::app
