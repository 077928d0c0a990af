// `ridgewatch compare --rig RIG.yaml FILE [--with EFFECT]... [--json] [--plots DIR]`: fits the gear-pair
// model (core/diagnosis/model_fit.hpp) to the impacts of a recording and shows where it fails: fitted c0 vs
// the rig's nominal (f0 gap), held-out excess over the noise floor, fit %, residual vs time after the
// impact and per impact, residual spectrum with f0 ± k·f_z / k·f_z markers, backbones measured vs model,
// whiteness, sensor faults. Text on stdout by default, one JSON object with --json. --plots DIR also
// writes SVG plots and DIR/index.html (cli/plot_diagnosis.hpp).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <ostream>
#include <sstream>

#include "cli/commands.hpp"
#include "cli/diagnosis_common.hpp"
#include "cli/plot_diagnosis.hpp"
#include "core/model/mesh_dynamics.hpp"

namespace ridgewatch::cli {

namespace {

std::string f(double v, int d = 4) { return diagnosis::format_number(v, d); }

// The text report (stdout without --json; the head of the plots' index.html).
void write_text(std::ostream& out, const diag::Loaded& l, const diagnosis::FitResult& fit, const diagnosis::ResidualReport& rep,
                const std::vector<std::string>& problems) {
  const double c0_nom = l.rig.rig.mean_mesh_stiffness_n_per_m;
  const auto& c0 = fit.estimates[0];
  const double f0_nom = l.rig.rig.natural_frequency_hz();
  out << "compare: " << l.path << " with model [";
  for (std::size_t i = 0; i < l.effects.size(); ++i) out << (i ? ", " : "") << l.effects[i];
  out << "] on " << l.seg.windows.size() << " impacts (" << (l.seg.windows.size() + 1) / 2 << " fitted, "
      << l.seg.windows.size() / 2 << " held out)\n";
  out << "  c0     " << f(c0.value, 5) << " N/m (95 %: " << f(c0.ci95_lo, 5) << " .. " << f(c0.ci95_hi, 5) << "), nominal "
      << f(c0_nom, 5) << ": " << f(100.0 * (c0.value / c0_nom - 1.0), 3) << " %  ->  f0 " << f(rep.f0_hz, 5)
      << " Hz vs " << f(f0_nom, 5) << " Hz from the rig\n";
  for (std::size_t i = 1; i < fit.estimates.size(); ++i) {
    const auto& e = fit.estimates[i];
    out << "  " << e.name << " = " << f(e.value) << " (95 %: " << f(e.ci95_lo) << " .. " << f(e.ci95_hi) << ")"
        << (e.at_bound ? " AT BOUND" : "") << "\n";
  }
  out << "  impact pulse: " << model::to_string(fit.params.pulse_shape) << " (the better training fit of half_sine and hann)\n";
  out << "  held-out excess over the noise floor: " << f(fit.heldout_excess, 3) << " (0 = nothing left to explain), fit "
      << f(fit.fit_percent, 4) << " %\n";
  out << "  residual vs time after impact (excess per ms):";
  for (double v : rep.excess_vs_time) out << " " << (std::isfinite(v) ? f(v, 2) : "-");
  out << "\n  residual lines (level / noise floor):";
  if (rep.peaks.empty()) out << " none";
  for (const auto& p : rep.peaks) out << " " << f(p.f_hz, 4) << " Hz x" << f(p.level, 3) << (p.marker.empty() ? "" : " [" + p.marker + "]");
  out << "\n  whiteness: Ljung-Box Q = " << f(rep.ljung_box_q, 3) << " (99.9 % limit " << f(rep.ljung_box_limit, 3) << "): "
      << (rep.white ? "white" : "NOT white") << "\n";
  out << "  backbone (amplitude %: zeta measured/model, f measured/model Hz):\n";
  for (std::size_t k = 0; k < rep.measured.amplitude_rel.size(); ++k) {
    if (!std::isfinite(rep.measured.zeta[k])) continue;
    out << "    " << f(100 * rep.measured.amplitude_rel[k], 2) << " %: " << f(rep.measured.zeta[k], 3) << " / "
        << (std::isfinite(rep.model.zeta[k]) ? f(rep.model.zeta[k], 3) : "-") << ", " << f(rep.measured.f_hz[k], 5) << " / "
        << (std::isfinite(rep.model.f_hz[k]) ? f(rep.model.f_hz[k], 5) : "-") << "\n";
  }
  for (const auto& p : problems) out << "  sensor: " << p << "\n";
}

}  // namespace

int run_compare(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err) {
  const Args args(argv, {"--rig", "--with", "--channel", "--rate", "--plots"}, {"--json"});
  diag::Loaded l = diag::load(args);
  std::optional<std::filesystem::path> plot_dir;  // made (or refused) before the fit
  if (const auto d = args.value("--plots")) plot_dir = plots::prepare_dir(*d);
  diagnosis::ModelFitter fitter(l.y, l.seg, l.rig.rig);
  diag::apply_settings(fitter, l);
  // The impact pulse shape (half-sine or Hann) is chosen by the training fit (model_fit.hpp).
  const diagnosis::FitResult fit =
      diag::guard_user_effects(*args.value("--rig"), [&] { return diagnosis::fit_pulse_shapes(fitter, l.effects); });
  const diagnosis::ResidualReport rep = diagnosis::analyse_residual(fitter, fit);
  const double c0_nom = l.rig.rig.mean_mesh_stiffness_n_per_m;
  const auto& c0 = fit.estimates[0];
  const double f0_nom = l.rig.rig.natural_frequency_hz();
  const auto problems = diagnosis::sensor_problems(l.seg, static_cast<double>(l.y.size()) / l.seg.sample_rate_hz);
  // A record the rig cannot describe (another structure, a wrong rig file): flagged, exit 3.
  const auto undescribed = diagnosis::description_problems(fitter, fit, rep);

  if (args.has("--json")) {
    nlohmann::json j;
    j["file"] = l.path;
    j["effects"] = l.effects;
    j["impacts"] = {{"total", l.seg.windows.size()}, {"training", (l.seg.windows.size() + 1) / 2}, {"held_out", l.seg.windows.size() / 2}};
    j["noise_sd"] = l.seg.noise_sd;
    j["c0"] = {{"nominal_n_per_m", c0_nom}, {"fitted_n_per_m", c0.value}, {"ci95", {c0.ci95_lo, c0.ci95_hi}},
               {"relative_gap", c0.value / c0_nom - 1.0}, {"f0_nominal_hz", f0_nom}, {"f0_fitted_hz", rep.f0_hz}};
    nlohmann::json params = nlohmann::json::array();
    for (const auto& e : fit.estimates) params.push_back(diag::estimate_json(e));
    j["parameters"] = params;
    nlohmann::json fixed = nlohmann::json::object();  // --with NAME:key=value! (not fitted)
    for (const auto& [name, st] : l.settings)
      if (st.fixed) fixed[name] = st.value;
    j["fixed_parameters"] = fixed;
    nlohmann::json corr = nlohmann::json::array();
    for (Eigen::Index r = 0; r < fit.correlation.rows(); ++r) {
      nlohmann::json row = nlohmann::json::array();
      for (Eigen::Index c = 0; c < fit.correlation.cols(); ++c) row.push_back(fit.correlation(r, c));
      corr.push_back(row);
    }
    j["correlation"] = corr;
    j["converged"] = fit.converged;
    j["pulse_shape"] = model::to_string(fit.params.pulse_shape);
    j["heldout_excess"] = fit.heldout_excess;
    j["fit_percent"] = fit.fit_percent;
    j["residual"] = diag::report_json(rep);
    j["sensor_problems"] = problems;
    j["describable"] = undescribed.empty();
    j["not_describable_because"] = undescribed;
    out << j.dump() << "\n";
  }
  std::ostringstream text;
  write_text(text, l, fit, rep, problems);
  for (const auto& u : undescribed) text << "  NOT DESCRIBED BY THE RIG: " << u << "\n";
  if (!args.has("--json")) out << text.str();
  if (!l.ignored.empty()) {
    err << "compare: rig model.effects not fitted (sensor/kinematics):";
    for (const auto& n : l.ignored) err << " " << n;
    err << "\n";
  }
  if (plot_dir) {
    const std::vector<plots::PlotFile> files = {
        plots::impacts(fitter, fit),
        plots::residual_scalogram(fitter, fit, rep),
        plots::envelopes(fitter, fit, rep),
        plots::backbones(rep),
        plots::residual_where(rep),
        plots::residual_spectra({{"model " + plots::effect_list(fit.effects), &rep}}),
    };
    plots::write_all(*plot_dir, "ridgewatch compare: " + l.path, text.str(), files);
    err << "compare: wrote " << files.size() << " plots and " << (*plot_dir / "index.html").string() << "\n";
  }
  if (!undescribed.empty()) {
    err << "compare: " << l.path << ": the rig does not describe this record (" << undescribed.front()
        << "); the fitted numbers above are not physical\n";
    return kExitBadInput;
  }
  return kExitOk;
}

}  // namespace ridgewatch::cli
