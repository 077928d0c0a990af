// `ridgewatch diagnose --rig RIG.yaml FILE [--with EFFECT[:key=value[!],...]]... [--json] [--quiet]
// [--history FILE.jsonl] [--plots DIR]`: the
// missing-effect loop (core/diagnosis/diagnose.hpp). Text by default, one JSON object with --json.
// --history appends one JSON line per run (time of run is not recorded: the line is a function of the
// inputs) with the file, model, verdict and excess before/after, so repeated runs on the same data
// form the "watch the error fall" table. --max-impacts N (default 16): runs of 4 consecutive impacts
// spread over the record. --plots DIR also writes SVG plots of the final model, the residual spectrum
// per round, the candidate ladder and the error per round (and per --history run), gathered by
// DIR/index.html (cli/plot_diagnosis.hpp). --with NAME:key=value starts a parameter there, key=value!
// fixes it. Progress lines go to stderr unless --quiet.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <ostream>
#include <sstream>

#include "cli/commands.hpp"
#include "cli/diagnosis_common.hpp"
#include "cli/plot_diagnosis.hpp"

namespace ridgewatch::cli {

namespace {

std::string g(double v, int d = 3) { return diagnosis::format_number(v, d); }

/// The proposed effect as a rig-file block (model.custom_effects, cli/rig_yaml.cpp reads it back).
std::string proposal_yaml(const diagnosis::TermDiscoveryResult& p) {
  std::ostringstream y;
  y << "model:\n  custom_effects:\n    - name: " << p.definition.name << "\n      force: \"" << p.definition.force
    << "\"\n      parameters:\n";
  for (const auto& q : p.definition.parameters)
    y << "        " << q.key << ": {unit: \"" << q.unit << "\", min: 0, max: " << g(q.max_value, 6)
      << ", default: " << g(q.default_value, 6) << ", null: 0}\n";
  if (!p.definition.kinks.empty()) {
    y << "      kinks: [";
    for (std::size_t k = 0; k < p.definition.kinks.size(); ++k) y << (k ? ", " : "") << "\"" << p.definition.kinks[k] << "\"";
    y << "]\n";
  }
  return y.str();
}

nlohmann::json proposal_json(const diagnosis::DiagnoseResult& r, const std::string& yaml) {
  if (!r.discovery_run) return nullptr;
  const auto& p = r.proposal;
  nlohmann::json terms = nlohmann::json::array();
  for (const auto& t : p.terms)
    terms.push_back({{"term", t.term}, {"parameter", t.parameter}, {"unit", t.unit}, {"coefficient", t.coefficient},
                     {"sd", t.sd}, {"linear_estimate", t.linear_coefficient}, {"heldout_gain", t.heldout_loss},
                     {"gap_parameter", t.gap_parameter.empty() ? nlohmann::json(nullptr) : nlohmann::json(t.gap_parameter)},
                     {"gap_m", t.gap_parameter.empty() ? nlohmann::json(nullptr) : nlohmann::json(t.gap)}});
  return {{"present", p.proposed},
          {"yaml", p.proposed ? nlohmann::json(yaml) : nlohmann::json(nullptr)},
          {"effect", p.definition.name},
          {"force", p.force},
          {"terms", terms},
          {"base_effects", p.base_effects},
          {"heldout_excess_before", p.heldout_excess_before},
          {"heldout_excess_after", p.heldout_excess_after},
          {"heldout_gain", p.heldout_gain},
          {"heldout_excess_fitted", std::isfinite(p.verified_excess) ? nlohmann::json(p.verified_excess) : nlohmann::json(nullptr)},
          {"required_gain", p.required_gain},
          {"note", p.note}};
}

/// Text of the proposal: the terms, the gain and the block to paste.
void proposal_text(std::ostream& text, const diagnosis::DiagnoseResult& r, const std::string& yaml, const std::string& file) {
  if (!r.discovery_run) return;
  const auto& p = r.proposal;
  if (!p.proposed) {
    text << "term discovery: nothing proposed (" << p.note << ")\n";
    return;
  }
  // A proposal fitted directly by the nonlinear fitter (the dead-zone family) has no first-order estimate.
  const bool direct = !p.terms.empty() && std::isnan(p.terms.front().linear_coefficient);
  text << "term discovery: a force from the term library explains the residual; held-out excess " << g(p.heldout_excess_before)
       << " -> " << g(p.heldout_excess_after) << (direct ? " fitted from each gap of the grid" : " to first order") << " (gain "
       << g(p.heldout_gain) << ", gate " << g(p.required_gain, 2) << "), " << g(p.verified_excess) << " fitted with the model\n";
  for (const auto& t : p.terms)
    text << "  " << t.term << ": " << g(t.coefficient, 4) << " " << t.unit << " (sd " << g(t.sd, 2)
         << (direct ? std::string(")") : "; first order " + g(t.linear_coefficient, 3) + "), held-out gain " + g(t.heldout_loss) + " to first order")
         << (t.gap_parameter.empty() ? std::string() : "; gap " + t.gap_parameter + " = " + g(t.gap, 4) + " m") << "\n";
  text << "paste into the rig file (merge with an existing model: section), then run\n  ridgewatch compare --rig RIG.yaml "
       << file;
  for (const auto& e : p.base_effects) text << " --with " << e;
  text << " --with " << p.definition.name << "\n" << yaml;
}

}  // namespace

int run_diagnose(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--rig", "--with", "--channel", "--rate", "--history", "--max-impacts", "--plots"}, {"--json", "--quiet"});
  diag::Loaded l = diag::load(args);
  std::optional<std::filesystem::path> plot_dir;  // made (or refused) before the fits
  if (const auto d = args.value("--plots")) plot_dir = plots::prepare_dir(*d);
  // Default 16 impacts (8 fitted, 8 held out): each candidate refit
  // costs ~0.1-1 s per 16 impacts; more impacts sharpen the gate but cost linearly.
  l.seg = diagnosis::subset_windows(l.seg, static_cast<std::size_t>(args.integer("--max-impacts", 16, 4, 100000)));
  diagnosis::ModelFitter fitter(l.y, l.seg, l.rig.rig);
  diag::apply_settings(fitter, l);
  diagnosis::DiagnoseOptions options;
  // Progress on stderr, one line per candidate fit and per round, with the elapsed time (a run takes
  // seconds to minutes); --quiet turns it off. Time is measured here, not in core.
  const auto started = std::chrono::steady_clock::now();
  if (!args.has("--quiet"))
    options.progress = [&err, started](const std::string& line) {
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
      err << "diagnose: [" << g(s, 3) << " s] " << line << "\n" << std::flush;
    };
  const diagnosis::DiagnoseResult r =
      diag::guard_user_effects(*args.value("--rig"), [&] { return diagnosis::diagnose(fitter, l.effects, options); });

  nlohmann::json steps = nlohmann::json::array();
  for (const auto& s : r.steps) {
    nlohmann::json params = nlohmann::json::array();
    for (const auto& e : s.parameters) params.push_back(diag::estimate_json(e));
    steps.push_back({{"round", s.round},
                     {"effect", s.effect},
                     {"excess_before", s.excess_before},
                     {"excess_after", s.excess_after},
                     {"required_gain", s.required_gain},
                     {"fraction_improved", s.fraction_improved},
                     {"delta_bic", s.delta_bic},
                     {"plausible", s.plausible},
                     {"implausible_because", s.plausibility},
                     {"gates", {{"heldout_gain", s.gain_ok}, {"impacts_improve", s.impacts_ok}, {"bic", s.bic_ok}, {"plausible", s.plausible}}},
                     {"accepted", s.accepted},
                     {"removed", s.removed},
                     {"parameters", params},
                     {"evidence", s.evidence}});
  }
  nlohmann::json final_params = nlohmann::json::array();
  for (const auto& e : r.final_fit.estimates) final_params.push_back(diag::estimate_json(e));
  nlohmann::json j = {{"file", l.path},
                      {"initial_effects", r.initial_effects},
                      {"impacts", l.seg.windows.size()},
                      {"noise_sd", l.seg.noise_sd},
                      {"baseline_excess", r.baseline_excess},
                      {"steps", steps},
                      {"verdict", r.verdict},
                      {"removed", r.removed},
                      {"ambiguous", r.ambiguous},
                      {"ambiguous_evidence", r.ambiguous_evidence},
                      {"final_excess", r.final_excess},
                      {"final_fit_percent", r.final_fit_percent},
                      {"final_parameters", final_params},
                      {"unexplained", {{"present", r.unexplained}, {"where", r.unexplained_where}}},
                      {"sensor_problems", r.sensor_problems}};
  // A step in ζ found by the step-time scan: the impacts that bracket it (its time is anywhere between
  // them), the time the model puts it at, and its size.
  const auto& ds = r.damping_step;
  j["damping_step"] = {{"present", ds.found},
                       {"between_impacts_s", ds.found ? nlohmann::json::array({ds.time.ci95_lo, ds.time.ci95_hi}) : nlohmann::json(nullptr)},
                       {"model_time_s", ds.found ? nlohmann::json(ds.time.value) : nlohmann::json(nullptr)},
                       {"step", ds.found ? diag::estimate_json(ds.step) : nlohmann::json(nullptr)}};

  const std::string yaml = r.proposal.proposed ? proposal_yaml(r.proposal) : std::string();
  j["proposed"] = proposal_json(r, yaml);
  // Judged on the best description found (the discovered force when it supersedes the catalogue's).
  const auto undescribed = diagnosis::description_problems(fitter, diagnosis::best_description(r), r.final_report);
  j["describable"] = undescribed.empty();
  j["not_describable_because"] = undescribed;
  if (const auto hist = args.value("--history")) {
    nlohmann::json line = {{"file", l.path},
                           {"model", r.initial_effects},
                           {"verdict", r.verdict},
                      {"removed", r.removed},
                      {"ambiguous", r.ambiguous},
                      {"ambiguous_evidence", r.ambiguous_evidence},
                           {"baseline_excess", r.baseline_excess},
                           {"final_excess", r.final_excess},
                           {"unexplained", r.unexplained}};
    std::ofstream h(*hist, std::ios::app);
    h << line.dump() << "\n";
    h.close();
    if (!h) throw UsageError("--history: cannot append to " + *hist);
  }
  if (args.has("--json")) out << j.dump() << "\n";
  std::ostringstream text;
  text << "diagnose: " << l.path << ", " << l.seg.windows.size() << " impacts; model [";
  for (std::size_t i = 0; i < r.initial_effects.size(); ++i) text << (i ? ", " : "") << r.initial_effects[i];
  text << "], held-out excess " << g(r.baseline_excess) << "\n";
  int round = 0;
  for (const auto& s : r.steps) {
    if (s.round != round) {
      round = s.round;
      text << " round " << round << ":\n";
    }
    if (s.removed) {
      text << "  REMOVE " << s.effect << ": " << s.evidence << "\n";
      continue;
    }
    text << "  " << (s.accepted ? "ACCEPT " : (s.passed ? "pass   " : "reject ")) << s.effect << ": excess "
         << g(s.excess_before) << " -> " << g(s.excess_after) << " (need gain > " << g(s.required_gain, 2) << "), "
         << g(100 * s.fraction_improved, 3) << " % impacts improve, dBIC " << g(s.delta_bic, 4)
         << (s.plausible ? "" : ", implausible: " + s.plausibility) << "\n";
    if (s.accepted) text << "      evidence: " << s.evidence << "\n";
  }
  text << "verdict: ";
  if (r.verdict.empty()) text << (!r.ambiguous.empty() ? "no single effect (ambiguous, below)" : r.unexplained ? "no catalogue effect passes" : "nothing missing above the noise");
  for (std::size_t i = 0; i < r.verdict.size(); ++i) {
    text << (i ? " then " : "") << r.verdict[i];
    if (r.verdict[i] == "damping_drift" && ds.found)
      text << " (a step in zeta of " << g(ds.step.value) << ", 95 %: " << g(ds.step.ci95_lo) << " .. " << g(ds.step.ci95_hi)
           << ", between the impacts at " << g(ds.time.ci95_lo, 4) << " s and " << g(ds.time.ci95_hi, 4) << " s)";
  }
  text << "; final held-out excess " << g(r.final_excess) << ", fit " << g(r.final_fit_percent, 4) << " %\n";
  if (!r.ambiguous.empty()) text << "ambiguous: " << r.ambiguous_evidence << "\n";
  for (const auto& u : undescribed) text << "NOT DESCRIBED BY THE RIG: " << u << "\n";
  text << "unexplained structured residual: " << (r.unexplained ? r.unexplained_where : "none") << "\n";
  proposal_text(text, r, yaml, l.path);
  for (const auto& p : r.sensor_problems) text << "sensor: " << p << "\n";
  if (!args.has("--json")) out << text.str();
  if (plot_dir) {
    // The starting model's fit, for the "before" lines of the impact plot (only when something was
    // accepted; the fit is deterministic, so it equals the one diagnose started from).
    std::optional<diagnosis::FitResult> start;
    if (!r.verdict.empty()) start = fitter.fit(r.initial_effects);
    std::vector<std::pair<std::string, const diagnosis::ResidualReport*>> spectra;
    for (std::size_t k = 0; k < r.rounds.size(); ++k)
      spectra.push_back({(k == 0 ? "start " : "round " + std::to_string(k) + " ") + plots::effect_list(r.rounds[k].effects) +
                             ", excess " + g(r.rounds[k].heldout_excess),
                         &r.rounds[k].report});
    if (spectra.empty()) spectra.push_back({"final " + plots::effect_list(r.final_fit.effects), &r.final_report});
    const auto history = args.value("--history") ? plots::read_history(*args.value("--history"), l.path) : std::vector<plots::HistoryRun>{};
    const std::vector<plots::PlotFile> files = {
        plots::impacts(fitter, r.final_fit, start ? &*start : nullptr),
        plots::residual_scalogram(fitter, r.final_fit, r.final_report),
        plots::envelopes(fitter, r.final_fit, r.final_report),
        plots::backbones(r.final_report, !r.verdict.empty() && !r.rounds.empty() ? &r.rounds.front().report : nullptr),
        plots::residual_where(r.final_report),
        plots::residual_spectra(spectra),
        plots::candidate_ladder(r),
        plots::error_fall(r, history),
    };
    plots::write_all(*plot_dir, "ridgewatch diagnose: " + l.path, text.str(), files);
    err << "diagnose: wrote " << files.size() << " plots and " << (*plot_dir / "index.html").string() << "\n";
  }
  if (!undescribed.empty()) {
    err << "diagnose: " << l.path << ": the rig does not describe this record (" << undescribed.front() << ")\n";
    return kExitBadInput;
  }
  return kExitOk;
}

}  // namespace ridgewatch::cli
