// ridgewatchd as systemd runs it: replay input, event log, SIGTERM/SIGHUP behaviour, sd_notify
// messages on a test-owned NOTIFY_SOCKET, watchdog pings only while samples arrive, usage errors.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "cli_runner.hpp"
#include "process_runner.hpp"

using ridgewatch::test::ChildProcess;
using ridgewatch::test::run_cli;
namespace fs = std::filesystem;
using namespace std::chrono_literals;

namespace {

const std::string kReplay = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav";

fs::path temp_dir(const std::string& name) {
  const auto d = fs::temp_directory_path() / ("ridgewatchd-test-" + name + "-" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

std::vector<nlohmann::json> read_jsonl(const fs::path& p) {
  std::vector<nlohmann::json> out;
  std::ifstream f(p);
  std::string line;
  while (std::getline(f, line)) out.push_back(nlohmann::json::parse(line));  // throws on a half line
  return out;
}

std::vector<nlohmann::json> analyze_events(const std::string& file) {
  const auto r = run_cli({"analyze", file});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  std::vector<nlohmann::json> out;
  std::istringstream s(r.out);
  std::string line;
  while (std::getline(s, line)) out.push_back(nlohmann::json::parse(line));
  return out;
}

std::string slurp(const fs::path& p) { return ridgewatch::test::slurp(p); }

// A datagram socket standing in for systemd's notify socket.
class NotifySocket {
 public:
  explicit NotifySocket(const fs::path& path) : path_(path) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof addr.sun_path - 1);
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) throw std::runtime_error("bind");
  }
  ~NotifySocket() { ::close(fd_); }
  /// All messages received within `duration`.
  std::vector<std::string> collect(std::chrono::milliseconds duration) {
    std::vector<std::string> msgs;
    const auto end = std::chrono::steady_clock::now() + duration;
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - std::chrono::steady_clock::now());
      if (left.count() <= 0) break;
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
      char buf[4096];
      const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
      if (n > 0) msgs.emplace_back(buf, static_cast<std::size_t>(n));
    }
    return msgs;
  }
  std::string env() const { return "NOTIFY_SOCKET=" + path_.string(); }

 private:
  fs::path path_;
  int fd_ = -1;
};

int count_containing(const std::vector<std::string>& msgs, const std::string& needle) {
  int n = 0;
  for (const auto& m : msgs) n += m.find(needle) != std::string::npos;
  return n;
}

}  // namespace

// The daemon and `ridgewatch analyze` share the pipeline: on the same file they must produce the
// same events (same onsets, same numbers).
TEST(Daemon, ReplayAsFastAsPossibleMatchesAnalyze) {
  const auto dir = temp_dir("max");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "max", "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << slurp(dir / "err");
  const auto daemon_events = read_jsonl(dir / "ev.jsonl");
  const auto reference = analyze_events(kReplay);
  ASSERT_EQ(daemon_events.size(), reference.size());
  ASSERT_GT(reference.size(), 40u);  // 2 s at 25 impacts/s
  for (std::size_t i = 0; i < reference.size(); ++i) {
    EXPECT_EQ(daemon_events[i]["sample_index"], reference[i]["sample_index"]);
    EXPECT_EQ(daemon_events[i]["status"], reference[i]["status"]);
    EXPECT_EQ(daemon_events[i]["zeta"], reference[i]["zeta"]);  // float samples either way: identical
    EXPECT_EQ(daemon_events[i]["alarm"], reference[i]["alarm"]);
  }
  EXPECT_TRUE(slurp(dir / "out").empty());  // events went to the file, nothing on stdout
}

// A replay as fast as possible through a ring far shorter than the file must not drop samples: the
// replay waits for the consumer (only live capture may overrun).
TEST(Daemon, FastReplayThroughATinyRingLosesNoSamples) {
  const auto dir = temp_dir("tiny");
  { std::ofstream(dir / "c.yaml") << "source:\n  ring_buffer_s: 0.05\n"; }
  ChildProcess d({RIDGEWATCHD_PATH, "--config", (dir / "c.yaml").string(), "--replay", kReplay, "--speed", "max",
                  "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << slurp(dir / "err");
  EXPECT_NE(slurp(dir / "err").find("51200 samples"), std::string::npos) << slurp(dir / "err");
  EXPECT_NE(slurp(dir / "err").find(" 0 overruns"), std::string::npos) << slurp(dir / "err");
  EXPECT_EQ(read_jsonl(dir / "ev.jsonl").size(), analyze_events(kReplay).size());
}

// Capture-on-trigger: every impact's raw window becomes a replay file with sidecar metadata, and the
// captured window holds the impact (its onset sits pretrigger_s into the file).
TEST(Daemon, CapturesEachImpactWindowWithSidecar) {
  const auto dir = temp_dir("capture");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "max", "--events", (dir / "ev.jsonl").string(),
                  "--capture-dir", (dir / "cap").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << slurp(dir / "err");
  const auto events = read_jsonl(dir / "ev.jsonl");
  ASSERT_FALSE(events.empty());
  std::size_t checked = 0;
  for (const auto& e : events) {
    const std::string base = (dir / "cap" / ("impact-" + std::to_string(e["sample_index"].get<std::uint64_t>()))).string();
    ASSERT_TRUE(fs::exists(base + ".wav")) << base;
    std::ifstream side_file(base + ".json");
    const auto side = nlohmann::json::parse(side_file);
    EXPECT_EQ(side["onset_sample_index"], e["sample_index"]);
    EXPECT_EQ(side["sample_rate_hz"].get<double>(), 25600.0);
    EXPECT_EQ(side["event"]["zeta"], e["zeta"]);
    if (checked++ < 3) {
      // The capture replays through the same tools: `modes` finds the gear-pair mode in it.
      const auto r = run_cli({"modes", base + ".wav", "--fmin", "500", "--fmax", "1500"});
      ASSERT_EQ(r.exit_code, 0) << r.err;
      const auto j = nlohmann::json::parse(r.out);
      ASSERT_GE(j["modes"].size(), 1u);
      EXPECT_NEAR(j["modes"][0]["f_hz"].get<double>(), e["f_hz"].get<double>(), 5.0);
    }
  }
}

// SIGTERM in the middle of a real-time replay: exit 0 promptly, every line complete JSON, and the
// events equal the first events of the full analysis (none lost, the one in progress finished).
TEST(Daemon, SigtermFinishesTheEventInProgressAndLosesNothing) {
  const auto dir = temp_dir("term");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "1", "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  std::this_thread::sleep_for(1000ms);
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(10s), 0) << slurp(dir / "err");
  const auto got = read_jsonl(dir / "ev.jsonl");
  const auto reference = analyze_events(kReplay);
  // ~1 s of a 2 s file at 25 impacts/s, with generous room for a slow start on a loaded machine.
  EXPECT_GE(got.size(), 5u);
  ASSERT_LT(got.size(), reference.size()) << "the replay ended before SIGTERM; the test proves nothing";
  // Every impact detected before the stop request is complete and identical to the reference. An
  // impact detected while its predecessor finished (impacts come every 40 ms, windows last 35 ms)
  // may follow, honestly marked window_cut: reported, not lost, not a wrong number marked ok.
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i]["sample_index"], reference[i]["sample_index"]) << i;
    if (i + 1 == got.size() && got[i]["status"] == "window_cut") continue;
    EXPECT_EQ(got[i]["status"], reference[i]["status"]) << i;
    EXPECT_EQ(got[i]["zeta"], reference[i]["zeta"]) << i;
  }
  EXPECT_NE(slurp(dir / "err").find("stop requested"), std::string::npos);
}

TEST(Daemon, NotifiesReadyStatusAndWatchdogWhileSamplesArrive) {
  const auto dir = temp_dir("notify");
  NotifySocket sock(dir / "notify.sock");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "1", "--loop", "--events", (dir / "ev.jsonl").string()},
                 {sock.env(), "WATCHDOG_USEC=300000"}, (dir / "out").string(), (dir / "err").string());
  const auto msgs = sock.collect(1500ms);
  d.signal(SIGTERM);
  EXPECT_EQ(d.wait(10s), 0) << slurp(dir / "err");
  EXPECT_EQ(count_containing(msgs, "READY=1"), 1);
  EXPECT_GE(count_containing(msgs, "STATUS="), 1);
  // Pings every watchdog/3 = 0.1 s while samples arrive: ~15 in 1.5 s; at least 5 on a loaded machine.
  EXPECT_GE(count_containing(msgs, "WATCHDOG=1"), 5);
}

// A stalled input (here: a replay slowed so far that no block arrives) must stop the watchdog pings
// so that systemd restarts the service.
TEST(Daemon, StalledInputWithholdsWatchdogPings) {
  const auto dir = temp_dir("stall");
  NotifySocket sock(dir / "notify.sock");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "0.001", "--events", (dir / "ev.jsonl").string()},
                 {sock.env(), "WATCHDOG_USEC=300000"}, (dir / "out").string(), (dir / "err").string());
  const auto msgs = sock.collect(1500ms);
  d.signal(SIGTERM);
  EXPECT_TRUE(d.wait(10s).has_value());
  EXPECT_EQ(count_containing(msgs, "READY=1"), 1);
  EXPECT_EQ(count_containing(msgs, "WATCHDOG=1"), 0);
  EXPECT_NE(slurp(dir / "err").find("withholding the watchdog ping"), std::string::npos);
}

TEST(Daemon, SighupWithBadConfigKeepsRunningWithTheOldOne) {
  const auto dir = temp_dir("hup");
  const auto cfg = dir / "ridgewatch.yaml";
  { std::ofstream(cfg) << "pipeline:\n  analyzer:\n    method: ml\n"; }
  ChildProcess d({RIDGEWATCHD_PATH, "--config", cfg.string(), "--replay", kReplay, "--speed", "1", "--loop", "--events",
                  (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  std::this_thread::sleep_for(400ms);
  { std::ofstream(cfg) << "pipeline:\n  analyzer:\n    method: fastest\n"; }
  d.signal(SIGHUP);
  std::this_thread::sleep_for(400ms);
  EXPECT_TRUE(d.running());
  { std::ofstream(cfg) << "pipeline:\n  analyzer:\n    method: ridge-ls\n"; }
  d.signal(SIGHUP);
  std::this_thread::sleep_for(400ms);
  EXPECT_TRUE(d.running());
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(10s), 0);
  const std::string err = slurp(dir / "err");
  EXPECT_NE(err.find("new configuration rejected"), std::string::npos) << err;
  EXPECT_NE(err.find("pipeline.analyzer.method"), std::string::npos) << err;
  EXPECT_NE(err.find("configuration reloaded"), std::string::npos) << err;
  EXPECT_GE(read_jsonl(dir / "ev.jsonl").size(), 10u);  // events kept coming through both reloads
}

// Log rotation: after the event log is renamed away, SIGHUP makes the daemon write to a new file at
// the configured path; together the two files hold every event exactly once.
TEST(Daemon, SighupReopensTheEventLogForRotation) {
  const auto dir = temp_dir("rotate");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "2", "--events", (dir / "ev.jsonl").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  // Start-up (FFT plans) took over 400 ms on a loaded 2-core machine: wait for the log to exist first.
  for (int i = 0; i < 500 && !fs::exists(dir / "ev.jsonl"); ++i) std::this_thread::sleep_for(10ms);
  std::this_thread::sleep_for(200ms);
  fs::rename(dir / "ev.jsonl", dir / "ev.jsonl.1");
  d.signal(SIGHUP);
  ASSERT_EQ(d.wait(30s), 0) << slurp(dir / "err");
  const auto old_part = read_jsonl(dir / "ev.jsonl.1");
  const auto new_part = read_jsonl(dir / "ev.jsonl");
  EXPECT_FALSE(old_part.empty());
  EXPECT_FALSE(new_part.empty());
  const auto reference = analyze_events(kReplay);
  ASSERT_EQ(old_part.size() + new_part.size(), reference.size());
  for (std::size_t i = 0; i < reference.size(); ++i) {
    const auto& got = i < old_part.size() ? old_part[i] : new_part[i - old_part.size()];
    EXPECT_EQ(got["sample_index"], reference[i]["sample_index"]) << i;
  }
}

TEST(Daemon, UnwritableEventLogIsCountedAndProcessingContinues) {
  const auto dir = temp_dir("nowrite");
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "max", "--events", "/nonexistent-dir/ev.jsonl",
                  "--csv", (dir / "ev.csv").string()},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(60s), 0);
  const std::string err = slurp(dir / "err");
  EXPECT_NE(err.find("/nonexistent-dir/ev.jsonl"), std::string::npos) << err;
  // The CSV log still got every event (header + one row per impact).
  std::ifstream csv(dir / "ev.csv");
  std::string line;
  std::size_t rows = 0;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, analyze_events(kReplay).size() + 1);
}

TEST(Daemon, UsageAndInputErrorsHaveDocumentedExitCodes) {
  const auto dir = temp_dir("usage");
  struct Case {
    std::vector<std::string> args;
    int code;
    std::string needle;
  };
  { std::ofstream(dir / "bad.yaml") << "trend:\n  ewma_lambda: 0.2\n"; }
  const std::vector<Case> cases = {
      {{"--speed", "fast", "--replay", kReplay}, 2, "--speed"},
      {{"--bogus"}, 2, "--bogus"},
      {{}, 2, "--replay"},
      {{"--check-config", (dir / "bad.yaml").string()}, 2, "trend"},
      {{"--config", "/nonexistent.yaml"}, 2, "/nonexistent.yaml"},
      {{"--replay", "/nonexistent.wav"}, 3, "/nonexistent.wav"},
      {{"--replay", kReplay, "--log-level", "loud"}, 2, "--log-level"},
  };
  for (const auto& c : cases) {
    std::vector<std::string> argv = {RIDGEWATCHD_PATH};
    argv.insert(argv.end(), c.args.begin(), c.args.end());
    ChildProcess d(argv, {}, (dir / "out").string(), (dir / "err").string());
    EXPECT_EQ(d.wait(30s), c.code) << c.needle << ": " << slurp(dir / "err");
    EXPECT_NE(slurp(dir / "err").find(c.needle), std::string::npos) << slurp(dir / "err");
  }
  const auto v = run_cli({});  // keep run_cli referenced for the shared helper
  EXPECT_EQ(v.exit_code, 2);
}

// systemd-analyze verify lints the shipped unit (with ExecStart pointing at the built binary).
TEST(SystemdUnit, VerifiesCleanly) {
  if (std::system("command -v systemd-analyze >/dev/null 2>&1") != 0) GTEST_SKIP() << "systemd-analyze not installed";
  const auto dir = temp_dir("unit");
  std::string unit = slurp(std::string(RIDGEWATCH_SOURCE_DIR) + "/systemd/ridgewatchd.service");
  for (const std::string key : {"Type=notify", "WatchdogSec=", "NoNewPrivileges=yes", "ProtectSystem=strict", "User="})
    EXPECT_NE(unit.find(key), std::string::npos) << key;
  const std::string from = "/usr/local/sbin/ridgewatchd";
  for (std::size_t p; (p = unit.find(from)) != std::string::npos;) unit.replace(p, from.size(), RIDGEWATCHD_PATH);
  { std::ofstream(dir / "ridgewatchd.service") << unit; }
  const std::string cmd = "systemd-analyze verify " + (dir / "ridgewatchd.service").string() + " >" +
                          (dir / "verify.log").string() + " 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << slurp(dir / "verify.log");
}
