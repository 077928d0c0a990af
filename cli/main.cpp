// ridgewatch: command-line front end. Results go to stdout, messages to stderr.
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "cli/args.hpp"
#include "cli/commands.hpp"
#include "drivers/sample_source.hpp"
#include "ridgewatch_version.hpp"

namespace {

constexpr const char* kUsage =
    "usage: ridgewatch COMMAND [ARGS]\n"
    "commands:\n"
    "  analyze FILE [--config F] [--channel N] [--rate HZ]\n"
    "      detect impacts and print one JSON line per impact (frequency, damping ratio, status, alarm)\n"
    "  modes FILE [--channel N] [--rate HZ] [--fmin HZ] [--fmax HZ] [--max-modes K]\n"
    "             [--method two-point|ridge-ls|ml] [--eta0 X]\n"
    "      identify the modes (frequency, damping ratio, 95 % interval) of one free response\n"
    "  simulate --rig RIG.yaml [--effect NAME[:key=value,...]]... [--duration S] [--rate HZ] [--noise REL]\n"
    "           [--seed N] [--channels vib|vib,tacho] --out BASE   (or: simulate --list-effects)\n"
    "      simulate the gear-pair model; writes BASE.wav and BASE.truth.json\n"
    "  compare --rig RIG.yaml FILE [--with EFFECT]... [--json] [--plots DIR]\n"
    "      fit the gear-pair model to the impacts; fitted c0 vs nominal, held-out excess, where it fails\n"
    "  diagnose --rig RIG.yaml FILE [--with EFFECT]... [--json] [--history H.jsonl] [--max-impacts N]\n"
    "           [--plots DIR]\n"
    "      find the missing model effect: try each catalogue effect, accept those that pass the gate\n"
    "  --plots DIR (compare, diagnose): also write SVG plots and DIR/index.html, a page that shows them\n"
    "      (DIR is created; if it cannot be created or written: exit 2 naming --plots and DIR)\n"
    "  --version  print the version\n"
    "exit codes: 0 ok, 2 bad usage or configuration, 3 bad input data\n";

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

}  // namespace

int main(int argc, char** argv) {
  namespace cli = ridgewatch::cli;
  if (argc < 2) {
    std::cerr << kUsage;
    return cli::kExitUsage;
  }
  const std::string command = argv[1];
  if (command == "--help" || command == "-h" || command == "help") {
    std::cout << kUsage;
    return cli::kExitOk;
  }
  if (command == "--version") {
    std::cout << "ridgewatch " << RIDGEWATCH_VERSION << "\n";
    return cli::kExitOk;
  }
  const std::vector<std::string> args(argv + 2, argv + argc);
  for (const Command& c : kCommands) {
    if (command != c.name) continue;
    try {
      return c.run(args, std::cout, std::cerr);
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
  std::cerr << "ridgewatch: unknown command '" << command << "'\n" << kUsage;
  return cli::kExitUsage;
}
