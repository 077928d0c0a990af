// Bad-input matrix through the real binaries: `ridgewatch analyze` and `ridgewatchd --replay` (plus
// `ridgewatch simulate --rig` for rig files). One test per case; each checks the documented exit code
// (2 usage/configuration, 3 bad data, 0 for valid-but-useless signals) and that the message names the
// source and the problem. Reader-level details (exact message wording, every CSV dialect) are covered
// in test_replay.cpp / test_config.cpp / test_simulate_cli.cpp; this file covers the command paths.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"
#include "drivers/replay_file.hpp"
#include "drivers/sample_source.hpp"
#include "process_runner.hpp"

using ridgewatch::test::ChildProcess;
using ridgewatch::test::CliResult;
using ridgewatch::test::run_cli;
using ridgewatch::test::slurp;
namespace fs = std::filesystem;
using namespace std::chrono_literals;

namespace {

const std::string kData = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/";
const std::string kPaperRig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rw-badinput-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string file(const std::string& name, const std::string& bytes) const {
    const auto p = dir_ / name;
    std::ofstream(p, std::ios::binary) << bytes;
    return p.string();
  }

  /// RIFF/WAVE bytes: 16-bit PCM (format 1) or 32-bit float (format 3), mono unless `channels`.
  static std::string wav_bytes(const std::vector<double>& samples, std::uint32_t rate, bool float32,
                               std::uint16_t channels = 1) {
    std::string data;
    for (double x : samples) {
      if (float32) {
        const auto f = static_cast<float>(x);
        char b[4];
        std::memcpy(b, &f, 4);
        data.append(b, 4);
      } else {
        const double c = std::clamp(std::round(x * 32767.0), -32768.0, 32767.0);
        const auto v = static_cast<std::uint16_t>(static_cast<std::int16_t>(c));
        data += static_cast<char>(v & 0xFF);
        data += static_cast<char>(v >> 8);
      }
    }
    const std::uint16_t bytes_per_sample = float32 ? 4 : 2;
    auto u32 = [](std::uint32_t v) {
      return std::string{static_cast<char>(v & 0xFF), static_cast<char>((v >> 8) & 0xFF),
                         static_cast<char>((v >> 16) & 0xFF), static_cast<char>(v >> 24)};
    };
    auto u16 = [](std::uint16_t v) { return std::string{static_cast<char>(v & 0xFF), static_cast<char>(v >> 8)}; };
    std::string fmt = u16(float32 ? 3 : 1) + u16(channels) + u32(rate) +
                      u32(rate * channels * bytes_per_sample) + u16(static_cast<std::uint16_t>(channels * bytes_per_sample)) +
                      u16(static_cast<std::uint16_t>(8 * bytes_per_sample));
    const auto data_size = static_cast<std::uint32_t>(data.size());
    return "RIFF" + u32(4 + 8 + 16 + 8 + data_size) + "WAVE" + "fmt " + u32(16) + fmt + "data" + u32(data_size) + data;
  }

  std::string wav(const std::string& name, const std::vector<double>& samples, std::uint32_t rate = 25600,
                  bool float32 = true) const {
    return file(name, wav_bytes(samples, rate, float32));
  }

  /// The bundled 2 s simulation (25.6 kHz, 50 impacts of ~0.35 peak).
  static std::vector<double> sim_noise() {
    auto src = ridgewatch::drivers::open_replay(kData + "sim-noise.wav", {});
    return ridgewatch::drivers::read_all(*src);
  }

  struct DaemonRun {
    int exit_code = -1;
    std::string err;
    std::vector<nlohmann::json> events;
  };
  /// ridgewatchd replaying `path` as fast as possible; events to a file (every line must parse).
  DaemonRun daemon(const std::vector<std::string>& extra) const {
    std::vector<std::string> argv = {RIDGEWATCHD_PATH, "--speed", "max", "--events", (dir_ / "ev.jsonl").string()};
    argv.insert(argv.end(), extra.begin(), extra.end());
    fs::remove(dir_ / "ev.jsonl");
    ChildProcess d(argv, {}, (dir_ / "d.out").string(), (dir_ / "d.err").string());
    DaemonRun r;
    const auto code = d.wait(120s);
    r.exit_code = code.value_or(-1);
    r.err = slurp(dir_ / "d.err");
    std::ifstream f(dir_ / "ev.jsonl");
    for (std::string line; std::getline(f, line);) r.events.push_back(nlohmann::json::parse(line));
    return r;
  }

  static std::vector<nlohmann::json> lines(const std::string& out) {
    std::vector<nlohmann::json> v;
    std::istringstream s(out);
    for (std::string line; std::getline(s, line);) v.push_back(nlohmann::json::parse(line));
    return v;
  }

  /// Both paths reject `path` with `code`, naming the file and `problem`; nothing on analyze's stdout.
  /// `extra`: flags for both commands; `daemon_extra` replaces them for ridgewatchd when given.
  /// A problem found while streaming (NaN at sample k) may follow the events completed before it.
  void expect_rejected(const std::string& path, int code, const std::string& problem,
                       const std::vector<std::string>& extra = {},
                       const std::optional<std::vector<std::string>>& daemon_extra = std::nullopt,
                       bool events_before_allowed = false) const {
    std::vector<std::string> a = {"analyze", path};
    a.insert(a.end(), extra.begin(), extra.end());
    const CliResult r = run_cli(a);
    EXPECT_EQ(r.exit_code, code) << r.err;
    EXPECT_NE(r.err.find(path), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(problem), std::string::npos) << r.err;
    if (!events_before_allowed) {
      EXPECT_TRUE(r.out.empty()) << r.out.substr(0, 300);
    }
    for (const auto& e : lines(r.out)) EXPECT_TRUE(e.contains("status"));  // whole JSON lines only
    std::vector<std::string> d = {"--replay", path};
    const auto& dx = daemon_extra ? *daemon_extra : extra;
    d.insert(d.end(), dx.begin(), dx.end());
    const DaemonRun dr = daemon(d);
    EXPECT_EQ(dr.exit_code, code) << dr.err;
    EXPECT_NE(dr.err.find(path), std::string::npos) << dr.err;
    EXPECT_NE(dr.err.find(problem), std::string::npos) << dr.err;
  }

  fs::path dir_;
};

// ---------------------------------------------------------------- audio files: exit 3 on both paths

TEST_F(BadInput, MissingWav) { expect_rejected((dir_ / "absent.wav").string(), 3, "file does not exist"); }

TEST_F(BadInput, EmptyWav) { expect_rejected(file("empty.wav", ""), 3, "empty file (0 bytes)"); }

TEST_F(BadInput, TruncatedWav) {
  std::string bytes = wav_bytes(std::vector<double>(2000, 0.1), 25600, true);
  bytes.resize(bytes.size() - 4000);
  expect_rejected(file("trunc.wav", bytes), 3, "truncated: header declares 2000 frames");
}

TEST_F(BadInput, GarbageWav) {
  std::string bytes;
  for (int i = 0; i < 4096; ++i) bytes += static_cast<char>((i * 7919 + 13) & 0xFF);
  expect_rejected(file("garbage.wav", bytes), 3, "not an audio file");
}

TEST_F(BadInput, WavWithZeroLengthData) { expect_rejected(wav("zero.wav", {}), 3, "empty (0 samples)"); }

// NaN/Inf in the middle: the message names the sample index. The daemon writes the events it completed
// before the bad sample (none lost, none invented) and exits 3.
TEST_F(BadInput, WavWithNaN) {
  auto x = sim_noise();
  x[30000] = std::numeric_limits<double>::quiet_NaN();
  const std::string p = wav("nan.wav", x);
  expect_rejected(p, 3, "sample 30000 is NaN", {}, std::nullopt, true);
  const CliResult r = run_cli({"analyze", p});
  const auto reference = lines(run_cli({"analyze", kData + "sim-noise.wav"}).out);
  const auto got = lines(r.out);
  const DaemonRun d = daemon({"--replay", p});
  // The events before the NaN are the reference's (the same numbers), and nothing after it. Both
  // paths see the same samples (the reader delivers those before the NaN, then fails); the daemon
  // also finishes the impact in progress at the failure (as at any end of input, marked window_cut
  // when the bad sample cut its window), analyze stops at the error.
  ASSERT_GE(got.size(), 20u);
  ASSERT_LT(got.size(), reference.size());
  ASSERT_GE(d.events.size(), got.size());
  ASSERT_LE(d.events.size(), got.size() + 2);
  for (std::size_t i = 0; i < d.events.size(); ++i) {
    EXPECT_LT(d.events[i]["sample_index"].get<std::uint64_t>(), 30000u);
    if (i < got.size()) {
      EXPECT_EQ(d.events[i]["sample_index"], reference[i]["sample_index"]);
      EXPECT_EQ(got[i]["zeta"], reference[i]["zeta"]);
      EXPECT_EQ(d.events[i]["zeta"], reference[i]["zeta"]);
    } else if (d.events[i]["status"] != "window_cut") {  // its window was complete before the NaN
      EXPECT_EQ(d.events[i]["sample_index"], reference[i]["sample_index"]);
      // The same samples, but the end of input may close the window where its decay ended rather
      // than at the next onset: an analyzer of another maximum length (FFT round-off, ~1e-14).
      EXPECT_NEAR(d.events[i]["zeta"].get<double>() / reference[i]["zeta"].get<double>(), 1.0, 1e-9);
    }  // else: an impact at the very end, honestly cut (its onset refined on the samples present)
  }
}

TEST_F(BadInput, WavWithInf) {
  auto x = sim_noise();
  x[1234] = -std::numeric_limits<double>::infinity();
  expect_rejected(wav("inf.wav", x), 3, "sample 1234 is -Inf", {}, std::nullopt, true);
}

TEST_F(BadInput, AbsurdSampleRate) {
  expect_rejected(wav("slow.wav", std::vector<double>(100, 0.0), 10), 3, "sample rate 10 Hz is outside");
  expect_rejected(wav("fast.wav", std::vector<double>(100, 0.0), 50000000), 3, "sample rate 50000000 Hz is outside");
}

TEST_F(BadInput, ChannelOutOfRange) {
  const std::string p = file("stereo.wav", wav_bytes(std::vector<double>(2000, 0.0), 25600, true, 2));
  expect_rejected(p, 3, "channel 2 out of range (file has 2 channels)", {"--channel", "2"});
}

// ---------------------------------------------------------- valid files with a useless signal: exit 0

// A clipping sensor: the impacts flatten at full scale. Every impact is still reported (nothing
// silently dropped), and the ones whose peak hits the rails are flagged `clipped`, never `ok`.
TEST_F(BadInput, ClippedSignalIsFlaggedNotTrusted) {
  auto x = sim_noise();
  double peak = 0.0;
  for (double v : x) peak = std::max(peak, std::abs(v));
  for (double& v : x) v = std::clamp(v * 4.0 / peak, -1.0, 1.0);  // peaks 4x beyond full scale
  const std::string p = wav("clipped.wav", x, 25600, false);     // 16-bit PCM: the rails are +-1
  const CliResult r = run_cli({"analyze", p});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto events = lines(r.out);
  const auto reference = lines(run_cli({"analyze", kData + "sim-noise.wav"}).out);
  ASSERT_EQ(events.size(), reference.size()) << r.err;
  std::size_t clipped = 0;
  for (const auto& e : events) {
    EXPECT_NE(e["status"], "ok") << e.dump();
    clipped += e["status"] == "clipped";
  }
  EXPECT_GE(clipped, events.size() * 9 / 10);
  const DaemonRun d = daemon({"--replay", p});
  ASSERT_EQ(d.exit_code, 0) << d.err;
  ASSERT_EQ(d.events.size(), events.size());
  for (std::size_t i = 0; i < events.size(); ++i) EXPECT_EQ(d.events[i]["status"], events[i]["status"]);
}

// DC only and silence: valid files without impacts give exit 0 and no events (not invented ones).
TEST_F(BadInput, DcOnlyGivesNoEvents) {
  const std::string p = wav("dc.wav", std::vector<double>(51200, 0.5));
  const CliResult r = run_cli({"analyze", p});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
  EXPECT_NE(r.err.find("51200 samples, 0 impacts"), std::string::npos) << r.err;
  const DaemonRun d = daemon({"--replay", p});
  EXPECT_EQ(d.exit_code, 0) << d.err;
  EXPECT_TRUE(d.events.empty());
}

TEST_F(BadInput, SilenceGivesNoEvents) {
  const std::string p = wav("silence.wav", std::vector<double>(51200, 0.0), 25600, false);
  const CliResult r = run_cli({"analyze", p});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
  EXPECT_NE(r.err.find("0 impacts"), std::string::npos) << r.err;
  const DaemonRun d = daemon({"--replay", p});
  EXPECT_EQ(d.exit_code, 0) << d.err;
  EXPECT_TRUE(d.events.empty());
}

// -------------------------------------------------------------------------------------- CSV files

std::string csv_of(const std::vector<double>& x, double rate, char sep, bool decimal_comma) {
  std::ostringstream o;
  o.precision(9);
  o << "time_s" << sep << "velocity\n";
  for (std::size_t i = 0; i < x.size(); ++i) {
    std::ostringstream t, v;
    t.precision(12);
    v.precision(9);
    t << static_cast<double>(i) / rate;
    v << x[i];
    std::string ts = t.str(), vs = v.str();
    if (decimal_comma) {
      std::replace(ts.begin(), ts.end(), '.', ',');
      std::replace(vs.begin(), vs.end(), '.', ',');
    }
    o << ts << sep << vs << "\n";
  }
  return o.str();
}

// Junk after the header (an instrument banner in the middle of the data) names the line.
TEST_F(BadInput, CsvWithHeaderJunkInTheData) {
  std::string text = "Scope XYZ export\nunits: s, m/s\n" + csv_of(std::vector<double>(200, 0.0), 25600, ',', false);
  text.insert(text.find("0.001"), "OVERLOAD,0.5\n");
  expect_rejected(file("junk.csv", text), 3, "is not a number");
  const CliResult r = run_cli({"analyze", (dir_ / "junk.csv").string()});
  EXPECT_NE(r.err.find(": line "), std::string::npos) << r.err;
}

// Decimal comma with ';' separators is read as numbers (same events as the '.' version); with ','
// separators it is ambiguous and rejected (never silently read as time = integer part).
TEST_F(BadInput, CsvDecimalComma) {
  std::vector<double> x = sim_noise();
  x.resize(12800);  // 0.5 s keeps the text small
  const std::string dot = file("dot.csv", csv_of(x, 25600, ',', false));
  const std::string comma = file("comma.csv", csv_of(x, 25600, ';', true));
  const CliResult a = run_cli({"analyze", dot});
  const CliResult b = run_cli({"analyze", comma});
  ASSERT_EQ(a.exit_code, 0) << a.err;
  ASSERT_EQ(b.exit_code, 0) << b.err;
  const auto ea = lines(a.out), eb = lines(b.out);
  ASSERT_GE(ea.size(), 10u);
  ASSERT_EQ(ea.size(), eb.size());
  for (std::size_t i = 0; i < ea.size(); ++i) EXPECT_EQ(ea[i]["zeta"], eb[i]["zeta"]);
  // "0,000039;..." with ',' as the separator: one-column decimal-comma data are ambiguous.
  std::string one_col;
  for (int i = 0; i < 100; ++i) one_col += "0," + std::to_string(100 + i) + "\n";
  const std::string cfg = file("rate.yaml", "source:\n  replay:\n    rate_hz: 25600\n");
  expect_rejected(file("ambiguous.csv", one_col), 3, "time", {"--rate", "25600"}, std::vector<std::string>{"--config", cfg});
}

TEST_F(BadInput, CsvMissingValues) {
  // Line 52 (header + 50 rows) loses its value: "t;" is one field where the file has two.
  std::string text = csv_of(std::vector<double>(200, 0.0), 25600, ';', false);
  std::size_t at = 0;
  for (int i = 0; i < 51; ++i) at = text.find('\n', at) + 1;
  text.replace(text.find(';', at), text.find('\n', at) - text.find(';', at), ";");
  expect_rejected(file("missing.csv", text), 3, "line 52: missing value (expected 2 fields, found 1)");
}

// ------------------------------------------------------------------ configuration files: exit 2

TEST_F(BadInput, ConfigYamlErrorsOnBothCommands) {
  struct Case {
    std::string text, needle;
  };
  const std::vector<Case> cases = {
      {"pipeline:\n  analyzer: [unclosed\n", "not valid YAML"},                              // syntax
      {"pipeline:\n  analyser:\n    eta0: 7\n", "pipeline.analyser: unknown key"},           // unknown key
      {"pipeline:\n  analyzer:\n    window_s: long\n", "pipeline.analyzer.window_s"},       // wrong type
      {"pipeline:\n  trend:\n    ewma_lambda: 7\n", "pipeline.trend.ewma_lambda"},          // out of range
      {"source:\n  ring_buffer_s: -1\n", "source.ring_buffer_s"},                             // out of range
      // Found by fuzz/fuzz_config: a scalar where a section belongs was an internal error (exit 1).
      {"pipeline:\n  analyzer: 5\n", "pipeline.analyzer: must be a mapping"},
      {"pipeline:\n  ? [a, b]\n  : 1\n", "pipeline: keys must be plain names"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.text);
    const std::string cfg = file("bad.yaml", c.text);
    const CliResult r = run_cli({"analyze", kData + "sim-noise.wav", "--config", cfg});
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find("bad.yaml"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.needle), std::string::npos) << r.err;
    EXPECT_TRUE(r.out.empty());
    const DaemonRun d = daemon({"--config", cfg, "--replay", kData + "sim-noise.wav"});
    EXPECT_EQ(d.exit_code, 2) << d.err;
    EXPECT_NE(d.err.find("bad.yaml"), std::string::npos) << d.err;
    EXPECT_NE(d.err.find(c.needle), std::string::npos) << d.err;
    EXPECT_TRUE(d.events.empty());
  }
}

// ---------------------------------------------------------- rig files with impossible physics: exit 2

TEST_F(BadInput, RigYamlWithImpossiblePhysics) {
  const std::string paper = slurp(kPaperRig);
  struct Case {
    std::string from, to, needle;
  };
  const std::vector<Case> cases = {
      {"  damping_ratio: 0.024 ", "  damping_ratio: 1.5 ", "mesh.damping_ratio: must be < 1 (got 1.5)"},
      {"  c0: 8.04e8 ", "  c0: 0.4e8 ", "mesh.harmonics: sum of c must be < mesh.c0"},
      {"  pinion_speed_rpm: 1500 ", "  pinion_speed_rpm: -1500 ", "operation.pinion_speed_rpm"},
      {"  rb2: 0.08466 ", "  rb2: 0 ", "gear.rb2"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.to);
    std::string text = paper;
    const auto at = text.find(c.from);
    ASSERT_NE(at, std::string::npos) << c.from;
    text.replace(at, c.from.size(), c.to);
    const std::string rig = file("rig.yaml", text);
    const CliResult r = run_cli({"simulate", "--rig", rig, "--duration", "0.01", "--out", (dir_ / "x").string()});
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find("rig.yaml: " + c.needle), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "x.wav"));
  }
  // Found by fuzz/fuzz_rig: a key that is not a plain name was an internal error (exit 1).
  std::string text = paper;
  text.replace(text.find("  J1: 0.093 "), 12, "  [J1]: 0.093 ");
  const std::string rig = file("rig.yaml", text);
  const CliResult r = run_cli({"simulate", "--rig", rig, "--duration", "0.01", "--out", (dir_ / "x").string()});
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("rig.yaml: gear: keys must be plain names"), std::string::npos) << r.err;
}

}  // namespace
