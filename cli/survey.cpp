// `ridgewatch survey FILE [--channel N] [--rate HZ] [--json] [--plots DIR] [--write-config OUT.yaml]
//                         [--config F] [--rig RIG.yaml] [--fmin HZ] [--fmax HZ]`
// Where the impacts of an unknown rig are and how to configure the pipeline for them
// (core/survey/survey.hpp). stdout: the text report or one JSON object; exit 0 also when the record
// holds no repeated impacts (then there is no proposal and nothing is written).
#include "app/survey_report.hpp"

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

using survey::SurveyResult;
constexpr double kPi = 3.141592653589793;

std::string f3(double v, int digits = 4) {
  if (!std::isfinite(v)) return "n/a";
  char b[64];
  std::snprintf(b, sizeof b, "%.*g", digits, v);
  return b;
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

// --plots DIR: the kurtogram, the envelope spectrum and the averaged free response, with the text
// report on the index page.
void write_survey_plots(const std::string& dir, const SurveyResult& r, const std::string& name, const std::string& text) {
  std::vector<plots::PlotFile> files = {kurtogram_plot(r)};
  if (!r.envelope_spectrum.empty()) files.push_back(envelope_spectrum_plot(r));
  if (!r.mean_envelope.empty()) files.push_back(free_response_plot(r));
  plots::write_all(std::filesystem::path(dir), "ridgewatch survey: " + name, text, files);
}

}  // namespace

int run_survey(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--channel", "--rate", "--plots", "--write-config", "--config", "--rig", "--fmin", "--fmax"},
                  {"--json"});
  const std::string& path = single_file(args);
  const drivers::ReplayOptions ropt = replay_options(args);
  SurveyOutput output;
  output.json = args.has("--json");
  if (const auto dir = args.value("--plots")) {
    plots::prepare_dir(*dir);  // before the work: a bad --plots is exit 2 at once
    output.write_plots = [dir = *dir](const SurveyResult& r, const std::string& name, const std::string& text) {
      write_survey_plots(dir, r, name, text);
    };
  }
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
