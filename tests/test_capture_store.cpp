// Bounded capture-on-trigger (output.capture): limits on files and bytes with the oldest captures
// removed and counted, the select filter, captures left by an earlier run, a full disk (no half
// captures, counted, resumes by itself), the configuration keys (old spelling output.capture_dir
// still accepted), the acceptance run of issue 18 through the real daemon (max_files 100 over a 60 s
// replay), the status line, and the relay test helper.
#include <gtest/gtest.h>
#include <sndfile.h>
#include <sys/mount.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <vector>

#include "app/args.hpp"
#include "app/config_yaml.hpp"
#include "daemon/capture_store.hpp"
#include "daemon/relay_test.hpp"
#include "drivers/gpio_fake.hpp"
#include "cli_runner.hpp"
#include "process_runner.hpp"

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using ridgewatch::daemon::CaptureStore;
using ridgewatch::trend::AlarmLevel;
using ridgewatch::pipeline::ImpactEvent;
using ridgewatch::pipeline::ImpactStatus;
using ridgewatch::test::ChildProcess;

namespace {

constexpr double kFs = 25600.0;
const std::vector<float> kWindow(1000, 0.25f);  // 1000 float samples: a 4 KB WAV + a ~1 KB sidecar

class CaptureStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ridgewatch-capture-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (mounted_) ::umount2(mounted_->c_str(), MNT_DETACH);
    fs::remove_all(dir_);
  }
  ridgewatch::app::CaptureConfig config(std::uint64_t max_files, std::uint64_t max_bytes, const std::string& select = "all") {
    ridgewatch::app::CaptureConfig c;
    c.dir = (dir_ / "cap").string();
    c.max_files = max_files;
    c.max_bytes = max_bytes;
    c.select = select;
    return c;
  }
  std::vector<std::string> names() const {
    std::vector<std::string> n;
    if (fs::exists(dir_ / "cap"))
      for (const auto& e : fs::directory_iterator(dir_ / "cap")) n.push_back(e.path().filename().string());
    std::sort(n.begin(), n.end());
    return n;
  }
  fs::path dir_;
  std::optional<fs::path> mounted_;
};

ImpactEvent event(std::uint64_t index, ImpactStatus status = ImpactStatus::ok, AlarmLevel level = AlarmLevel::normal) {
  ImpactEvent e;
  e.sample_index = index;
  e.t_s = static_cast<double>(index) / kFs;
  e.f_hz = 854.0;
  e.zeta = 0.024;
  e.status = status;
  e.alarm.level = level;
  return e;
}

// The impact-N.wav / impact-N.json names of sample indices `from`, `from + step`, ... (count of them).
std::vector<std::string> expected_names(std::uint64_t from, std::uint64_t step, std::size_t count) {
  std::vector<std::string> n;
  for (std::size_t i = 0; i < count; ++i)
    for (const char* ext : {".json", ".wav"}) n.push_back("impact-" + std::to_string(from + i * step) + ext);
  std::sort(n.begin(), n.end());
  return n;
}

// Frames of a WAV file, -1 when libsndfile cannot read it (a half-written capture).
long long wav_frames(const fs::path& p) {
  SF_INFO info{};
  SNDFILE* f = sf_open(p.c_str(), SFM_READ, &info);
  if (f == nullptr) return -1;
  sf_close(f);
  return info.frames;
}

}  // namespace

// max_files counts files (a capture is a WAV and a JSON): 10 files = the 5 newest of 30 captures.
TEST_F(CaptureStoreTest, MaxFilesKeepsTheNewestAndCountsTheRemoved) {
  CaptureStore store(config(10, 0));
  for (std::uint64_t i = 0; i < 30; ++i) ASSERT_EQ(store.write(event(1000 * i), "t", kWindow, 1000 * i, kFs), "");
  EXPECT_EQ(store.written(), 30u);
  EXPECT_EQ(store.removed(), 25u);
  EXPECT_EQ(store.files(), 10u);
  EXPECT_EQ(names(), expected_names(25000, 1000, 5));
}

TEST_F(CaptureStoreTest, MaxBytesKeepsTheNewestWithinTheLimit) {
  CaptureStore probe(config(0, 0));
  ASSERT_EQ(probe.write(event(1), "t", kWindow, 1, kFs), "");
  const std::uint64_t one = probe.bytes();  // one capture: 4 KB of samples + header + sidecar
  ASSERT_GT(one, 4000u);
  fs::remove_all(dir_ / "cap");
  // Room for 3.5 captures: 3 stay. (Every capture here has the same size up to a digit of the index
  // in its sidecar, hence the half capture of margin.)
  CaptureStore store(config(0, one * 7 / 2));
  for (std::uint64_t i = 0; i < 12; ++i) ASSERT_EQ(store.write(event(100 + i), "t", kWindow, 100 + i, kFs), "");
  EXPECT_EQ(names(), expected_names(109, 1, 3));
  EXPECT_EQ(store.removed(), 9u);
  EXPECT_LE(store.bytes(), one * 7 / 2);
}

TEST_F(CaptureStoreTest, SelectFiltersTheEvents) {
  const CaptureStore all(config(0, 0, "all")), not_ok(config(0, 0, "not_ok")), alarm(config(0, 0, "alarm"));
  const ImpactEvent good = event(1), low = event(2, ImpactStatus::low_snr), alert = event(3, ImpactStatus::ok, AlarmLevel::alert),
                    danger = event(4, ImpactStatus::ok, AlarmLevel::danger), learning = event(5, ImpactStatus::ok, AlarmLevel::learning);
  EXPECT_TRUE(all.selected(good) && all.selected(low) && all.selected(alert));
  EXPECT_FALSE(not_ok.selected(good));
  EXPECT_TRUE(not_ok.selected(low));
  EXPECT_FALSE(not_ok.selected(alert));
  EXPECT_FALSE(alarm.selected(good) || alarm.selected(low) || alarm.selected(learning));
  EXPECT_TRUE(alarm.selected(alert) && alarm.selected(danger));
}

// Captures of an earlier run count toward the limits; the oldest (by modification time, not by name)
// go first, already when the store opens.
TEST_F(CaptureStoreTest, CapturesOfAnEarlierRunCountAndTheOldestGoFirst) {
  {
    CaptureStore first(config(0, 0));
    for (std::uint64_t i = 0; i < 8; ++i) ASSERT_EQ(first.write(event(900 - 100 * i), "t", kWindow, 0, kFs), "");
  }
  // Written in the order 900, 800, ..., 200: make the modification times say so, a second apart.
  const auto now = fs::file_time_type::clock::now();
  for (std::uint64_t i = 0; i < 8; ++i)
    for (const char* ext : {".wav", ".json"})
      fs::last_write_time(dir_ / "cap" / ("impact-" + std::to_string(900 - 100 * i) + ext),
                          now - std::chrono::seconds(100 - static_cast<int>(i)));
  CaptureStore store(config(10, 0));
  EXPECT_EQ(store.removed(), 3u);  // 16 files, 10 allowed: the 3 oldest captures (900, 800, 700)
  EXPECT_EQ(names(), expected_names(200, 100, 5));
  ASSERT_EQ(store.write(event(5), "t", kWindow, 0, kFs), "");
  EXPECT_EQ(store.removed(), 4u);  // then 600
  EXPECT_FALSE(fs::exists(dir_ / "cap" / "impact-600.wav"));
  EXPECT_TRUE(fs::exists(dir_ / "cap" / "impact-5.wav"));
}

// A full disk: like the event log (tests/test_failure_injection.cpp), a capture that does not fit is
// counted and leaves nothing half-written behind; writing resumes by itself when there is room again.
TEST_F(CaptureStoreTest, FullDiskCountsFailuresLeavesNoHalfCaptureAndResumes) {
  const fs::path mnt = dir_ / "cap";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=64k,mode=0755") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << "); needs root with CAP_SYS_ADMIN";
  mounted_ = mnt;
  CaptureStore store(config(0, 0));
  std::size_t failed = 0;
  for (std::uint64_t i = 0; i < 40; ++i) failed += store.write(event(10 + i), "t", kWindow, 0, kFs).empty() ? 0 : 1;
  // 64 KiB hold ~12 captures of ~5 KB: most of the 40 fail.
  EXPECT_GE(failed, 20u);
  EXPECT_EQ(store.failed(), failed);
  EXPECT_EQ(store.written() + store.failed(), 40u);
  // Every capture on the disk is whole: its WAV reads back with every frame, its sidecar parses.
  std::size_t whole = 0;
  for (const auto& e : fs::directory_iterator(mnt)) {
    if (e.path().extension() != ".wav") continue;
    EXPECT_EQ(wav_frames(e.path()), static_cast<long long>(kWindow.size())) << e.path();
    std::ifstream side(fs::path(e.path()).replace_extension(".json"));
    EXPECT_TRUE(nlohmann::json::accept(side)) << e.path();
    ++whole;
  }
  EXPECT_EQ(whole, store.written());
  EXPECT_EQ(store.files(), 2 * whole);
  EXPECT_EQ(names().size(), 2 * whole) << "a half capture (WAV without JSON or the reverse) stayed behind";
  // Space comes back (the operator deletes the captures): writing resumes.
  for (const auto& e : fs::directory_iterator(mnt)) fs::remove(e.path());
  EXPECT_EQ(store.write(event(1000), "t", kWindow, 0, kFs), "");
  EXPECT_EQ(wav_frames(mnt / "impact-1000.wav"), static_cast<long long>(kWindow.size()));
}

// With max_bytes below the free space the same small disk never fills: every capture is written.
TEST_F(CaptureStoreTest, MaxBytesBelowTheFreeSpaceNeverFillsTheDisk) {
  const fs::path mnt = dir_ / "cap";
  fs::create_directories(mnt);
  if (::mount("tmpfs", mnt.c_str(), "tmpfs", 0, "size=64k,mode=0755") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << "); needs root with CAP_SYS_ADMIN";
  mounted_ = mnt;
  // 32 KB of captures on a 64 KiB tmpfs (tmpfs rounds every file up to 4 KiB pages: ~12 KiB per
  // capture, so ~3 captures of 32 KB use ~36 KiB).
  CaptureStore store(config(0, 32000));
  for (std::uint64_t i = 0; i < 40; ++i) ASSERT_EQ(store.write(event(10 + i), "t", kWindow, 0, kFs), "") << i;
  EXPECT_EQ(store.failed(), 0u);
  EXPECT_EQ(store.written(), 40u);
  EXPECT_LE(store.bytes(), 32000u);
}

TEST(CaptureConfig, NewSectionOldSpellingAndErrors) {
  using ridgewatch::app::parse_config;
  const auto c = parse_config("output:\n  capture:\n    dir: /x\n    max_files: 100\n    max_bytes: 0\n    select: not_ok\n", "t.yaml");
  EXPECT_EQ(c.output.capture.dir, "/x");
  EXPECT_EQ(c.output.capture.max_files, 100u);
  EXPECT_EQ(c.output.capture.max_bytes, 0u);
  EXPECT_EQ(c.output.capture.select, "not_ok");
  // The old spelling still works and keeps the default limits.
  const auto old = parse_config("output:\n  capture_dir: /old\n", "t.yaml");
  EXPECT_EQ(old.output.capture.dir, "/old");
  EXPECT_EQ(old.output.capture.max_files, 1000u);
  // --print-defaults writes the new layout only.
  EXPECT_EQ(ridgewatch::app::to_yaml(old).find("capture_dir"), std::string::npos);
  auto message = [](const std::string& text) {
    try {
      parse_config(text, "t.yaml");
    } catch (const ridgewatch::app::UsageError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("output:\n  capture: {select: everything}\n").find("output.capture.select"), std::string::npos);
  EXPECT_NE(message("output:\n  capture: {max_files: -1}\n").find("output.capture.max_files"), std::string::npos);
  EXPECT_NE(message("output:\n  capture: {dir: /a}\n  capture_dir: /b\n").find("output.capture_dir"), std::string::npos);
  EXPECT_NE(message("output:\n  capture: {size: 1}\n").find("size"), std::string::npos);
}

// Issue 18's acceptance: max_files 100 over a 60 s replay (the 2 s noisy record looped, ~1500 impacts)
// leaves exactly 100 files, the captures of the last 50 events, and the daemon reports how many it
// removed. Also the status line: last zeta, baseline, EWMA z-score.
TEST(CaptureDaemon, MaxFiles100Over60sReplayLeavesExactly100FilesAndCountsTheRemoved) {
  const fs::path dir = fs::temp_directory_path() / ("ridgewatch-capture-daemon-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  {
    std::ofstream cfg(dir / "rw.yaml");
    cfg << "output:\n  events: \"" << (dir / "ev.jsonl").string() << "\"\n  capture:\n    dir: \"" << (dir / "cap").string()
        << "\"\n    max_files: 100\n    max_bytes: 0\nlogging:\n  status_interval_s: 0.05\n";
  }
  const std::string replay = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav";  // 25.6 kHz, 2 s
  ChildProcess d({RIDGEWATCHD_PATH, "--config", (dir / "rw.yaml").string(), "--replay", replay, "--speed", "max", "--loop",
                  "--max-samples", std::to_string(60 * 25600)},
                 {}, (dir / "out").string(), (dir / "err").string());
  ASSERT_EQ(d.wait(120s), 0) << ridgewatch::test::slurp(dir / "err");
  const std::string err = ridgewatch::test::slurp(dir / "err");
  std::vector<nlohmann::json> events;
  {
    std::ifstream f(dir / "ev.jsonl");
    for (std::string line; std::getline(f, line);) events.push_back(nlohmann::json::parse(line));
  }
  ASSERT_GT(events.size(), 1000u) << "a 60 s replay at ~25 impacts/s";
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir / "cap")) files.push_back(e.path().filename().string());
  std::sort(files.begin(), files.end());
  EXPECT_EQ(files.size(), 100u);
  std::vector<std::string> expected;
  for (std::size_t i = events.size() - 50; i < events.size(); ++i)
    for (const char* ext : {".json", ".wav"})
      expected.push_back("impact-" + std::to_string(events[i]["sample_index"].get<std::uint64_t>()) + ext);
  std::sort(expected.begin(), expected.end());
  EXPECT_EQ(files, expected);
  const std::string counts = "captures: " + std::to_string(events.size()) + " written, " +
                             std::to_string(events.size() - 50) + " removed to keep output.capture limits, 0 failed; 100 files";
  EXPECT_NE(err.find(counts), std::string::npos) << counts << "\n" << err.substr(err.size() > 3000 ? err.size() - 3000 : 0);

  // The final status line describes the last event and the trend state of the last event.
  const auto stopped = err.find("stopped: ");
  ASSERT_NE(stopped, std::string::npos) << err;
  const std::string line = err.substr(stopped, err.find('\n', stopped) - stopped);
  const auto& last = events.back();
  char zeta[32];
  std::snprintf(zeta, sizeof zeta, "%.4g", last["zeta"].get<double>());
  EXPECT_NE(line.find(std::string("last zeta ") + zeta + " (" + last["status"].get<std::string>() + ")"), std::string::npos)
      << line;
  std::smatch m;
  ASSERT_TRUE(std::regex_search(line, m, std::regex(R"(baseline zeta ([0-9.e+-]+), EWMA z ([+-][0-9.]+) \(alert 5, danger 9\), )")))
      << line;
  const double baseline = std::stod(m[1].str()), z = std::stod(m[2].str());
  // Independent of the trend code: the learned baseline is the median of the first 256 good events'
  // zeta (median of ln zeta = ln of the median): it lies between their 40th and 60th percentiles.
  std::vector<double> first;
  for (const auto& e : events)
    if (e["status"] == "ok" && first.size() < 256) first.push_back(e["zeta"].get<double>());
  std::sort(first.begin(), first.end());
  EXPECT_GE(baseline, first[first.size() * 2 / 5] * (1 - 5e-4)) << "4 significant digits: 5e-4 relative";
  EXPECT_LE(baseline, first[first.size() * 3 / 5] * (1 + 5e-4));
  // The z-score has the sign of EWMA - baseline in the event, and with alarm normal it is below the
  // alert limit of 5 EWMA standard deviations.
  const double ewma = last["alarm_detail"]["ewma_ln_zeta"].get<double>();
  const double ln_base = std::log(last["alarm_detail"]["baseline_zeta"].get<double>());
  EXPECT_EQ(last["alarm"], "normal");
  if (std::abs(ewma - ln_base) > 1e-3) {
    EXPECT_EQ(z > 0, ewma > ln_base) << line;
  }
  EXPECT_LT(std::abs(z), 5.0) << line;
  fs::remove_all(dir);
}

TEST(RelayTest, AsksFirstThenCyclesEachRelayAndEndsDeEnergised) {
  using ridgewatch::drivers::FakeRelayOutput;
  ridgewatch::daemon::GpioLines lines;
  auto alert = std::make_unique<FakeRelayOutput>("alert line 17");
  auto danger = std::make_unique<FakeRelayOutput>("danger line 18");
  FakeRelayOutput* a = alert.get();
  FakeRelayOutput* dg = danger.get();
  lines.alert = std::move(alert);
  lines.danger = std::move(danger);
  std::istringstream no("no\n");
  std::ostringstream out;
  EXPECT_EQ(ridgewatch::daemon::test_relays(lines, no, out, false, 0ms), 2);
  EXPECT_TRUE(a->history().empty());
  EXPECT_NE(out.str().find("Type yes"), std::string::npos);
  std::istringstream yes("yes\n");
  EXPECT_EQ(ridgewatch::daemon::test_relays(lines, yes, out, false, 0ms), 0);
  EXPECT_EQ(a->history(), (std::vector<bool>{true, false, true, false}));
  EXPECT_EQ(dg->history(), (std::vector<bool>{true, false, true, false}));
  EXPECT_FALSE(a->energised());
  // --yes skips the question; no relay configured is a usage problem.
  std::istringstream none;
  EXPECT_EQ(ridgewatch::daemon::test_relays(lines, none, out, true, 0ms), 0);
  ridgewatch::daemon::GpioLines empty;
  EXPECT_EQ(ridgewatch::daemon::test_relays(empty, none, out, true, 0ms), 2);
  // A relay that cannot be driven (chip lost) is reported, exit 3.
  dg->fail_writes(true);
  std::ostringstream failed;
  EXPECT_EQ(ridgewatch::daemon::test_relays(lines, none, failed, true, 0ms), 3);
  EXPECT_NE(failed.str().find("danger relay danger line 18: energised (healthy) -- WRITE FAILED"), std::string::npos)
      << failed.str();
}
