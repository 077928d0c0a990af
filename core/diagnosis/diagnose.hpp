// The missing-effect loop (issue 5 "diagnose"): starting from a model, refit with every diagnosable
// catalogue effect not yet in it (and every user-defined effect of the rig file, impact_model.hpp),
// judge each on the held-out impacts, accept the best one that passes the gate, repeat until none
// passes. Pure computation.
//
// Gate (all required; README "Model vs measurement"):
//  1. clear held-out gain: excess_before - excess_after > 3 sqrt(2 / n_held) (1 + excess_after), three
//     standard errors of a held-out power ratio over n_held white samples;
//  2. at least 75 % of the held-out impacts improve (a real effect acts on every impact; fitting noise
//     improves about half of them);
//  3. training ΔBIC < -10 ("very strong" evidence on the Kass–Raftery scale);
//  4. physically plausible fitted values: the effect's size significantly non-zero (> 2 sd from its
//     null value) and not stuck at a bound of the fit range (unless that bound is a physical value the
//     effect takes, as complete tooth separation), and effect-specific rules (a second mode off f0's own
//     bandwidth and off the mesh lines and sidebands, damped below 0.2; a damping drift keeping ζ > 0).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "core/diagnosis/model_fit.hpp"
#include "core/diagnosis/residual_analysis.hpp"
#include "core/diagnosis/term_discovery.hpp"

namespace ridgewatch::diagnosis {

struct CandidateOutcome {
  std::string effect;
  int round = 0;
  double excess_before = 0.0, excess_after = 0.0;
  double required_gain = 0.0;
  double fraction_improved = 0.0;
  double delta_bic = 0.0;
  bool plausible = false;
  std::string plausibility;  ///< why not plausible (empty when plausible)
  bool gain_ok = false, impacts_ok = false, bic_ok = false;
  bool passed = false;       ///< all four gates
  bool accepted = false;     ///< chosen in its round
  bool removed = false;      ///< a backward-elimination step: an earlier pick taken back
  std::vector<ParameterEstimate> parameters;  ///< the effect's own fitted parameters
  std::string evidence;      ///< in words
};

struct DiagnoseOptions {
  int max_rounds = 3;
  std::vector<std::string> candidates;  ///< empty: every diagnosable effect
  /// LM restarts of an accepted model from its own optimum (until χ² improves by less than 1).
  int polish_restarts = 2;
  /// Called with one line per stage (each candidate fit, each round's outcome) for progress reports;
  /// the caller decides where it goes (the CLI: stderr). Empty: silent.
  std::function<void(const std::string&)> progress;
  /// Term discovery (term_discovery.hpp) when the loop ends with structured residual left.
  bool discover_terms = true;
  TermDiscoveryOptions discovery;
};

struct DiagnoseResult {
  std::vector<std::string> initial_effects;
  double baseline_excess = 0.0;
  std::vector<CandidateOutcome> steps;   ///< every candidate tried, in order
  std::vector<std::string> verdict;      ///< accepted effects in order (taken-back ones removed)
  std::vector<std::string> removed;      ///< effects accepted and later taken back
  /// Candidates that explain the data about as well as an accepted one (or as each other when none
  /// could be told apart): the verdict names none of them alone. Empty when the choice was clear.
  std::vector<std::string> ambiguous;
  std::string ambiguous_evidence;        ///< why they could not be told apart (words)
  double final_excess = 0.0;
  double final_fit_percent = 0.0;
  bool unexplained = false;
  std::string unexplained_where;
  std::vector<std::string> sensor_problems;
  FitResult final_fit;
  ResidualReport final_report;
  /// The model after each round: [0] the starting model, then one entry per accepted effect (for
  /// "watch the error fall" tables and per-step residual spectra). `effects` is that round's model.
  struct Round {
    std::vector<std::string> effects;
    double heldout_excess = 0.0;
    double fit_percent = 0.0;
    ResidualReport report;
  };
  std::vector<Round> rounds;
  /// A step in ζ found by damping_drift's step-time scan (damping_step.hpp) when the final model has
  /// one: `time` is the model's step time with the onsets of the two fitted impacts that bracket it as
  /// its interval (the time is not identifiable inside that gap; sd NaN), `step` the fitted size.
  struct DampingStep {
    bool found = false;
    ParameterEstimate time, step;
  };
  DampingStep damping_step;
  /// Term discovery on the final model's residual, run when `unexplained` (else empty, proposed false).
  bool discovery_run = false;
  TermDiscoveryResult proposal;
};

DiagnoseResult diagnose(const ModelFitter& fitter, const std::vector<std::string>& initial_effects,
                        const DiagnoseOptions& options = {});

/// Sentences about sensor faults found in the segmentation (spikes, dropouts); empty if none.
std::vector<std::string> sensor_problems(const Segmentation& seg, double duration_s);

/// Reasons why the rig cannot describe the record (empty when it can): c0 or ζ at the bound of the
/// fit range, a damping ratio that the fitted drift makes negative, less than half of the held-out
/// signal explained (fit < 50 %), or every held-out response beating / far off f0. `compare` and
/// `diagnose` flag these and exit 3 instead of printing numbers that mean nothing (issue 14).
std::vector<std::string> description_problems(const ModelFitter& fitter, const FitResult& fit, const ResidualReport& rep);

/// The fit that best describes the record, for description_problems: the discovered force on the
/// starting model when it supersedes the accepted catalogue effects (they are then listed as
/// ambiguous with it), else the final model's fit. The superseded fit can sit at a range end for that
/// reason alone: cubic damping approximated by quadratic damping and friction drives ζ to 1e-4.
const FitResult& best_description(const DiagnoseResult& r);

/// A number with `digits` significant digits (%.*g) for evidence texts and reports.
std::string format_number(double value, int digits = 3);

}  // namespace ridgewatch::diagnosis
