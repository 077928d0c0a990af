// `ridgewatch modes FILE`: identify every mode of one free response and print JSON on stdout.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <ostream>
#include <sstream>
#include <stdexcept>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "cli/plot_diagnosis.hpp"
#include "cli/plot_modes.hpp"
#include "cli/replay_flags.hpp"
#include "core/dsp/modes.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

namespace {

using dsp::DampingEstimate;

// JSON number or null for NaN/Inf (nlohmann writes shortest round-trip decimals).
nlohmann::ordered_json num(double v) { return std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json(nullptr); }

nlohmann::ordered_json estimate_json(const DampingEstimate& e) {
  return {{"f_hz", num(e.f_hz)},
          {"f_sd_hz", num(e.f_sd_hz)},
          {"zeta", num(e.zeta)},
          {"zeta_sd", num(e.zeta_sd)},
          {"zeta_ci95", {num(e.zeta_ci95_lo), num(e.zeta_ci95_hi)}},
          {"method", std::string(dsp::to_string(e.method))},
          {"status", std::string(dsp::to_string(e.status))},
          {"snr_db", num(e.snr_db)},
          {"amplitude", num(e.amplitude)},
          {"window_s", {num(e.window_start_s), num(e.window_end_s)}}};
}

// Backbone points and, when tested, the constancy test's evidence and (where dependent) the law.
nlohmann::ordered_json backbone_json(const dsp::Backbone& b) {
  nlohmann::ordered_json pts = nlohmann::ordered_json::array();
  for (const auto& p : b.points)
    pts.push_back({{"amplitude", num(p.amplitude)}, {"zeta", num(p.zeta)}, {"zeta_sd", num(p.zeta_sd)},
                   {"f_hz", num(p.f_hz)}, {"f_sd_hz", num(p.f_sd_hz)}, {"t_s", num(p.t_s)}});
  return pts;
}

nlohmann::ordered_json law_json(const dsp::Backbone& b) {
  if (!b.tested) return nullptr;
  nlohmann::ordered_json j = {{"slope_z", num(b.slope_z)},
                              {"relative_change", num(b.relative_change)},
                              {"chi2_constant", num(b.chi2_constant)},
                              {"dof", b.dof},
                              {"form", b.amplitude_dependent ? std::string(dsp::to_string(b.law)) : "constant"},
                              {"a", num(b.a)},
                              {"a_ci95", {num(b.a_ci95_lo), num(b.a_ci95_hi)}}};
  if (b.amplitude_dependent) {
    j["b"] = num(b.b);
    j["b_ci95"] = {num(b.b_ci95_lo), num(b.b_ci95_hi)};
  }
  return j;
}

std::string fmt(double v) { return nlohmann::ordered_json(v).dump(); }

}  // namespace

int run_modes(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv,
                  {"--channel", "--rate", "--fmin", "--fmax", "--max-modes", "--method", "--eta0",
                   "--start", "--end", "--min-snr-db", "--voices", "--plots"},
                  {"--all-methods"});
  const std::string& path = single_file(args);
  std::filesystem::path plot_dir;
  if (const auto d = args.value("--plots")) plot_dir = plots::prepare_dir(*d);
  const drivers::ReplayOptions ropt = replay_options(args);

  dsp::ModeSearchOptions opt;
  if (const auto m = args.value("--method"); m && !dsp::parse_damping_method(*m, opt.method))
    throw UsageError("--method: '" + *m + "' is not one of two-point, ridge-ls, ml");
  opt.max_modes = static_cast<std::size_t>(args.integer("--max-modes", 16, 1, 64));
  if (const auto eta0 = args.optional_number("--eta0", 5.0, 1000.0)) opt.eta0 = *eta0;  // else per mode
  opt.voices_per_octave = static_cast<std::size_t>(args.integer("--voices", 32, 4, 256));
  opt.min_peak_snr_db = args.number("--min-snr-db", opt.min_peak_snr_db, 0.0, 100.0);
  opt.onset_s = args.number("--start", -1.0, 0.0, 1e9);
  const auto end_s = args.optional_number("--end", 1e-9, 1e9);
  if (end_s && opt.onset_s >= 0 && *end_s <= opt.onset_s)
    throw UsageError("--end: " + fmt(*end_s) + " s must be after --start " + fmt(opt.onset_s) + " s");
  if (end_s) opt.end_s = *end_s;
  const auto fmin = args.optional_number("--fmin", 1e-6, 1e9);
  const auto fmax = args.optional_number("--fmax", 1e-6, 1e9);
  if (fmin && fmax && *fmin >= *fmax) throw UsageError("--fmin must be below --fmax");

  auto source = drivers::open_replay(path, ropt);
  const double fs = source->info().sample_rate_hz;
  const std::vector<double> x = drivers::read_all(*source);
  if (x.size() < 64)
    throw drivers::InputError(path + ": too short for mode identification (" + std::to_string(x.size()) +
                              " samples, need at least 64)");
  if (fmax && *fmax >= 0.5 * fs)
    throw UsageError("--fmax: " + fmt(*fmax) + " Hz must be below half the sample rate of " + path +
                     " (" + fmt(0.5 * fs) + " Hz)");
  if (fmin && *fmin >= 0.5 * fs)
    throw UsageError("--fmin: " + fmt(*fmin) + " Hz must be below half the sample rate of " + path +
                     " (" + fmt(0.5 * fs) + " Hz)");
  if (opt.onset_s >= static_cast<double>(x.size()) / fs)
    throw UsageError("--start: " + fmt(opt.onset_s) + " s is beyond the end of " + path);
  if (end_s && *end_s > static_cast<double>(x.size()) / fs)
    throw UsageError("--end: " + fmt(*end_s) + " s is beyond the end of " + path + " (" +
                     fmt(static_cast<double>(x.size()) / fs) + " s)");
  opt.f_min_hz = fmin.value_or(0.0);
  opt.f_max_hz = fmax.value_or(0.0);

  dsp::ModeSearchResult r;
  try {
    r = dsp::identify_modes(x, fs, opt);
  } catch (const std::invalid_argument& e) {
    // Options are validated above; what remains is about the data (e.g. onset too close to the end).
    throw drivers::InputError(path + ": " + e.what());
  }
  if (r.modes.empty()) err << "modes: " << path << ": " << r.note << "\n";

  nlohmann::ordered_json doc = {{"file", path},
                        {"sample_rate_hz", fs},
                        {"samples", x.size()},
                        {"onset_s", r.onset_s},
                        {"end_s", r.end_s},
                        {"band_hz", {r.f_min_hz, r.f_max_hz}},
                        {"noise_sd", num(r.noise_sd)},
                        {"modes", nlohmann::ordered_json::array()}};
  if (!r.note.empty()) doc["note"] = r.note;
  doc["peaks"] = nlohmann::ordered_json::array();
  for (const auto& p : r.peaks) doc["peaks"].push_back({{"f_hz", num(p.f_hz)}, {"snr_db", num(p.snr_db)}, {"eta0", num(p.eta0)}});
  for (const auto& m : r.modes) {
    nlohmann::ordered_json j = estimate_json(m.selected);
    if (args.has("--all-methods"))
      j["estimates"] = {{"two-point", estimate_json(m.two_point)},
                        {"ridge-ls", estimate_json(m.ridge_ls)},
                        {"ml", estimate_json(m.ml)}};
    j["eta0"] = num(m.eta0);
    j["eta0_needed"] = num(m.eta0_needed);
    j["resolved"] = m.resolved;
    j["detection_snr_db"] = num(m.detection_snr_db);
    j["amplitude_dependent"] = m.backbone.tested ? nlohmann::ordered_json(m.backbone.amplitude_dependent) : nlohmann::ordered_json(nullptr);
    j["backbone"] = backbone_json(m.backbone);
    j["backbone_test"] = law_json(m.backbone);
    if (!m.note.empty()) j["note"] = m.note;
    doc["modes"].push_back(std::move(j));
  }
  if (!plot_dir.empty()) {
    // The plots cover the analysed part (up to --end).
    const std::span<const double> analysed(x.data(), std::min(x.size(), static_cast<std::size_t>(std::llround(r.end_s * fs))));
    plots::write_all(plot_dir, "ridgewatch modes " + path, doc.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace),
                     plots::mode_plots(analysed, fs, r));
  }
  // Invalid UTF-8 in a file name is replaced rather than aborting the output.
  out << doc.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace) << "\n";
  return kExitOk;
}

}  // namespace ridgewatch::cli
