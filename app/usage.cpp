#include "app/usage.hpp"

#include <set>
#include <sstream>

namespace ridgewatch::app::usage {

namespace {

const Flag kChannel{"--channel", "N", "channel of a multichannel file, 0-based (default 0)"};
const Flag kRate{"--rate", "HZ", "sample rate of a one-column CSV file (required for such files)"};
const Flag kFormat{"--format", "json|table",
                   "json (default; compare/diagnose: text) or table: aligned columns, 4 significant digits",
                   true};
const Flag kRig{"--rig", "RIG.yaml", "rig file (config/rigs/, /usr/share/ridgewatch/rigs/); required", false, true};
const Flag kWith{"--with", "EFFECT[:k=v[!],...]", "add a catalogue or rig-file (custom_effects) effect to the model; k=v starts a parameter, k=v! fixes it (repeatable)"};
const Flag kJson{"--json", "", "print the result as one JSON object instead of text (same as --format json)"};
const Flag kPlots{"--plots", "DIR", "also write SVG plots and DIR/index.html (DIR is created)"};

// One line per flag. Adding a flag to a command: one line here (tests/test_usage.cpp fails until
// the command's Args and this table agree).
std::vector<Command> make_commands() {
  return {
      {"analyze",
       "FILE",
       "detect impacts and print one JSON line per impact (frequency, damping ratio, status, alarm)",
       {
           {"--config", "F", "configuration file; its pipeline section and rig are used (default: built-in defaults)"},
           {"--rig", "RIG.yaml", "rig file: f_expected_hz and the detector band from its model unless --config sets them; "
                                 "the summary reports measured f vs model f_d"},
           kChannel,
           {"--all-channels", "", "one stream per channel, same pipeline; events carry \"stream\": \"ch<N>\" (N 0-based), "
                                  "in time order"},
           {"--jobs", "N", "with several streams (--all-channels): run them on N threads, 1-256 (default 1)"},
           {"--summary", "", "several FILEs allowed; instead of the events one JSON object, per file and stream and over all, "
                             "with the count of events and of ok ones, mean zeta, its spread and 95 % interval, mean f"},
           {"--plots", "DIR", "with --summary: also write summary.svg (mean zeta per file with its 95 % interval and "
                              "every ok event, the paper's Figure 9) and DIR/index.html"},
           kRate,
           kFormat,
       },
       {"The same pipeline as ridgewatchd, on a file, as fast as possible. With source.combine in --config the "
        "stream is a derived channel (e.g. the mesh coordinate from two shaft channels)."}},
      {"modes",
       "FILE",
       "identify the modes (frequency, damping ratio, 95 % interval) of one free response",
       {
           kChannel,
           kRate,
           {"--fmin", "HZ", "lower edge of the band searched for modes"},
           {"--fmax", "HZ", "upper edge of the band searched for modes (< fs/2)"},
           {"--max-modes", "K", "keep the K strongest peaks, 1-64 (default 16)"},
           {"--method", "two-point|ridge-ls|ml", "estimator reported in each mode's top-level fields (default ml)"},
           {"--eta0", "X", "Morlet centre frequency eta0 for every mode, 5-1000 (default: chosen per mode)"},
           {"--voices", "V", "analysis rows per octave, 4-256 (default 32)"},
           {"--start", "S", "start of the free response, s from the file start (default: first sample at half the peak)"},
           {"--end", "S", "end of the analysed part, s from the file start (default: the record end)"},
           {"--min-snr-db", "D", "a peak must stand D dB above the noise floor (default 10)"},
           {"--all-methods", "", "add the estimates of every method to each mode"},
           {"--plots", "DIR", "also write scalogram, envelope and backbone SVG plots and DIR/index.html"},
           kFormat,
       },
       {}},
      {"survey",
       "FILE",
       "find repeated impacts, the band they ring in and their modes; propose a pipeline configuration",
       {
           kChannel,
           kRate,
           {"--json", "", "print every figure as one JSON object"},
           {"--plots", "DIR", "also write kurtogram, envelope spectrum and free-response SVG plots and DIR/index.html"},
           {"--write-config", "OUT.yaml", "merge the proposal into a copy of --config (or of the defaults)"},
           {"--config", "F", "configuration file the proposal is merged into"},
           {"--rig", "RIG.yaml", "rig file: name the shaft order of the impact rate"},
           {"--fmin", "HZ", "lowest frequency considered"},
           {"--fmax", "HZ", "highest frequency considered (at most fs/2)"},
       },
       {"Without repeated impacts it says so with the evidence and proposes nothing (exit 0)."}},
      {"simulate",
       "",
       "simulate the gear-pair model; writes BASE.wav and BASE.truth.json",
       {
           kRig,
           {"--effect", "NAME[:key=value,...]", "add a catalogue effect with parameters (repeatable)"},
           {"--duration", "S", "length of the simulation, s"},
           {"--rate", "HZ", "output sample rate"},
           {"--noise", "REL", "sensor noise, relative to the response RMS"},
           {"--seed", "N", "random seed (same arguments and seed: same bytes)"},
           {"--channels", "vib|vib,tacho|vib,shafts",
            "channels written: the sensor, optionally a tacho pulse or the shaft speeds phi1_dot, phi2_dot (rad/s) "
            "whose rb1 phi1_dot + rb2 phi2_dot is q dot"},
           {"--out", "BASE", "output base name; required", false, true},
           {"--list-effects", "", "print the effect catalogue as JSON and exit"},
       },
       {}},
      {"compare",
       "FILE",
       "fit the gear-pair model to the impacts; fitted c0 vs nominal, held-out excess, where it fails",
       {kRig, kWith, kChannel, kRate, kJson, kPlots, kFormat},
       {}},
      {"diagnose",
       "FILE",
       "find the missing model effect: try each catalogue and rig-file effect, accept those that pass the gate",
       {
           kRig,
           kWith,
           kChannel,
           kRate,
           kJson,
           {"--history", "H.jsonl", "append this run to a history file (plotted by --plots)"},
           {"--max-impacts", "N", "impacts used, 4-100000 (default 16: 8 fitted, 8 held out)"},
           {"--quiet", "", "no progress lines on stderr"},
           kPlots,
           kFormat,
       },
       {}},
  };
}

Command make_daemon() {
  return {"ridgewatchd",
          "",
          "gearbox damping monitor daemon",
          {
              {"--config", "FILE", "configuration file (default: built-in defaults)"},
              {"--replay", "FILE", "replay a recorded file instead of the configured source"},
              {"--speed", "max|N", "replay pace: N x real time, max = as fast as possible"},
              {"--loop", "", "replay: start again at the end"},
              {"--channel", "N", "channel analysed (replay and ALSA), 0-based"},
              {"--events", "PATH|-", "JSON Lines event log (- = standard output)"},
              {"--csv", "PATH", "also write a CSV event log"},
              {"--capture-dir", "DIR", "capture each impact window as WAV + JSON (output.capture.dir)"},
              {"--log-level", "LEVEL", "trace, debug, info, warn or error"},
              {"--max-samples", "N", "stop after N input samples (soak runs)"},
              {"--check-config", "FILE", "check a configuration file and exit"},
              {"--survey", "SECONDS", "record SECONDS from the configured source, print its survey and exit"},
              {"--write-config", "OUT.yaml", "with --survey: merge the proposal into a copy of --config"},
              {"--print-defaults", "", "print the default configuration and exit"},
              {"--list-devices", "", "list ALSA capture devices (rates, formats, channels) and GPIO chips and lines"},
              {"--test-relays", "", "cycle the configured relay lines (gpio section) after a confirmation"},
              {"--yes", "", "with --test-relays: do not ask for confirmation"},
              {"--version", "", "print the version and exit"},
          },
          {"Signals: TERM/INT finish the impact in progress, flush and exit 0; HUP reloads the configuration "
           "(a bad one is rejected, the old one kept) and reopens the output files (with streams: only reopens "
           "them; other changes need a restart); USR1 resets a latched alarm. With streams, http.listen serves all of "
           "them: /metrics with a stream label, the page with a link per stream.",
           "Exit codes: 0 ok, 2 bad usage or configuration, 3 input (file/device) failed."}};
}

std::string flag_text(const Flag& f) { return f.value.empty() ? f.name : f.name + " " + f.value; }

// Wraps "[--a X] [--b] ..." items after `indent` columns to lines of at most `width`.
std::string wrap_items(const std::string& head, const std::vector<std::string>& items, std::size_t width = 100) {
  std::string out = head, line = head;
  const std::string pad(head.size() + 1, ' ');  // continuation lines align with the first item
  for (const auto& it : items) {
    if (line.size() + 1 + it.size() > width && line.size() > pad.size()) {
      out += "\n" + pad;
      line = pad;
    }
    const std::string piece = (line == pad ? "" : " ") + it;
    out += piece;
    line += piece;
  }
  return out;
}

std::vector<std::string> bracketed(const Command& c) {
  std::vector<std::string> items;
  for (const auto& f : c.flags) items.push_back(f.required ? flag_text(f) : "[" + flag_text(f) + "]");
  return items;
}

// roff: escape backslashes and leading dots/quotes, and '-' as \- (so flags copy and paste).
std::string roff(const std::string& s) {
  std::string o;
  for (char ch : s) {
    if (ch == '\\') o += "\\e";
    else if (ch == '-') o += "\\-";
    else o += ch;
  }
  if (!o.empty() && (o[0] == '.' || o[0] == '\'')) o = "\\&" + o;
  return o;
}

void man_flags(std::ostringstream& o, const Command& c) {
  for (const auto& f : c.flags) {
    if (f.value.empty())
      o << ".TP\n.B " << roff(f.name) << "\n";
    else
      o << ".TP\n.BI \"" << roff(f.name) << " \" \"" << roff(f.value) << "\"\n";
    o << roff(f.help) << "\n";
  }
}

void man_header(std::ostringstream& o, const std::string& name, int section, const std::string& version) {
  o << ".\\\" Generated by packaging/gen_docs from app/usage.cpp; do not edit.\n"
    << ".TH " << name << " " << section << " \"\" \"ridgewatch " << version << "\" \"ridgewatch\"\n"
    << ".nh\n.ad l\n";  // no hyphenation, ragged right: flags stay whole and copyable
}

}  // namespace

const std::vector<Command>& commands() {
  static const std::vector<Command> c = make_commands();
  return c;
}

const Command& daemon() {
  static const Command d = make_daemon();
  return d;
}

const Command* find(const std::string& name) {
  for (const auto& c : commands())
    if (c.name == name) return &c;
  return nullptr;
}

std::vector<std::string> args_flags(const Command& c, bool valued) {
  std::vector<std::string> v;
  for (const auto& f : c.flags)
    if (!f.by_main && f.value.empty() != valued) v.push_back(f.name);
  return v;
}

Args parse(const std::vector<std::string>& argv, const Command& c) {
  const auto valued = args_flags(c, true), switches = args_flags(c, false);
  return Args(argv, std::set<std::string>(valued.begin(), valued.end()),
              std::set<std::string>(switches.begin(), switches.end()));
}

std::string command_help(const Command& c, const std::string& program) {
  std::ostringstream o;
  const std::string head = "usage: " + program + (c.name == program ? "" : " " + c.name) +
                           (c.operands.empty() ? "" : " " + c.operands);
  o << wrap_items(head, bracketed(c)) << "\n" << c.summary << "\n\nflags:\n";
  std::size_t w = 0;
  for (const auto& f : c.flags) w = std::max(w, flag_text(f).size());
  for (const auto& f : c.flags) o << "  " << flag_text(f) << std::string(w + 2 - flag_text(f).size(), ' ') << f.help << "\n";
  o << "  --help" << std::string(w + 2 > 6 ? w + 2 - 6 : 1, ' ') << "print this help and exit\n";
  for (const auto& n : c.notes) o << "\n" << n << "\n";
  return o.str();
}

std::string top_help() {
  std::ostringstream o;
  o << "usage: ridgewatch COMMAND [ARGS]   (ridgewatch COMMAND --help: the command's flags explained)\n"
       "commands:\n";
  for (const auto& c : commands()) {
    o << wrap_items("  " + c.name + (c.operands.empty() ? "" : " " + c.operands), bracketed(c)) << "\n";
    o << "      " << c.summary << "\n";
  }
  o << "  --version  print the version\n"
       "exit codes: 0 ok, 2 bad usage or configuration, 3 bad input data\n";
  return o.str();
}

std::string man_ridgewatch(const std::string& version) {
  std::ostringstream o;
  man_header(o, "RIDGEWATCH", 1, version);
  o << ".SH NAME\nridgewatch \\- gearbox damping identification from impact responses\n"
    << ".SH SYNOPSIS\n";
  for (const auto& c : commands()) {
    o << ".B ridgewatch " << c.name << "\n";
    if (!c.operands.empty()) o << ".I " << c.operands << "\n";
    o << roff([&] {
      std::string s;
      for (const auto& it : bracketed(c)) s += it + " ";
      return s;
    }()) << "\n.br\n";
  }
  o << ".B ridgewatch \\-\\-version\n"
    << ".SH DESCRIPTION\nMorlet continuous-wavelet damping identification (modes of a free response, "
       "per-impact monitoring of a file), the gear-pair simulator and model-versus-measurement diagnosis. "
       "Results go to standard output, messages to standard error.\n";
  o << ".SH COMMANDS\n";
  for (const auto& c : commands()) {
    o << ".SS " << roff(c.name) << "\n" << roff(c.summary) << ".\n";
    for (const auto& n : c.notes) o << ".PP\n" << roff(n) << "\n";
    man_flags(o, c);
  }
  o << ".SH EXIT STATUS\n0 ok, 1 internal error, 2 bad usage or configuration (the message names the flag "
       "or key), 3 bad input data (the message names the file and the problem).\n"
    << ".SH SEE ALSO\n.BR ridgewatchd (8),\n.BR ridgewatch.yaml (5)\n";
  return o.str();
}

std::string man_ridgewatchd(const std::string& version) {
  const Command& d = daemon();
  std::ostringstream o;
  man_header(o, "RIDGEWATCHD", 8, version);
  o << ".SH NAME\nridgewatchd \\- gearbox damping monitor daemon\n.SH SYNOPSIS\n.B ridgewatchd\n";
  for (const auto& it : bracketed(d)) o << roff(it) << "\n";
  o << ".SH DESCRIPTION\nReads an ALSA capture device (or replays a file), detects impacts, estimates the "
       "damping ratio of each, tracks it against a learned baseline (EWMA, CUSUM) and drives alarm relays. "
       "Events go to a JSON Lines log; a status line (last damping ratio, baseline, EWMA z-score, alarm) "
       "goes to the log and to systemd every logging.status_interval_s. Usually started by systemd "
       "(ridgewatchd.service) with /etc/ridgewatch/ridgewatch.yaml.\n"
    << ".SH OPTIONS\n";
  man_flags(o, d);
  o << ".TP\n.B \\-\\-help\nprint the help and exit\n";
  for (const auto& n : d.notes) o << ".PP\n" << roff(n) << "\n";
  o << ".SH FIRST LIVE RUN\n.nf\nridgewatchd \\-\\-list\\-devices\n"
       "ridgewatchd \\-\\-check\\-config /etc/ridgewatch/ridgewatch.yaml\n"
       "ridgewatchd \\-\\-config /etc/ridgewatch/ridgewatch.yaml \\-\\-test\\-relays\n"
       "systemctl enable \\-\\-now ridgewatchd\njournalctl \\-u ridgewatchd \\-f\n.fi\n"
    << ".SH FILES\n.TP\n/etc/ridgewatch/ridgewatch.yaml\nconfiguration, see\n.BR ridgewatch.yaml (5)\n"
       ".TP\n/var/lib/ridgewatch\nstate and captures\n.TP\n/var/log/ridgewatch\nevent logs (rotated by "
       "/etc/logrotate.d/ridgewatch, which sends HUP)\n"
    << ".SH SEE ALSO\n.BR ridgewatch (1),\n.BR ridgewatch.yaml (5),\n.BR systemd.service (5)\n";
  return o.str();
}

std::string man_config(const std::string& version, const std::string& config_yaml) {
  std::ostringstream o;
  man_header(o, "RIDGEWATCH.YAML", 5, version);
  o << ".SH NAME\nridgewatch.yaml \\- configuration of ridgewatchd and ridgewatch analyze\n"
    << ".SH DESCRIPTION\nA YAML file with the key rig (a rig file whose model supplies the expected "
       "frequency and the detector band) and the sections source, pipeline, output, gpio and logging. "
       "A key left out keeps its default; unknown or mistyped keys and out-of-range values are errors "
       "(exit 2) naming the key. Check a file with\n.B ridgewatchd \\-\\-check\\-config\n.IR FILE ;\n"
       "print the defaults with\n.BR \"ridgewatchd \\-\\-print\\-defaults\" .\n"
       ".PP\nThe documented file below (installed as /etc/ridgewatch/ridgewatch.yaml) lists every key "
       "with its unit, range and default.\n"
    << ".SH KEYS\n.nf\n";
  std::istringstream in(config_yaml);
  for (std::string line; std::getline(in, line);) o << (line.empty() ? "" : roff(line)) << "\n";
  o << ".fi\n.SH SEE ALSO\n.BR ridgewatchd (8),\n.BR ridgewatch (1)\n";
  return o.str();
}

std::string bash_completion() {
  // Plain bash (COMP_WORDS, compgen): works with or without the bash-completion package.
  std::ostringstream o;
  o << "# bash completion for ridgewatch and ridgewatchd. Generated by packaging/gen_docs from app/usage.cpp.\n"
       "_ridgewatch() {\n"
       "  local cur=${COMP_WORDS[COMP_CWORD]} prev=${COMP_WORDS[COMP_CWORD-1]} flags\n"
       "  if [[ $COMP_CWORD -eq 1 ]]; then\n"
       "    COMPREPLY=($(compgen -W '";
  for (const auto& c : commands()) o << c.name << " ";
  o << "--help --version' -- \"$cur\"))\n    return\n  fi\n  case ${COMP_WORDS[1]} in\n";
  for (const auto& c : commands()) {
    o << "    " << c.name << ") flags='";
    for (const auto& f : c.flags) o << f.name << " ";
    o << "--help' ;;\n";
  }
  o << "    *) return ;;\n  esac\n"
       "  case $prev in\n"
       "    --format) COMPREPLY=($(compgen -W 'json table' -- \"$cur\")); return ;;\n"
       "    --method) COMPREPLY=($(compgen -W 'two-point ridge-ls ml' -- \"$cur\")); return ;;\n"
       "    --channels) COMPREPLY=($(compgen -W 'vib vib,tacho vib,shafts' -- \"$cur\")); return ;;\n"
       "    --plots) COMPREPLY=($(compgen -d -- \"$cur\")); return ;;\n";
  // Other valued flags take a number or a name: nothing to offer.
  o << "    ";
  bool first = true;
  std::set<std::string> seen;
  for (const auto& c : commands())
    for (const auto& f : c.flags)
      if (seen.insert(f.name).second && !f.value.empty() && f.name != "--format" && f.name != "--method" && f.name != "--channels" &&
          f.name != "--plots" && f.value.find("yaml") == std::string::npos && f.value != "FILE" && f.value != "F" &&
          f.value.find("jsonl") == std::string::npos && f.value != "BASE") {
        o << (first ? "" : "|") << f.name;
        first = false;
      }
  o << ") return ;;\n"
       "  esac\n"
       "  if [[ $cur == -* ]]; then COMPREPLY=($(compgen -W \"$flags\" -- \"$cur\")); else COMPREPLY=($(compgen -f -- \"$cur\")); fi\n"
       "}\ncomplete -o filenames -F _ridgewatch ridgewatch\n\n"
       "_ridgewatchd() {\n"
       "  local cur=${COMP_WORDS[COMP_CWORD]} prev=${COMP_WORDS[COMP_CWORD-1]}\n"
       "  case $prev in\n"
       "    --log-level) COMPREPLY=($(compgen -W 'trace debug info warn error' -- \"$cur\")); return ;;\n"
       "    --speed) COMPREPLY=($(compgen -W 'max 1 10' -- \"$cur\")); return ;;\n"
       "    --capture-dir) COMPREPLY=($(compgen -d -- \"$cur\")); return ;;\n"
       "    --channel|--max-samples) return ;;\n"
       "  esac\n"
       "  if [[ $cur == -* ]]; then COMPREPLY=($(compgen -W '";
  for (const auto& f : daemon().flags) o << f.name << " ";
  o << "--help' -- \"$cur\")); else COMPREPLY=($(compgen -f -- \"$cur\")); fi\n}\n"
       "complete -o filenames -F _ridgewatchd ridgewatchd\n";
  return o.str();
}

}  // namespace ridgewatch::app::usage
