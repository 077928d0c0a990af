// One usage table (app/usage.cpp) for every command: the flags each command's Args accepts are exactly
// the table's (so a flag added to a command without a line in the table fails here, naming it), and
// `--help`, the top-level help, the man pages and the bash completion list every one of them.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "app/args.hpp"
#include "cli/commands.hpp"
#include "app/usage.hpp"
#include "cli_runner.hpp"

namespace cli = ridgewatch::cli;
namespace app = ridgewatch::app;
namespace usage = ridgewatch::app::usage;
using ridgewatch::test::run_cli;

namespace {

using Runner = int (*)(const std::vector<std::string>&, std::ostream&, std::ostream&);
const std::map<std::string, Runner> kRunners = {{"analyze", cli::run_analyze},
                                                {"modes", cli::run_modes},
                                                {"simulate", cli::run_simulate},
                                                {"compare", cli::run_compare},
                                                {"diagnose", cli::run_diagnose},
                                                {"survey", cli::run_survey}};

// The flags the command's Args accepts, as reported by its HelpRequested.
app::HelpRequested accepted_flags(const std::string& command) {
  std::ostringstream out, err;
  try {
    kRunners.at(command)({"--help"}, out, err);
  } catch (const app::HelpRequested& h) {
    return h;
  }
  ADD_FAILURE() << command << " --help did not reach Args (no HelpRequested)";
  return app::HelpRequested({}, {});
}

// A flag as roff writes it: every '-' as "\-".
std::string roff_flag(const std::string& flag) {
  std::string o;
  for (char c : flag) o += c == '-' ? std::string("\\-") : std::string(1, c);
  return o;
}

std::set<std::string> table_set(const usage::Command& c, bool valued) {
  const auto v = usage::args_flags(c, valued);
  return {v.begin(), v.end()};
}

}  // namespace

TEST(Usage, EveryCommandHasATableEntryAndViceVersa) {
  for (const auto& [name, run] : kRunners) EXPECT_NE(usage::find(name), nullptr) << name << " missing in app/usage.cpp";
  for (const auto& c : usage::commands()) EXPECT_TRUE(kRunners.count(c.name)) << c.name << " has no runner here";
}

// The table, and so help/man/completion, lists exactly what Args accepts.
TEST(Usage, ArgsFlagsEqualTheTableForEveryCommand) {
  for (const auto& c : usage::commands()) {
    const auto h = accepted_flags(c.name);
    for (const auto& f : h.valued)
      EXPECT_TRUE(table_set(c, true).count(f)) << c.name << ": Args accepts " << f
                                                 << " (with a value) but app/usage.cpp does not list it with a value";
    for (const auto& f : h.switches)
      EXPECT_TRUE(table_set(c, false).count(f)) << c.name << ": Args accepts switch " << f
                                                  << " but app/usage.cpp does not list it as a switch";
    for (const auto& f : table_set(c, true))
      EXPECT_TRUE(h.valued.count(f)) << c.name << ": app/usage.cpp lists " << f << " but Args does not take it with a value";
    for (const auto& f : table_set(c, false))
      EXPECT_TRUE(h.switches.count(f)) << c.name << ": app/usage.cpp lists switch " << f << " but Args does not accept it";
  }
}

TEST(Usage, HelpTopHelpManAndCompletionListEveryFlag) {
  const std::string top = usage::top_help();
  const std::string man = usage::man_ridgewatch("test");
  const std::string completion = usage::bash_completion();
  for (const auto& c : usage::commands()) {
    const std::string help = usage::command_help(c);
    for (const auto& f : c.flags) {
      EXPECT_NE(help.find(f.name), std::string::npos) << c.name << " --help lacks " << f.name;
      EXPECT_NE(top.find(f.name), std::string::npos) << "ridgewatch --help lacks " << c.name << " " << f.name;
      EXPECT_NE(man.find(".SS " + c.name), std::string::npos) << c.name;
      // In the man page, within the command's own section.
      const auto sec = man.find(".SS " + c.name);
      const auto next = man.find(".SS ", sec + 1);
      EXPECT_NE(man.substr(sec, next - sec).find(roff_flag(f.name)), std::string::npos)
          << "ridgewatch(1) section " << c.name << " lacks " << f.name;
      EXPECT_NE(completion.find(c.name + ") flags='"), std::string::npos);
      const auto cl = completion.find(c.name + ") flags='");
      EXPECT_NE(completion.substr(cl, completion.find('\n', cl) - cl).find(f.name + " "), std::string::npos)
          << "completion of " << c.name << " lacks " << f.name;
    }
  }
  const std::string dhelp = usage::command_help(usage::daemon(), "ridgewatchd");
  const std::string dman = usage::man_ridgewatchd("test");
  for (const auto& f : usage::daemon().flags) {
    EXPECT_NE(dhelp.find(f.name), std::string::npos) << "ridgewatchd --help lacks " << f.name;
    EXPECT_NE(dman.find(roff_flag(f.name)), std::string::npos) << "ridgewatchd(8) lacks " << f.name;
    EXPECT_NE(completion.find(f.name + " "), std::string::npos) << "ridgewatchd completion lacks " << f.name;
  }
  // The flags issue 12 found missing from the top-level help.
  for (const char* f : {"--start", "--all-methods", "--min-snr-db", "--voices"}) EXPECT_NE(top.find(f), std::string::npos) << f;
}

// Through the binaries: every subcommand's --help exits 0 with the table's text on stdout; the
// daemon's too; an unknown flag is still exit 2.
TEST(Usage, HelpOfEveryCommandExitsZero) {
  for (const auto& c : usage::commands()) {
    const auto r = run_cli({c.name, "--help"});
    EXPECT_EQ(r.exit_code, 0) << c.name << ": " << r.err;
    EXPECT_EQ(r.out, usage::command_help(c)) << c.name;
    // Also after other arguments (a user adding --help to a command line that failed).
    EXPECT_EQ(run_cli({c.name, "somefile.wav", "--help"}).exit_code, 0) << c.name;
  }
  const auto top = run_cli({"--help"});
  EXPECT_EQ(top.exit_code, 0);
  EXPECT_EQ(top.out, usage::top_help());
  const auto bad = run_cli({"modes", "x.wav", "--no-such-flag"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("unknown flag --no-such-flag"), std::string::npos) << bad.err;

  const std::string cmd = ridgewatch::test::shell_quote(RIDGEWATCHD_PATH) + " --help";
  FILE* p = ::popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string out;
  char buf[4096];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
  EXPECT_EQ(WEXITSTATUS(::pclose(p)), 0);
  EXPECT_EQ(out, usage::command_help(usage::daemon(), "ridgewatchd"));
}

// Args itself: --help wins over every other argument, unless the command parses --help itself.
TEST(Usage, ArgsReportsItsFlagsOnHelp) {
  try {
    app::Args({"--rate", "5", "--help", "--bogus"}, {"--rate"}, {"--json"});
    FAIL() << "no HelpRequested";
  } catch (const app::HelpRequested& h) {
    EXPECT_EQ(h.valued, (std::set<std::string>{"--rate"}));
    EXPECT_EQ(h.switches, (std::set<std::string>{"--json"}));
  }
  const app::Args own({"--help"}, {}, {"--help"});
  EXPECT_TRUE(own.has("--help"));
}

namespace {

ridgewatch::test::CliResult run_daemon(const std::vector<std::string>& args, const std::string& stdin_text = "") {
  const auto dir = std::filesystem::temp_directory_path();
  const std::string tag = std::to_string(::getpid());
  const auto in = dir / ("ridgewatchd-usage-" + tag + ".in");
  const auto out = dir / ("ridgewatchd-usage-" + tag + ".out");
  const auto err = dir / ("ridgewatchd-usage-" + tag + ".err");
  std::ofstream(in) << stdin_text;
  std::string cmd = ridgewatch::test::shell_quote(RIDGEWATCHD_PATH);
  for (const auto& a : args) cmd += " " + ridgewatch::test::shell_quote(a);
  cmd += " <" + in.string() + " >" + out.string() + " 2>" + err.string();
  const int status = std::system(cmd.c_str());
  ridgewatch::test::CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ridgewatch::test::slurp(out);
  r.err = ridgewatch::test::slurp(err);
  for (const auto& p : {in, out, err}) std::filesystem::remove(p);
  return r;
}

}  // namespace

// --list-devices works without any sound card or GPIO chip (it says so); --test-relays needs the gpio
// section; a missing ALSA device is the daemon's own one-line message, no raw "ALSA lib ..." line.
TEST(DaemonHelpers, ListDevicesTestRelaysAndCleanAlsaErrors) {
  const auto list = run_daemon({"--list-devices"});
  EXPECT_EQ(list.exit_code, 0) << list.err;
  EXPECT_NE(list.out.find("ALSA capture devices (source.alsa.device):"), std::string::npos) << list.out;
  EXPECT_NE(list.out.find("GPIO chips and lines (gpio section):"), std::string::npos) << list.out;
  EXPECT_EQ(list.err.find("ALSA lib"), std::string::npos) << list.err;

  const auto relays = run_daemon({"--test-relays"}, "yes\n");
  EXPECT_EQ(relays.exit_code, 2);
  EXPECT_NE(relays.err.find("--test-relays: gpio.enabled is false"), std::string::npos) << relays.err;
  EXPECT_EQ(run_daemon({"--yes"}).exit_code, 2);

  const auto cfg = std::filesystem::temp_directory_path() / ("ridgewatchd-usage-alsa-" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(cfg) << "source:\n  type: alsa\n  alsa:\n    device: \"plughw:CARD=NoSuchCard,DEV=0\"\n";
  const auto alsa = run_daemon({"--config", cfg.string()});
  std::filesystem::remove(cfg);
  EXPECT_EQ(alsa.exit_code, 3) << alsa.err;
  EXPECT_NE(alsa.err.find("alsa plughw:CARD=NoSuchCard,DEV=0: cannot open capture PCM"), std::string::npos) << alsa.err;
  EXPECT_EQ(alsa.err.find("ALSA lib"), std::string::npos) << alsa.err;
}

// The completion script in bash itself: after "ridgewatch CMD --" it offers exactly the command's
// flags and --help; values of --format and --method are offered; the daemon's flags likewise.
TEST(Usage, BashCompletionOffersEveryFlag) {
  if (std::system("command -v bash >/dev/null 2>&1") != 0) GTEST_SKIP() << "no bash";
  const auto script = std::filesystem::temp_directory_path() / ("ridgewatch-completion-" + std::to_string(::getpid()));
  std::ofstream(script) << usage::bash_completion();
  auto complete = [&](const std::string& function, const std::vector<std::string>& words) {
    std::string cmd = "bash -c 'source " + script.string() + "; COMP_WORDS=(";
    for (const auto& w : words) cmd += "\"" + w + "\" ";
    cmd += "); COMP_CWORD=" + std::to_string(words.size() - 1) + "; " + function +
           "; printf \"%s\\n\" \"${COMPREPLY[@]}\"' 2>&1";
    FILE* p = ::popen(cmd.c_str(), "r");
    std::string out;
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
    ::pclose(p);
    std::set<std::string> got;
    std::istringstream in(out);
    for (std::string line; std::getline(in, line);)
      if (!line.empty()) got.insert(line);
    return got;
  };
  for (const auto& c : usage::commands()) {
    std::set<std::string> expected = {"--help"};
    for (const auto& f : c.flags) expected.insert(f.name);
    EXPECT_EQ(complete("_ridgewatch", {"ridgewatch", c.name, "--"}), expected) << c.name;
  }
  EXPECT_EQ(complete("_ridgewatch", {"ridgewatch", "mo"}), (std::set<std::string>{"modes"}));
  EXPECT_EQ(complete("_ridgewatch", {"ridgewatch", "modes", "x.wav", "--format", ""}), (std::set<std::string>{"json", "table"}));
  EXPECT_EQ(complete("_ridgewatch", {"ridgewatch", "modes", "--method", "r"}), (std::set<std::string>{"ridge-ls"}));
  std::set<std::string> daemon_flags = {"--help"};
  for (const auto& f : usage::daemon().flags) daemon_flags.insert(f.name);
  EXPECT_EQ(complete("_ridgewatchd", {"ridgewatchd", "--"}), daemon_flags);
  std::filesystem::remove(script);
}
