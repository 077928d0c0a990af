// `ridgewatch survey` and `ridgewatchd --survey SECONDS`: the report of core/survey/survey.hpp as text
// or JSON, the proposed `pipeline:` block and --write-config (the proposal merged into a copy of a
// configuration file). Shared by the CLI command and the daemon's survey mode; the plots are the CLI's
// (cli/survey.cpp passes them in as write_plots).
#pragma once

#include <functional>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include "core/survey/survey.hpp"

namespace ridgewatch::app {

struct SurveyOutput {
  bool json = false;
  std::optional<std::string> write_config;  ///< --write-config OUT.yaml
  std::optional<std::string> base_config;   ///< the configuration file the proposal is merged into
  /// Called once after the report with the result, the source's name and the text report (the CLI's
  /// --plots DIR); empty: no plots.
  std::function<void(const survey::SurveyResult&, const std::string& source_name, const std::string& text)> write_plots;
};

/// Checks the output flags before any work: --write-config named and not the base file itself.
/// Throws UsageError naming the flag.
void check_survey_output(const SurveyOutput& out);

/// Runs the survey on `samples` and writes the report (stdout: text or one JSON object; notes on
/// `err`). Returns the exit code (0, also when no impacts are found).
int survey_and_report(const std::vector<double>& samples, double sample_rate_hz, const std::string& source_name,
                      const survey::SurveyOptions& options, const SurveyOutput& output, std::ostream& out,
                      std::ostream& err);

/// The proposal as the `pipeline:` block of a configuration file (current keys).
std::string proposal_yaml(const survey::Proposal& p);

}  // namespace ridgewatch::app
