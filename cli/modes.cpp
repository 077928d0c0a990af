// `ridgewatch modes FILE`: identify every mode of one free response and print JSON on stdout.
#include <cmath>
#include <ostream>
#include <sstream>
#include <stdexcept>

#include "cli/args.hpp"
#include "cli/commands.hpp"
#include "cli/json_writer.hpp"
#include "core/dsp/modes.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::cli {

namespace {

using dsp::DampingEstimate;

std::string estimate_json(const DampingEstimate& e) {
  std::ostringstream o;
  o << "{\"f_hz\":" << json_number(e.f_hz) << ",\"f_sd_hz\":" << json_number(e.f_sd_hz)
    << ",\"zeta\":" << json_number(e.zeta) << ",\"zeta_sd\":" << json_number(e.zeta_sd)
    << ",\"zeta_ci95\":[" << json_number(e.zeta_ci95_lo) << "," << json_number(e.zeta_ci95_hi) << "]"
    << ",\"method\":" << json_string(dsp::to_string(e.method))
    << ",\"status\":" << json_string(dsp::to_string(e.status)) << ",\"snr_db\":" << json_number(e.snr_db)
    << ",\"amplitude\":" << json_number(e.amplitude) << ",\"window_s\":[" << json_number(e.window_start_s)
    << "," << json_number(e.window_end_s) << "]}";
  return o.str();
}

}  // namespace

int run_modes(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv,
                  {"--channel", "--rate", "--fmin", "--fmax", "--max-modes", "--method", "--eta0",
                   "--start", "--min-snr-db", "--voices"},
                  {"--all-methods"});
  if (args.positional().size() != 1)
    throw UsageError("expects exactly one FILE (got " + std::to_string(args.positional().size()) + ")");
  const std::string& path = args.positional()[0];

  drivers::ReplayOptions ropt;
  ropt.channel = static_cast<std::size_t>(args.integer("--channel", 0, 0, 1023));
  ropt.csv_rate_hz = args.optional_number("--rate", drivers::kMinReplayRateHz, drivers::kMaxReplayRateHz);

  dsp::ModeSearchOptions opt;
  if (const auto m = args.value("--method"); m && !dsp::parse_damping_method(*m, opt.method))
    throw UsageError("--method: '" + *m + "' is not one of two-point, ridge-ls, ml");
  opt.max_modes = static_cast<std::size_t>(args.integer("--max-modes", 8, 1, 64));
  opt.eta0 = args.number("--eta0", opt.eta0, 5.0, 50.0);
  opt.voices_per_octave = static_cast<std::size_t>(args.integer("--voices", 32, 4, 256));
  opt.min_peak_snr_db = args.number("--min-snr-db", opt.min_peak_snr_db, 0.0, 100.0);
  opt.onset_s = args.number("--start", -1.0, 0.0, 1e9);
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
    throw UsageError("--fmax: " + json_number(*fmax) + " Hz must be below half the sample rate of " + path +
                     " (" + json_number(0.5 * fs) + " Hz)");
  if (fmin && *fmin >= 0.5 * fs)
    throw UsageError("--fmin: " + json_number(*fmin) + " Hz must be below half the sample rate of " + path +
                     " (" + json_number(0.5 * fs) + " Hz)");
  if (opt.onset_s >= static_cast<double>(x.size()) / fs)
    throw UsageError("--start: " + json_number(opt.onset_s) + " s is beyond the end of " + path);
  opt.f_min_hz = fmin.value_or(0.0);
  opt.f_max_hz = fmax.value_or(0.0);

  dsp::ModeSearchResult r;
  try {
    r = dsp::identify_modes(x, fs, opt);
  } catch (const std::invalid_argument& e) {
    // Options are validated above; what remains is about the data (e.g. onset too close to the end).
    throw drivers::InputError(path + ": " + e.what());
  }
  if (r.modes.empty()) err << "modes: no mode stands " << opt.min_peak_snr_db << " dB above the noise floor in " << path << "\n";

  out << "{\"file\":" << json_string(path) << ",\"sample_rate_hz\":" << json_number(fs)
      << ",\"samples\":" << x.size() << ",\"onset_s\":" << json_number(r.onset_s)
      << ",\"band_hz\":[" << json_number(r.f_min_hz) << "," << json_number(r.f_max_hz) << "]"
      << ",\"noise_sd\":" << json_number(r.noise_sd) << ",\"modes\":[";
  for (std::size_t i = 0; i < r.modes.size(); ++i) {
    const auto& m = r.modes[i];
    std::string sel = estimate_json(m.selected);
    if (args.has("--all-methods")) {
      sel.pop_back();
      sel += ",\"estimates\":{\"two-point\":" + estimate_json(m.two_point) +
             ",\"ridge-ls\":" + estimate_json(m.ridge_ls) + ",\"ml\":" + estimate_json(m.ml) + "}}";
    }
    out << (i ? "," : "") << sel;
  }
  out << "]}\n";
  return kExitOk;
}

}  // namespace ridgewatch::cli
