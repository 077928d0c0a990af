// `ridgewatch survey` and `ridgewatchd --survey SECONDS`: the report of core/survey/survey.hpp as text
// or JSON, the proposed `pipeline:` block, --write-config (the proposal merged into a copy of a
// configuration file) and --plots DIR. Shared by the CLI command and the daemon's survey mode.
#pragma once

#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include "cli/app_names.hpp"
#include "core/survey/survey.hpp"

namespace ridgewatch::cli {

struct SurveyOutput {
  bool json = false;
  std::optional<std::string> plots_dir;     ///< --plots DIR (checked before the work)
  std::optional<std::string> write_config;  ///< --write-config OUT.yaml
  std::optional<std::string> base_config;   ///< the configuration file the proposal is merged into
};

/// Checks the output flags before any work: --plots DIR writable, --write-config not the base file.
/// Throws UsageError naming the flag.
void check_survey_output(const SurveyOutput& out);

/// Runs the survey on `samples` and writes the report (stdout: text or one JSON object; notes on
/// `err`). Returns the exit code (0, also when no impacts are found).
int survey_and_report(const std::vector<double>& samples, double sample_rate_hz, const std::string& source_name,
                      const survey::SurveyOptions& options, const SurveyOutput& output, std::ostream& out,
                      std::ostream& err);

/// The proposal as the `pipeline:` block of a configuration file (current keys).
std::string proposal_yaml(const survey::Proposal& p);

}  // namespace ridgewatch::cli
