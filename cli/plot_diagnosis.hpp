// The plot files of `ridgewatch compare --plots DIR` and `ridgewatch diagnose --plots DIR` (issue 5
// "Plots"): SVG files drawn with cli/plot_svg.hpp from the fit and the residual reports of
// core/diagnosis, and DIR/index.html, a self-contained page (no scripts, no external style sheets)
// that shows the text report and every plot (<img> of the sibling SVG files).
//
// Files (diagnose: of the final model; compare: of the one fit):
//   impacts.svg             measured vs model on two held-out impacts (the worst and a typical one),
//                           residual in σ units below each
//   residual-scalogram.svg  RMS |CWT| of the held-out residual vs time after impact and frequency, in
//                           units of white noise of the floor σ, with f0 ± k·f_z and k·f_z markers
//   envelopes.svg           ln envelope |W(t, f0)| of a weak and a strong held-out impact, measured vs
//                           model, with the noise floor
//   backbones.svg           damping and frequency vs amplitude, measured vs model
//   residual-where.svg      held-out excess vs time after the impact, and per impact vs its amplitude
//   residual-spectrum.svg   residual spectrum per step (diagnose: per round) with the marker lines
//   candidate-ladder.svg    (diagnose) held-out excess after each candidate, by round and outcome
//   error-fall.svg          (diagnose) held-out excess per round, and per run of the --history file
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "cli/app_names.hpp"
#include "core/diagnosis/diagnose.hpp"

namespace ridgewatch::cli::plots {

struct PlotFile {
  std::string file;     ///< name inside DIR, e.g. "impacts.svg"
  std::string title;
  std::string caption;  ///< what to look for, one or two sentences
  std::string svg;      ///< the document
};

/// Creates DIR and its parents for `--plots DIR` and checks that a file can be written in it, before
/// any work is done. Throws UsageError (exit 2, like every other output error) naming --plots and DIR.
std::filesystem::path prepare_dir(const std::string& dir);

/// Writes every file and DIR/index.html (title, the text report in <pre>, one section per plot).
/// Throws UsageError naming --plots and the file that could not be written.
void write_all(const std::filesystem::path& dir, const std::string& page_title, const std::string& report_text,
               const std::vector<PlotFile>& files);

/// Measured vs model on two held-out impacts with the residual in σ units; `start` (optional): the
/// starting model's fit, drawn as a third line.
PlotFile impacts(const diagnosis::ModelFitter& fitter, const diagnosis::FitResult& fit, const diagnosis::FitResult* start = nullptr);
PlotFile residual_scalogram(const diagnosis::ModelFitter& fitter, const diagnosis::FitResult& fit, const diagnosis::ResidualReport& rep);
PlotFile envelopes(const diagnosis::ModelFitter& fitter, const diagnosis::FitResult& fit, const diagnosis::ResidualReport& rep);
/// `start` (optional): the starting model's report, whose model backbone is drawn as well.
PlotFile backbones(const diagnosis::ResidualReport& rep, const diagnosis::ResidualReport* start = nullptr);
/// Held-out excess per ms after the impact and per impact against the fitted impact force.
PlotFile residual_where(const diagnosis::ResidualReport& rep);
/// One curve per step: (label, report).
PlotFile residual_spectra(const std::vector<std::pair<std::string, const diagnosis::ResidualReport*>>& steps);
PlotFile candidate_ladder(const diagnosis::DiagnoseResult& r);

struct HistoryRun {
  std::vector<std::string> model, verdict;
  double baseline_excess = 0.0, final_excess = 0.0;
};
/// The runs of a --history file (JSON Lines written by diagnose) on `data_file`; lines that are not
/// such records are skipped. Empty if the file cannot be read.
std::vector<HistoryRun> read_history(const std::string& path, const std::string& data_file);
PlotFile error_fall(const diagnosis::DiagnoseResult& r, const std::vector<HistoryRun>& history);

/// "[a, b]" or "[]" for a list of effect names.
std::string effect_list(const std::vector<std::string>& effects);

}  // namespace ridgewatch::cli::plots
