// Subcommands of `ridgewatch`. Each takes the arguments after the subcommand name, writes its result
// on `out` and diagnostics on `err`, and returns an exit code (see app/args.hpp). UsageError and
// drivers::InputError may propagate; main() maps them to exit codes 2 and 3 (app/args.hpp).
#pragma once

#include <iosfwd>
#include <string>
#include <vector>

#include "cli/app_names.hpp"

namespace ridgewatch::cli {

int run_analyze(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);
int run_modes(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);
int run_simulate(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);
int run_compare(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);
int run_diagnose(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);
int run_survey(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

}  // namespace ridgewatch::cli
