// ridgewatch: command-line front end. Results go to stdout, messages to stderr.
#include <exception>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "cli/format_table.hpp"
#include "app/usage.hpp"
#include "drivers/sample_source.hpp"
#include "ridgewatch_version.hpp"

namespace {

struct Command {
  const char* name;
  int (*run)(const std::vector<std::string>&, std::ostream&, std::ostream&);
};

constexpr Command kCommands[] = {
    {"analyze", ridgewatch::cli::run_analyze},
    {"modes", ridgewatch::cli::run_modes},
    {"simulate", ridgewatch::cli::run_simulate},
    {"compare", ridgewatch::cli::run_compare},
    {"diagnose", ridgewatch::cli::run_diagnose},
    {"survey", ridgewatch::cli::run_survey},
};

// Takes --format json|table out of the arguments of a command whose usage lists it (main handles it
// for every such command, so the commands keep printing JSON). nullopt: not given.
std::optional<std::string> take_format(const std::string& command, std::vector<std::string>& args) {
  namespace cli = ridgewatch::cli;
  const auto* doc = cli::usage::find(command);
  bool listed = false;
  for (const auto& f : doc ? doc->flags : std::vector<cli::usage::Flag>{}) listed = listed || f.name == "--format";
  if (!listed) return std::nullopt;
  std::optional<std::string> format;
  for (std::size_t i = 0; i < args.size();) {
    if (args[i] == "--format") {
      if (i + 1 >= args.size()) throw cli::UsageError("--format needs a value");
      format = args[i + 1];
      args.erase(args.begin() + static_cast<std::ptrdiff_t>(i), args.begin() + static_cast<std::ptrdiff_t>(i) + 2);
    } else if (args[i].rfind("--format=", 0) == 0) {
      format = args[i].substr(9);
      args.erase(args.begin() + static_cast<std::ptrdiff_t>(i));
    } else {
      ++i;
    }
  }
  if (format && *format != "json" && *format != "table")
    throw cli::UsageError("--format: '" + *format + "' is not one of json, table");
  // compare and diagnose print text by default; both formats start from their JSON.
  if (format && (command == "compare" || command == "diagnose")) args.push_back("--json");
  return format;
}

}  // namespace

int main(int argc, char** argv) {
  namespace cli = ridgewatch::cli;
  if (argc < 2) {
    std::cerr << cli::usage::top_help();
    return cli::kExitUsage;
  }
  const std::string command = argv[1];
  if (command == "--help" || command == "-h" || command == "help") {
    std::cout << cli::usage::top_help();
    return cli::kExitOk;
  }
  if (command == "--version") {
    std::cout << "ridgewatch " << RIDGEWATCH_VERSION << "\n";
    return cli::kExitOk;
  }
  std::vector<std::string> args(argv + 2, argv + argc);
  for (const Command& c : kCommands) {
    if (command != c.name) continue;
    try {
      const auto format = take_format(command, args);
      if (format != "table") return c.run(args, std::cout, std::cerr);
      std::ostringstream json;
      const int rc = c.run(args, json, std::cerr);
      std::cout << (rc == cli::kExitOk ? cli::format_table(json.str()) : json.str());
      return rc;
    } catch (const cli::HelpRequested&) {
      std::cout << cli::usage::command_help(*cli::usage::find(command));
      return cli::kExitOk;
    } catch (const cli::UsageError& e) {
      std::cerr << "ridgewatch " << command << ": " << e.what() << "\n";
      return cli::kExitUsage;
    } catch (const ridgewatch::drivers::InputError& e) {
      std::cerr << "ridgewatch " << command << ": " << e.what() << "\n";
      return cli::kExitBadInput;
    } catch (const std::exception& e) {
      std::cerr << "ridgewatch " << command << ": internal error: " << e.what() << "\n";
      return 1;
    }
  }
  std::cerr << "ridgewatch: unknown command '" << command << "'\n" << cli::usage::top_help();
  return cli::kExitUsage;
}
