// The one description of every command's flags: `ridgewatch --help`, `ridgewatch CMD --help`,
// `ridgewatchd --help`, the man pages ridgewatch(1), ridgewatchd(8), ridgewatch.yaml(5) and the bash
// completion are all generated from the tables in usage.cpp (packaging/gen_docs.cpp writes the files at
// build time). A flag added to a command's Args must get one line there; tests/test_usage.cpp compares
// the flags each command's Args accepts with the table, the help text, the man page and the completion.
#pragma once

#include <string>
#include <vector>

#include "app/args.hpp"

namespace ridgewatch::app::usage {

struct Flag {
  std::string name;     ///< "--fmin"
  std::string value;    ///< metavariable ("HZ"); empty for a switch
  std::string help;     ///< one sentence: meaning, unit, range, default
  bool by_main = false; ///< handled by main() before the command's Args (e.g. --format)
  bool required = false;  ///< shown without brackets in the synopsis
};

struct Command {
  std::string name;      ///< "modes"; "ridgewatchd" for the daemon
  std::string operands;  ///< positional part of the synopsis, e.g. "FILE"
  std::string summary;   ///< one line
  std::vector<Flag> flags;
  std::vector<std::string> notes;  ///< extra paragraphs of the command's help
};

/// The subcommands of `ridgewatch`, in help order.
const std::vector<Command>& commands();
/// The daemon's flags (`ridgewatchd`).
const Command& daemon();
/// The subcommand named `name`; nullptr when there is none.
const Command* find(const std::string& name);

/// `ridgewatch CMD --help` / `ridgewatchd --help`: synopsis and one line per flag.
std::string command_help(const Command& c, const std::string& program = "ridgewatch");
/// `ridgewatch --help`: every command with every flag.
std::string top_help();

/// Names of the flags the command's Args parses (valued and switches), i.e. without by_main flags.
std::vector<std::string> args_flags(const Command& c, bool valued);

/// The command's Args, with the flags of its table entry: a command parsing its arguments this way
/// needs one line in the table per flag and nothing else. (The daemon does; the subcommands still
/// list their flags in their own Args call, and tests/test_usage.cpp checks that the two agree.)
Args parse(const std::vector<std::string>& argv, const Command& c);

/// Man pages (roff, man(7) macros). `config_yaml` is the documented configuration file (config/ridgewatch.yaml).
std::string man_ridgewatch(const std::string& version);
std::string man_ridgewatchd(const std::string& version);
std::string man_config(const std::string& version, const std::string& config_yaml);
/// bash completion script for ridgewatch and ridgewatchd.
std::string bash_completion();

}  // namespace ridgewatch::app::usage
