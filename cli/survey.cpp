// `ridgewatch survey FILE [--channel N] [--rate HZ] [--json] [--plots DIR] [--write-config OUT.yaml]
//                         [--config F] [--rig RIG.yaml] [--fmin HZ] [--fmax HZ]`
// Where the impacts of an unknown rig are and how to configure the pipeline for them
// (core/survey/survey.hpp). stdout: the text report or one JSON object; exit 0 also when the record
// holds no repeated impacts (then there is no proposal and nothing is written).
#include "cli/survey.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <ostream>
#include <sstream>
#include <stdexcept>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "app/config_yaml.hpp"
#include "cli/plot_diagnosis.hpp"
#include "cli/plot_svg.hpp"
#include "cli/replay_flags.hpp"
#include "app/rig_yaml.hpp"
#include "app/yaml_reader.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

namespace {

using nlohmann::json;
constexpr double kPi = 3.141592653589793;

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
                     {"amplitude", num(m.amplitude)}, {"segments", m.segments}});
  j["modes"] = modes;
  j["segments_analysed"] = r.segments_analysed;
  j["decay_left_at_next_impact"] = num(r.decay_per_period);
  j["trigger_headroom"] = num(r.trigger_headroom);
  j["lines_hz"] = r.line_hz;
  j["mean_envelope"] = {{"rate_hz", num(r.envelope_rate_hz)}, {"values", r.mean_envelope}};
  if (r.proposal) {
    const auto& p = *r.proposal;
    json d = {{"band_lo_hz", p.detector.band_lo_hz}, {"band_hi_hz", p.detector.band_hi_hz},
              {"trigger_ratio", p.detector.trigger_ratio}, {"holdoff_s", p.detector.holdoff_s}};
    json a = {{"f_expected_hz", p.analyzer.f_expected_hz}, {"band_rel", p.analyzer.band_rel},
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
  for (std::size_t i = 0; i < r.modes.size(); ++i)
    o << (i == 0 ? "ringing mode: " : "further mode: ") << f3(r.modes[i].f_hz, 6) << " Hz, zeta " << f3(r.modes[i].zeta, 3)
      << " (quartiles " << f3(r.modes[i].zeta_q1, 3) << " .. " << f3(r.modes[i].zeta_q3, 3) << "), in "
      << r.modes[i].segments << " of " << r.segments_analysed << " free responses\n";
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

plots::PlotFile kurtogram_plot(const survey::SurveyResult& r) {
  namespace pl = plot;
  const auto& k = r.kurtogram;
  const double nyq = r.sample_rate_hz / 2;
  // One heat-map row per level; columns at the finest band width.
  double finest = nyq;
  for (const auto& c : k.cells) finest = std::min(finest, c.f_hi_hz - c.f_lo_hz);
  const auto cols = static_cast<std::size_t>(std::min(1024.0, std::ceil(nyq / finest)));
  const std::size_t rows = k.levels.size();
  std::vector<double> v(rows * cols, NAN);
  double vmax = 0;
  for (const auto& c : k.cells) {
    std::size_t row = 0;
    while (row < rows && k.levels[row] != c.level) ++row;
    if (row == rows) continue;
    const auto a = static_cast<std::size_t>(std::floor(c.f_lo_hz / nyq * static_cast<double>(cols)));
    const auto b = static_cast<std::size_t>(std::ceil(c.f_hi_hz / nyq * static_cast<double>(cols)));
    const double val = std::isfinite(c.kurtosis) ? std::max(0.0, c.kurtosis) : NAN;
    for (std::size_t col = a; col < std::min(b, cols); ++col) v[(rows - 1 - row) * cols + col] = val;  // level 1 at the top
    if (std::isfinite(val)) vmax = std::max(vmax, val);
  }
  pl::Panel p;
  p.title = "Fast kurtogram: spectral kurtosis by band (level 1 at the top)";
  p.x_label = "frequency (Hz)";
  p.y_label = "level (rows, finer bands downwards)";
  p.heatmap(0.0, nyq, 0.0, static_cast<double>(rows), rows, cols, std::move(v), 0.0, vmax > 0 ? vmax : 1.0,
            "spectral kurtosis");
  p.legend = false;
  if (std::isfinite(r.band_lo_hz)) {
    p.vline(r.band_lo_hz, {"#d62728", 1.5, pl::Dash::dashed}, "best band");
    p.vline(r.band_hi_hz, {"#d62728", 1.5, pl::Dash::dashed});
  }
  pl::Figure fig(900, 480);
  fig.add(std::move(p), {0, 0, 900, 480});
  return {"kurtogram.svg", "Kurtogram",
          "Spectral kurtosis of the band envelopes on Antoni's 1/3-binary band tree (0 = Gaussian noise, -1 = a steady "
          "line, large = bursts). The dashed lines mark the band with the largest kurtosis: where the impacts ring.",
          fig.svg()};
}

plots::PlotFile envelope_spectrum_plot(const survey::SurveyResult& r) {
  namespace pl = plot;
  pl::Panel p;
  p.title = "Envelope spectrum of the best band";
  p.x_label = "frequency of the envelope (Hz)";
  p.y_label = "|spectrum| (max = 1)";
  p.line(r.envelope_spectrum_hz, r.envelope_spectrum, {pl::palette(0), 1.2}, "envelope spectrum");
  if (std::isfinite(r.rate_hz))
    for (int h = 1; h <= 10; ++h) {
      const double f = h * r.rate_hz;
      if (!r.envelope_spectrum_hz.empty() && f > r.envelope_spectrum_hz.back()) break;
      p.vline(f, {"#d62728", 1.0, pl::Dash::dotted}, h == 1 ? "impact rate " + f3(r.rate_hz) + "/s" : "");
    }
  pl::Figure fig(900, 420);
  fig.add(std::move(p), {0, 0, 900, 420});
  return {"envelope-spectrum.svg", "Envelope spectrum",
          "Spectrum of the squared band envelope: repeated impacts give lines at the impact rate and its harmonics "
          "(dotted); a speed variation smears the higher harmonics.",
          fig.svg()};
}

plots::PlotFile free_response_plot(const survey::SurveyResult& r) {
  namespace pl = plot;
  pl::Panel p;
  p.title = "Averaged free response after the impacts (band envelope)";
  p.x_label = "time after the envelope peak (ms)";
  p.y_label = "envelope (dB re peak)";
  std::vector<double> t, db, fit;
  for (std::size_t k = 0; k < r.mean_envelope.size(); ++k) {
    t.push_back(static_cast<double>(k) / r.envelope_rate_hz * 1e3);
    db.push_back(r.mean_envelope[k] > 0 ? 20 * std::log10(r.mean_envelope[k]) : NAN);
  }
  p.line(t, db, {pl::palette(0), 1.5}, "mean band envelope");
  if (!r.modes.empty() && std::isfinite(r.modes[0].zeta)) {
    const double sigma = 2 * kPi * r.modes[0].f_hz * r.modes[0].zeta;  // envelope decay rate, 1/s
    for (double tm : t) fit.push_back(-20 * std::log10(std::exp(1.0)) * sigma * tm * 1e-3);
    p.line(t, fit, {"#d62728", 1.5, pl::Dash::dashed},
           "ridge decay e^(-2 pi f zeta t), f " + f3(r.modes[0].f_hz, 5) + " Hz, zeta " + f3(r.modes[0].zeta, 3));
  }
  p.legend_at = pl::Panel::LegendAt::top_right;
  pl::Figure fig(900, 420);
  fig.add(std::move(p), {0, 0, 900, 420});
  return {"free-response.svg", "Averaged free response",
          "Band envelope after the impacts, averaged and normalised to its peak, against the decay of the ringing "
          "mode's ridge estimate (dashed): parallel lines mean the proposed f_expected_hz and window fit the ringing.",
          fig.svg()};
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
    << "  analyzer:\n"
    << "    f_expected_hz: " << f(p.analyzer.f_expected_hz) << "\n"
    << "    band_rel: " << f(p.analyzer.band_rel) << "\n"
    << "    ml_band_rel: " << f(p.analyzer.ml_band_rel) << "\n"
    << "    window_s: " << f(p.analyzer.window_s) << "\n"
    << "    clip_level: " << f(p.analyzer.clip_level) << "\n";
  return o.str();
}

void check_survey_output(const SurveyOutput& out) {
  if (out.plots_dir) plots::prepare_dir(*out.plots_dir);
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
  if (output.plots_dir) {
    std::vector<plots::PlotFile> files = {kurtogram_plot(r)};
    if (!r.envelope_spectrum.empty()) files.push_back(envelope_spectrum_plot(r));
    if (!r.mean_envelope.empty()) files.push_back(free_response_plot(r));
    plots::write_all(std::filesystem::path(*output.plots_dir), "ridgewatch survey: " + name, text, files);
  }
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
    c.pipeline.analyzer.f_expected_hz = p.analyzer.f_expected_hz;
    c.pipeline.analyzer.band_rel = p.analyzer.band_rel;
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

int run_survey(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--channel", "--rate", "--plots", "--write-config", "--config", "--rig", "--fmin", "--fmax"},
                  {"--json"});
  const std::string& path = single_file(args);
  const drivers::ReplayOptions ropt = replay_options(args);
  SurveyOutput output;
  output.json = args.has("--json");
  output.plots_dir = args.value("--plots");
  output.write_config = args.value("--write-config");
  output.base_config = args.value("--config");
  survey::SurveyOptions opt;
  opt.f_min_hz = args.number("--fmin", opt.f_min_hz, 1.0, 5e6);
  opt.f_max_hz = args.number("--fmax", 0.0, 1.0, 5e6);
  if (const auto rig = args.value("--rig")) opt.shaft_hz = load_rig_yaml(*rig).rig.pinion_speed_hz();
  check_survey_output(output);
  auto source = drivers::open_replay(path, ropt);
  const double fs = source->info().sample_rate_hz;
  if (opt.f_max_hz > 0 && !(opt.f_max_hz > opt.f_min_hz && opt.f_max_hz <= fs / 2))
    throw UsageError("--fmax: must be above --fmin (" + f3(opt.f_min_hz) + " Hz) and at most fs/2 = " + f3(fs / 2) + " Hz");
  if (!(opt.f_min_hz < fs / 2)) throw UsageError("--fmin: must be below fs/2 = " + f3(fs / 2) + " Hz");
  const std::vector<double> x = drivers::read_all(*source);  // InputError (exit 3) names the file
  if (x.size() < 64) throw drivers::InputError(path + ": too short for a survey (" + std::to_string(x.size()) + " samples)");
  return survey_and_report(x, fs, path, opt, output, out, err);
}

}  // namespace ridgewatch::cli
