// Fault injection into ridgewatchd: event log on a full disk (/dev/full, and a full tmpfs that gets
// space back), an event log the daemon may not write (EACCES, as an unprivileged user) that becomes
// writable, SIGTERM at random moments, SIGHUP with broken configurations, and ALSA device loss with a
// counted gap reaching the event stream (in-process Daemon with an injected AlsaSource).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>
#include <sys/mount.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>
#include <sstream>
#include <thread>

#include "cli_runner.hpp"
#include "daemon/daemon.hpp"
#include "daemon/event_log.hpp"
#include "drivers/alsa_source.hpp"
#include "drivers/replay_file.hpp"
#include "process_runner.hpp"

using ridgewatch::test::ChildProcess;
using ridgewatch::test::run_cli;
using ridgewatch::test::slurp;
namespace fs = std::filesystem;
namespace rd = ridgewatch::drivers;
using namespace std::chrono_literals;

namespace {

const std::string kReplay = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav";

class FailureInjection : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rw-fault-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (mounted_) ::umount2(mounted_->c_str(), MNT_DETACH);
    fs::remove_all(dir_);
  }

  static std::vector<nlohmann::json> read_jsonl(const fs::path& p) {
    std::vector<nlohmann::json> out;
    std::ifstream f(p);
    for (std::string line; std::getline(f, line);) out.push_back(nlohmann::json::parse(line));  // throws on a half line
    return out;
  }
  static std::size_t count_lines(const fs::path& p) {
    std::ifstream f(p);
    std::size_t n = 0;
    for (std::string line; std::getline(f, line);) ++n;
    return n;
  }
  static const std::vector<nlohmann::json>& reference() {
    static const std::vector<nlohmann::json> ref = [] {
      const auto r = run_cli({"analyze", kReplay});
      std::vector<nlohmann::json> out;
      std::istringstream s(r.out);
      for (std::string line; std::getline(s, line);) out.push_back(nlohmann::json::parse(line));
      return out;
    }();
    return ref;
  }
  /// The numbers of the daemon's final status line "stopped: S samples, N impacts (...), ... W write failures".
  static std::pair<std::uint64_t, std::uint64_t> stopped_impacts_and_failures(const std::string& err) {
    std::smatch m;
    static const std::regex re(R"(stopped: \d+ samples, (\d+) impacts .* (\d+) write failures)");
    if (!std::regex_search(err, m, re)) return {~0ULL, ~0ULL};
    return {std::stoull(m[1]), std::stoull(m[2])};
  }
  static bool wait_for(const std::function<bool()>& pred, std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
      if (pred()) return true;
      std::this_thread::sleep_for(20ms);
    }
    return pred();
  }

  fs::path dir_;
  std::optional<fs::path> mounted_;
};

// ENOSPC on every write: the daemon processes the whole file, counts every lost event, logs the
// fault, exits 0; the CSV log on a healthy disk gets every event.
TEST_F(FailureInjection, EventLogOnAFullDiskIsCountedAndProcessingContinues) {
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "max", "--events", "/dev/full", "--csv",
                  (dir_ / "ev.csv").string()},
                 {}, (dir_ / "out").string(), (dir_ / "err").string());
  ASSERT_EQ(d.wait(60s), 0) << slurp(dir_ / "err");
  const std::string err = slurp(dir_ / "err");
  EXPECT_NE(err.find("/dev/full: write failed: No space left on device"), std::string::npos) << err;
  EXPECT_NE(err.find("processing continues"), std::string::npos) << err;
  const auto [impacts, failures] = stopped_impacts_and_failures(err);
  EXPECT_EQ(impacts, reference().size()) << err;
  EXPECT_EQ(failures, reference().size()) << err;  // every event counted as not written
  EXPECT_EQ(count_lines(dir_ / "ev.csv"), reference().size() + 1);
}

// A block of lines (the daemon writes each processing step's events as one block) on a disk that
// has room for part of it: tmpfs takes one free page (4096 bytes) of the 4500-byte block, the write
// of the rest fails with ENOSPC; the two whole lines stay, the cut third line is truncated away and
// counted as lost. With space back, the next block is written whole after them.
TEST_F(FailureInjection, LineBlockCutShortByAFullDiskKeepsWholeLinesOnly) {
  const fs::path mnt = dir_ / "mnt";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=64k,mode=0755") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << "); needs root with CAP_SYS_ADMIN";
  mounted_ = mnt;
  const fs::path filler = mnt / "filler";
  {
    const int fd = ::open(filler.c_str(), O_WRONLY | O_CREAT, 0644);
    ASSERT_GE(fd, 0);
    const std::string chunk(4096, 'x');
    while (::write(fd, chunk.data(), chunk.size()) > 0) {
    }
    const off_t size = ::lseek(fd, 0, SEEK_END);
    ASSERT_GE(size, 4096);
    ASSERT_EQ(size % 4096, 0);
    ASSERT_EQ(::ftruncate(fd, size - 4096), 0);  // exactly one page free
    ::close(fd);
  }
  const fs::path path = mnt / "lines.txt";
  ridgewatch::daemon::LineFile file(path.string());
  const std::string a(1499, 'a'), b(1499, 'b'), c(1499, 'c');
  EXPECT_EQ(file.write_lines(a + "\n" + b + "\n" + c + "\n", 3), 1u);
  EXPECT_TRUE(file.fault());
  EXPECT_NE(file.last_error().find("No space left on device"), std::string::npos) << file.last_error();
  EXPECT_EQ(file.lines_written(), 2u);
  EXPECT_EQ(file.lines_failed(), 1u);
  EXPECT_EQ(slurp(path), a + "\n" + b + "\n");
  fs::remove(filler);
  EXPECT_EQ(file.write_lines("d\ne\n", 2), 0u);
  EXPECT_FALSE(file.fault());
  EXPECT_EQ(file.lines_written(), 4u);
  EXPECT_EQ(slurp(path), a + "\n" + b + "\n" + "d\ne\n");
}

// Nothing fits (ENOSPC at once): every line of the block is counted, nothing is written.
TEST(LineFile, BlockOnAFullDeviceCountsEveryLine) {
  ridgewatch::daemon::LineFile file("/dev/full");
  EXPECT_EQ(file.write_lines("one\ntwo\nthree\n", 3), 3u);
  EXPECT_EQ(file.lines_failed(), 3u);
  EXPECT_EQ(file.lines_written(), 0u);
  EXPECT_NE(file.last_error().find("/dev/full: write failed: No space left on device"), std::string::npos)
      << file.last_error();
  EXPECT_FALSE(file.write_line("four"));
  EXPECT_EQ(file.lines_failed(), 4u);
}

// A disk that fills up and gets space back: a 64 KiB tmpfs filled to the last byte. Writes fail
// (ENOSPC, or a short write that is cut back so the file stays whole JSON lines) until the filler
// is deleted; then writing resumes by itself. Written + counted-as-lost = all events.
TEST_F(FailureInjection, EventLogResumesWhenTheDiskHasSpaceAgain) {
  const fs::path mnt = dir_ / "mnt";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=64k,mode=0755") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << "); needs root with CAP_SYS_ADMIN";
  mounted_ = mnt;
  {
    const int fd = ::open((mnt / "filler").c_str(), O_WRONLY | O_CREAT, 0644);
    ASSERT_GE(fd, 0);
    const std::string chunk(512, 'x');
    while (::write(fd, chunk.data(), chunk.size()) > 0) {
    }
    ::close(fd);
  }
  const fs::path events = mnt / "ev.jsonl";
  // 8x real time and looping: ~200 impacts per second, for as long as the test needs.
  ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "8", "--loop", "--events", events.string()}, {},
                 (dir_ / "out").string(), (dir_ / "err").string());
  ASSERT_TRUE(wait_for([&] { return slurp(dir_ / "err").find("No space left on device") != std::string::npos; }, 30s))
      << slurp(dir_ / "err");
  EXPECT_TRUE(d.running());
  fs::remove(mnt / "filler");  // space comes back
  ASSERT_TRUE(wait_for([&] { return count_lines(events) >= 20; }, 30s)) << slurp(dir_ / "err");
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(30s), 0) << slurp(dir_ / "err");
  const std::string err = slurp(dir_ / "err");
  const auto written = read_jsonl(events);  // every line whole
  const auto [impacts, failures] = stopped_impacts_and_failures(err);
  EXPECT_GT(failures, 0u) << err;
  EXPECT_GE(written.size(), 20u);
  EXPECT_EQ(written.size() + failures, impacts) << err;
  // What was written after the resume is the stream's tail without holes: consecutive impacts 40 ms
  // (1024 samples at 25.6 kHz) apart.
  for (std::size_t i = 1; i < written.size(); ++i) {
    const auto step = written[i]["sample_index"].get<std::int64_t>() - written[i - 1]["sample_index"].get<std::int64_t>();
    EXPECT_NEAR(static_cast<double>(step), 1024.0, 64.0) << i;
  }
}

// EACCES: the daemon runs as an unprivileged user (root ignores permission bits) and its log
// directory is not writable for it; every event is counted as lost, each later event retries the
// open, and once the directory is made writable the log is created and writing resumes.
TEST_F(FailureInjection, UnwritableEventLogResumesWhenPermissionIsGranted) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to start the daemon as another user";
  if (std::system("command -v setpriv >/dev/null 2>&1") != 0) GTEST_SKIP() << "setpriv (util-linux) not installed";
  const fs::path logdir = dir_ / "log";
  fs::create_directories(logdir);
  fs::permissions(dir_, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec |
                            fs::perms::others_read | fs::perms::others_exec);
  fs::permissions(logdir, fs::perms::owner_all | fs::perms::others_read | fs::perms::others_exec);  // 0705
  const fs::path events = logdir / "ev.jsonl";
  ChildProcess d({"/usr/bin/setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", RIDGEWATCHD_PATH, "--replay",
                  kReplay, "--speed", "8", "--loop", "--events", events.string()},
                 {}, (dir_ / "out").string(), (dir_ / "err").string());
  ASSERT_TRUE(wait_for([&] { return slurp(dir_ / "err").find("Permission denied") != std::string::npos; }, 30s))
      << slurp(dir_ / "err");
  std::this_thread::sleep_for(300ms);  // some events are lost meanwhile
  EXPECT_TRUE(d.running());
  EXPECT_FALSE(fs::exists(events));
  fs::permissions(logdir, fs::perms::all);  // 0777: the daemon may create its log now
  ASSERT_TRUE(wait_for([&] { return count_lines(events) >= 20; }, 30s)) << slurp(dir_ / "err");
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(30s), 0) << slurp(dir_ / "err");
  const std::string err = slurp(dir_ / "err");
  EXPECT_NE(err.find(events.string() + ": cannot open for writing: Permission denied"), std::string::npos) << err;
  const auto written = read_jsonl(events);
  const auto [impacts, failures] = stopped_impacts_and_failures(err);
  EXPECT_GT(failures, 0u) << err;
  EXPECT_EQ(written.size() + failures, impacts) << err;
}

// SIGTERM at 20 random moments (seeded, reproducible) of a 2x real-time replay: exit 0, every line
// whole JSON, and the events equal the first events of the full analysis (none lost, none invented);
// only the very last may be an impact cut by the shutdown, marked window_cut.
TEST_F(FailureInjection, SigtermAtRandomMomentsLosesNothing) {
  std::mt19937 rng(6);
  std::uniform_int_distribution<int> delay_ms(0, 1200);  // the replay lasts 1 s at 2x
  const auto& ref = reference();
  ASSERT_GT(ref.size(), 40u);
  for (int run = 0; run < 20; ++run) {
    const int delay = delay_ms(rng);
    SCOPED_TRACE("run " + std::to_string(run) + ", SIGTERM " + std::to_string(delay) + " ms after start");
    const fs::path events = dir_ / ("ev" + std::to_string(run) + ".jsonl");
    const fs::path err_path = dir_ / ("err" + std::to_string(run));
    ChildProcess d({RIDGEWATCHD_PATH, "--replay", kReplay, "--speed", "2", "--events", events.string()}, {},
                   (dir_ / "out").string(), err_path.string());
    // Signal handlers are installed before the "started" line; a SIGTERM before that would be the
    // default action (the process has not done anything yet), which is not what this test is about.
    ASSERT_TRUE(wait_for([&] { return slurp(err_path).find("started:") != std::string::npos; }, 30s));
    std::this_thread::sleep_for(std::chrono::milliseconds(delay));
    d.signal(SIGTERM);
    ASSERT_EQ(d.wait(30s), 0) << slurp(err_path);
    const auto got = read_jsonl(events);
    ASSERT_LE(got.size(), ref.size());
    for (std::size_t i = 0; i < got.size(); ++i) {
      if (i + 1 == got.size() && got[i]["status"] == "window_cut") {
        // An impact detected at the shutdown: its onset is refined on the samples present (the
        // envelope maximum after the trigger may be missing), so it may sit a little off the full
        // analysis' onset; 0.5 ms is a fraction of the trigger band's 3 ms envelope rise.
        const double shift = got[i]["sample_index"].get<double>() - ref[i]["sample_index"].get<double>();
        EXPECT_LE(std::abs(shift), 0.0005 * 25600) << i;
        continue;
      }
      EXPECT_EQ(got[i]["sample_index"], ref[i]["sample_index"]) << i;
      EXPECT_EQ(got[i]["status"], ref[i]["status"]) << i;
      EXPECT_EQ(got[i]["zeta"], ref[i]["zeta"]) << i;
    }
    const auto [impacts, failures] = stopped_impacts_and_failures(slurp(err_path));
    EXPECT_EQ(impacts, got.size()) << slurp(err_path);  // every impact the daemon detected is in the log
    EXPECT_EQ(failures, 0u);
  }
}

// SIGHUP with a configuration that is not YAML, then with the file deleted: both rejected, the old
// configuration kept, events keep coming, a good file afterwards is taken.
TEST_F(FailureInjection, SighupWithBrokenOrMissingConfigKeepsTheOldOne) {
  const fs::path cfg = dir_ / "ridgewatch.yaml";
  { std::ofstream(cfg) << "pipeline:\n  analyzer:\n    method: ml\n"; }
  const fs::path events = dir_ / "ev.jsonl";
  ChildProcess d({RIDGEWATCHD_PATH, "--config", cfg.string(), "--replay", kReplay, "--speed", "2", "--loop", "--events",
                  events.string()},
                 {}, (dir_ / "out").string(), (dir_ / "err").string());
  ASSERT_TRUE(wait_for([&] { return count_lines(events) >= 5; }, 30s));
  { std::ofstream(cfg) << "pipeline: [unclosed\n"; }
  d.signal(SIGHUP);
  ASSERT_TRUE(wait_for([&] { return slurp(dir_ / "err").find("not valid YAML") != std::string::npos; }, 30s));
  fs::remove(cfg);
  d.signal(SIGHUP);
  ASSERT_TRUE(wait_for([&] { return slurp(dir_ / "err").find("cannot open") != std::string::npos; }, 30s))
      << slurp(dir_ / "err");
  const std::size_t before = count_lines(events);
  ASSERT_TRUE(wait_for([&] { return count_lines(events) >= before + 10; }, 30s));  // still processing
  EXPECT_TRUE(d.running());
  { std::ofstream(cfg) << "pipeline:\n  analyzer:\n    method: ridge-ls\n"; }
  d.signal(SIGHUP);
  ASSERT_TRUE(wait_for([&] { return slurp(dir_ / "err").find("configuration reloaded") != std::string::npos; }, 30s));
  d.signal(SIGTERM);
  ASSERT_EQ(d.wait(30s), 0);
  const std::string err = slurp(dir_ / "err");
  std::size_t rejected = 0;
  for (std::size_t p = 0; (p = err.find("new configuration rejected", p)) != std::string::npos; ++p) ++rejected;
  EXPECT_EQ(rejected, 2u) << err;
  read_jsonl(events);  // whole lines
}

// ALSA device loss through the daemon. The first PCM writes its copy of the stream to /dev/full
// (libasound's `file` plugin), so a few thousand frames in, its read fails with -EIO as when the
// device is unplugged; the AlsaSource closes it, waits out its backoff and reopens, getting a healthy
// PCM on the same data. The outage becomes a counted gap in the stream index, which the daemon logs
// and the pipeline turns into a cut window (no event spans it with a trusted number), and the
// events after it equal those of the file analysed on its own.
TEST_F(FailureInjection, AlsaDeviceLossBecomesALoggedCountedGapAndProcessingResumes) {
  // The samples of the bundled simulation as S16 raw frames (25.6 kHz mono).
  auto src = rd::open_replay(kReplay, {});
  const std::vector<double> x = rd::read_all(*src);
  std::vector<std::int16_t> raw;
  for (double v : x) raw.push_back(static_cast<std::int16_t>(std::lround(std::clamp(v, -1.0, 1.0) * 32767.0)));
  const fs::path infile = dir_ / "in.raw";
  {
    std::ofstream f(infile, std::ios::binary);
    f.write(reinterpret_cast<const char*>(raw.data()), static_cast<std::streamsize>(raw.size() * 2));
  }
  const std::string pcm = "{ type file slave.pcm { type null } infile \"" + infile.string() + "\" format \"raw\" ";
  const auto local = rd::AlsaLocalConfig::from_string("pcm.rwfull " + pcm + "file \"/dev/full\" }\npcm.rwgood " + pcm +
                                                      "file \"/dev/null\" }");
  std::atomic<int> opens{0};
  rd::AlsaSeams seams;
  seams.open = [&](snd_pcm_t** p, const std::string&) {
    const int n = opens.fetch_add(1);
    if (n == 1) return -ENODEV;  // the first (immediate) reopen attempt fails: the device is still gone
    return snd_pcm_open_lconf(p, n == 0 ? "rwfull" : "rwgood", SND_PCM_STREAM_CAPTURE, 0, local->get());
  };
  // Real backoff sleep (the default): the outage lasts >= 200 ms, i.e. >= 5120 frames lost.

  ridgewatch::daemon::DaemonOptions options;
  options.config = ridgewatch::app::default_config();
  // Replay semantics for the ring (the file plugin has no pacing: wait for the consumer instead of
  // overrunning, so the only gap is the injected one); the source itself is the AlsaSource.
  options.config.source.type = "replay";
  options.config.output.events = (dir_ / "ev.jsonl").string();
  options.config.output.source_name = "alsa-test";
  options.source_factory = [&](const ridgewatch::app::SourceConfig&) -> std::unique_ptr<rd::SampleSource> {
    rd::AlsaSourceConfig c;
    c.device = "rwtest";
    c.rate_hz = 25600;
    c.format = rd::AlsaSampleFormat::s16_le;
    c.period_frames = 256;
    c.buffer_frames = 1024;
    c.reopen_min_ms = 200ms;
    c.reopen_max_ms = 400ms;
    return std::make_unique<rd::AlsaSource>(c, local, seams);
  };
  std::ostringstream log;
  auto previous_logger = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::ostream_sink_mt>(log)));
  ridgewatch::daemon::Daemon::clear_requests();
  ridgewatch::daemon::Daemon daemon(options);
  int code = -1;
  std::thread runner([&] { code = daemon.run(); });
  // After the reopen the healthy PCM plays the whole file (then silence): wait for its impacts.
  const bool complete = wait_for([&] { return count_lines(dir_ / "ev.jsonl") >= reference().size(); }, 60s);
  ridgewatch::daemon::Daemon::request_stop();
  runner.join();
  ridgewatch::daemon::Daemon::clear_requests();
  spdlog::set_default_logger(previous_logger);
  ASSERT_TRUE(complete) << log.str();
  EXPECT_NE(log.str().find("gap in the input before sample"), std::string::npos) << log.str();
  EXPECT_EQ(code, 0);
  EXPECT_EQ(opens.load(), 3);  // the first open, one failed reopen, the successful one
  EXPECT_EQ(daemon.stats().gaps, 1u);
  const auto got = read_jsonl(dir_ / "ev.jsonl");
  // Events before the loss: impacts whose window the gap cut are reported window_cut, never ok.
  // After it: the file from its start, shifted by the stream position of the reopen.
  const auto& ref = reference();
  ASSERT_GE(got.size(), ref.size());
  const std::size_t before = got.size() - ref.size();
  const auto offset = got[before]["sample_index"].get<std::int64_t>() - ref[0]["sample_index"].get<std::int64_t>();
  EXPECT_GT(offset, 5000);  // the outage: >= 200 ms at 25.6 kHz, plus the frames read before it
  for (std::size_t i = 0; i < before; ++i) EXPECT_NE(got[i]["status"], "ok") << got[i].dump();
  for (std::size_t i = 0; i < ref.size(); ++i) {
    const auto& g = got[before + i];
    EXPECT_EQ(g["sample_index"].get<std::int64_t>() - offset, ref[i]["sample_index"].get<std::int64_t>()) << i;
    // The file's last impact is cut by the end of the file when analysed alone; here silence follows.
    if (i + 1 < ref.size() || ref[i]["status"] != "window_cut") {
      EXPECT_EQ(g["status"], ref[i]["status"]) << i;
    }
    EXPECT_NEAR(g["zeta"].get<double>(), ref[i]["zeta"].get<double>(), 2e-4) << i;  // S16 quantisation
  }
}

}  // namespace
