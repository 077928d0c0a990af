// ridgewatchd with several streams (`streams:`): every stream's events equal the single-channel
// `ridgewatch analyze --channel N` of its channel (16 independent rigs in one file), whatever the
// worker count; each stream's trend, alarm and relays are its own; configuration errors are exit 2
// naming the key (through the real binary and --check-config).
//
// Truth: the recordings come from tests/support/indep_signals.hpp (no code shared with core/model),
// and the reference events from the single-channel analyze, whose pipeline is tested elsewhere; here
// only that each stream sees exactly its channel's samples and its own settings and trend.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <thread>
#include <string>
#include <vector>

#include "app/config_yaml.hpp"
#include "cli_runner.hpp"
#include "scratch_dir_test.hpp"
#include "daemon/daemon.hpp"
#include "daemon/streams_daemon.hpp"
#include "daemon/worker_pool.hpp"
#include "drivers/gpio_fake.hpp"
#include "process_runner.hpp"
// GCC 12 -O2 reports a false -Wstringop-overflow inside indep::write_wav's header bytes (vector insert
// of a 4-byte tag), as in test_modes_cli.cpp.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wstringop-overflow"
#include "support/indep_signals.hpp"
#pragma GCC diagnostic pop

namespace ridgewatch::test {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

class DaemonStreams : public ScratchDirTest {
 protected:
  DaemonStreams() : ScratchDirTest("rw-dstreams") {}
  // Runs ridgewatchd to the end of its input; returns the exit code (stderr in err_).
  int daemon(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {RIDGEWATCHD_PATH};
    argv.insert(argv.end(), args.begin(), args.end());
    ChildProcess d(argv, {}, (dir_ / "out").string(), (dir_ / "err").string());
    const std::optional<int> code = d.wait(120s);
    err_ = slurp(dir_ / "err");
    return code.value_or(-1);
  }
  std::string err_;
};

std::vector<nlohmann::json> jsonl(const std::string& text) {
  std::vector<nlohmann::json> v;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) v.push_back(nlohmann::json::parse(line));
  return v;
}

// Each stream's events, in file order, with the stream field removed (to compare with analyze).
std::map<std::string, std::vector<nlohmann::json>> by_stream(const std::vector<nlohmann::json>& events) {
  std::map<std::string, std::vector<nlohmann::json>> m;
  for (auto e : events) {
    const std::string s = e.at("stream");
    e.erase("stream");
    m[s].push_back(e);
  }
  return m;
}

// `channels` independent rigs (impact rate, ζ, noise seed differ per channel) as one 24-bit WAV.
std::string write_rigs(const fs::path& path, std::size_t channels, double duration_s) {
  const double fs = 25600.0;
  const auto n = static_cast<std::size_t>(duration_s * fs);
  std::vector<double> frames(channels * n, 0.0);
  for (std::size_t ch = 0; ch < channels; ++ch) {
    indep::RigSpec s;
    s.fs_hz = fs;
    s.duration_s = duration_s;
    s.rev_hz = 20.0 + static_cast<double>(ch);
    s.response = {.f_hz = 840.0 + 2.0 * static_cast<double>(ch), .zeta = 0.01 + 0.002 * static_cast<double>(ch), .amplitude = 0.3};
    s.noise_sd = 0.001;
    s.seed = 300 + ch;
    const auto rec = indep::make_rig_record(s);
    for (std::size_t i = 0; i < n; ++i) frames[channels * i + ch] = rec.x[i];
  }
  indep::write_wav(path.string(), frames, fs, static_cast<int>(channels), indep::SampleFormat::pcm24);
  return path.string();
}

std::string streams_yaml(std::size_t channels, std::size_t workers) {
  std::string y = "workers: " + std::to_string(workers) + "\nstreams:\n";
  for (std::size_t ch = 0; ch < channels; ++ch)
    y += "  - name: ch" + std::to_string(ch) + "\n    channel: " + std::to_string(ch) + "\n";
  return y;
}

// The acceptance case: 16 independent rigs in one file, one stream per channel; every stream's
// events are the single-channel analyze's (same count, same values, bit for bit: the same float
// samples go through the same pipeline), on 2 workers and on 1.
TEST_F(DaemonStreams, SixteenChannelsEqualAnalyzePerChannel) {
#ifdef RIDGEWATCH_SANITIZED
  constexpr std::size_t kChannels = 4;  // the sanitizer pass: a representative subset
#else
  constexpr std::size_t kChannels = 16;
#endif
  const std::string wav = write_rigs(dir_ / "multi.wav", kChannels, 1.0);
  std::map<std::string, std::vector<nlohmann::json>> first;
  for (const std::size_t workers : {2u, 1u}) {
    const std::string cfg = write("w" + std::to_string(workers) + ".yaml", streams_yaml(kChannels, workers));
    const std::string events = (dir_ / ("ev" + std::to_string(workers) + ".jsonl")).string();
    ASSERT_EQ(daemon({"--config", cfg, "--replay", wav, "--speed", "max", "--events", events}), 0) << err_;
    const auto streams = by_stream(jsonl(slurp(events)));
    ASSERT_EQ(streams.size(), kChannels) << err_;
    if (workers == 2) {
      first = streams;
      continue;
    }
    EXPECT_EQ(streams, first) << "1 worker and 2 workers differ";
  }
  std::size_t total = 0;
  for (std::size_t ch = 0; ch < kChannels; ++ch) {
    const CliResult one = run_cli({"analyze", wav, "--channel", std::to_string(ch)});
    ASSERT_EQ(one.exit_code, 0) << one.err;
    const auto single = jsonl(one.out);
    const auto& mine = first["ch" + std::to_string(ch)];
    ASSERT_GE(single.size(), 15u) << "channel " << ch;  // 20-35 impacts per second
    ASSERT_EQ(mine.size(), single.size()) << "channel " << ch;
    for (std::size_t i = 0; i < single.size(); ++i) EXPECT_EQ(mine[i], single[i]) << "channel " << ch << " event " << i;
    total += single.size();
  }
  EXPECT_GT(total, kChannels * 15);
}

// Three rigs: a and c steady, b with a damping step (+50 %) half way. Each stream has its own
// trend (configured baseline: 2 s are too short to learn one) and relays; c has its own pipeline
// (a mode at 1200 Hz: its own f_expected_hz and detector band). Only b's alarm and b's relay go,
// and the top-level relay (the worst of all streams) with it. The top-level tacho gives the shaft speed.
TEST_F(DaemonStreams, DampingStepRaisesOnlyThatStreamsAlarm) {
  const double fs = 25600.0, duration = 2.4, step_s = 1.2;
  const auto n = static_cast<std::size_t>(duration * fs);
  std::vector<double> frames(3 * n, 0.0);
  indep::Rng rng(77);
  for (std::size_t ch = 0; ch < 3; ++ch) {
    std::vector<double> x(n, 0.0);
    const double f = ch == 2 ? 1200.0 : 860.0;
    // 20 impacts/s; ζ = 0.02 decays 40 dB in 43 ms (860 Hz), within the 50 ms between impacts.
    for (double t = 0.013 + 0.003 * static_cast<double>(ch); t < duration; t += 0.05) {
      indep::Mode m{.f_hz = f, .zeta = 0.02, .amplitude = 0.3 * rng.uniform(0.9, 1.1), .phase_rad = 0.0};
      if (ch == 1 && t > step_s) m.zeta = 0.03;
      indep::add_decay(x, fs, t, m);
    }
    for (std::size_t i = 0; i < n; ++i) frames[3 * i + ch] = x[i] + 0.001 * rng.gauss();
  }
  const std::string wav = (dir_ / "three.wav").string();
  indep::write_wav(wav, frames, fs, 3, indep::SampleFormat::pcm24);
  const std::string events = (dir_ / "ev.jsonl").string(), csv = (dir_ / "ev.csv").string();
  const std::string yaml = "source: {replay: {path: " + wav + ", speed: 0}}\n"
                           "output: {events: " + events + ", csv: " + csv + "}\n"
                           "gpio: {enabled: true, alert_line: 1, tacho_line: 2}\n"
                           "pipeline:\n  analyzer: {f_expected_hz: 860}\n  detector: {band_lo_hz: 730, band_hi_hz: 990}\n"
                           "  trend: {baseline_zeta: 0.02, baseline_ln_sd: 0.05}\n"
                           "streams:\n"
                           "  - {name: a, channel: 0, gpio: {alert_line: 10}}\n"
                           "  - {name: b, channel: 1, gpio: {alert_line: 11}}\n"
                           "  - name: c\n    channel: 2\n    gpio: {alert_line: 12}\n"
                           "    pipeline: {analyzer: {f_expected_hz: 1200}, detector: {band_lo_hz: 1050, band_hi_hz: 1350}}\n";
  daemon::DaemonOptions options;
  options.config = app::parse_config(yaml, (dir_ / "c.yaml").string());
  ASSERT_EQ(options.config.streams.size(), 3u);
  std::map<int, std::shared_ptr<drivers::FakeRelayOutput>> relays;  // by line
  auto tacho = std::make_shared<drivers::FakeTachoInput>("tacho");
  // One shaft for all streams, 1500 rpm: a pulse every 40 ms (kernel timestamps in ns).
  for (int i = 0; i < 5; ++i) tacho->inject({1'000'000'000LL + i * 40'000'000LL, true});
  std::size_t tacho_lines = 0;
  options.gpio_factory = [&](const app::GpioConfig& g) {
    daemon::GpioLines lines;
    auto fake = std::make_shared<drivers::FakeRelayOutput>("line" + std::to_string(g.alert_line));
    relays[g.alert_line] = fake;
    struct Shared : drivers::RelayOutput {
      std::shared_ptr<drivers::FakeRelayOutput> f;
      explicit Shared(std::shared_ptr<drivers::FakeRelayOutput> x) : f(std::move(x)) {}
      void set_healthy(bool h) override { f->set_healthy(h); }
      bool healthy() const override { return f->healthy(); }
      const std::string& name() const override { return f->name(); }
      std::uint64_t errors() const override { return f->errors(); }
    };
    lines.alert = std::make_unique<Shared>(fake);
    if (g.tacho_line >= 0) {  // the top-level lines only: the streams' own carry relays
      ++tacho_lines;
      lines.tacho = std::make_unique<drivers::SharedTachoInput>(tacho);
    }
    return lines;
  };
  daemon::Daemon::clear_requests();
  daemon::Daemon d(std::move(options));
  ASSERT_EQ(d.run(), 0);

  const auto streams = by_stream(jsonl(slurp(events)));
  ASSERT_EQ(streams.size(), 3u);
  for (const auto& [name, ev] : streams) {
    ASSERT_GE(ev.size(), 45u) << name;  // 20 impacts/s for 2.4 s
    std::size_t ok = 0;
    bool alarmed = false, alarmed_before_step = false;
    for (const auto& e : ev) {
      ok += e["status"] == "ok";
      const bool a = e["alarm"] == "alert" || e["alarm"] == "danger";
      alarmed |= a;
      alarmed_before_step |= a && e["t_s"].get<double>() < step_s;
      if (name == "c" && e["status"] == "ok") {
        EXPECT_NEAR(e["f_hz"].get<double>(), 1200.0, 2.0);  // its own band and f_expected_hz
      }
    }
    EXPECT_GE(ok, ev.size() / 2) << name;
    EXPECT_FALSE(alarmed_before_step) << name;
    EXPECT_EQ(alarmed, name == "b") << name;
  }
  // Relays: energised at start (healthy); only b's and the top-level one dropped out.
  ASSERT_EQ(relays.size(), 4u);
  for (const auto& [line, relay] : relays) {
    const auto& h = relay->history();
    ASSERT_FALSE(h.empty()) << line;
    EXPECT_TRUE(h.front()) << line;
    const bool dropped = std::find(h.begin(), h.end(), false) != h.end();
    EXPECT_EQ(dropped, line == 11 || line == 1) << "line " << line;
  }
  // Tacho (the top-level line, opened once): 5 pulses 40 ms apart -> 25 Hz shaft.
  EXPECT_EQ(tacho_lines, 1u);
  EXPECT_EQ(d.stats().tacho_pulses, 5u);
  EXPECT_NEAR(d.stats().shaft_hz, 25.0, 1e-9);
  // The CSV: one file, a stream column.
  const std::string text = slurp(csv);
  EXPECT_EQ(text.rfind("t_s,sample_index,source,stream,f_hz", 0), 0u) << text.substr(0, 80);
  EXPECT_NE(text.find(",\"b\","), std::string::npos);
}

// Configuration errors: exit 2 and a message naming the key, through --check-config and at start.
TEST_F(DaemonStreams, ConfigurationErrorsAreExit2NamingTheKey) {
  const std::string wav = write_rigs(dir_ / "two.wav", 2, 0.2);
  struct Case {
    std::string yaml, key;
  };
  const std::string replay = "source: {replay: {path: " + wav + "}}\n";
  const std::vector<Case> cases = {
      {replay + "streams:\n  - {name: a, channel: 0}\n  - {name: b, channel: 5}\n", "streams[1].channel: channel 5 out of range"},
      {"source: {type: alsa, alsa: {channels: 4}}\nstreams:\n  - {name: a, channel: 4}\n", "streams[0].channel"},
      {replay + "streams:\n  - {name: a, channel: 0}\n  - {name: a, channel: 1}\n", "streams[1].name: 'a' is also the name of streams[0]"},
      {replay + "streams:\n  - {name: a, channel: 0, rig: no-such-rig.yaml}\n", "streams[0].rig"},
      {replay + "workers: -1\nstreams:\n  - {name: a, channel: 0}\n", "workers: must be a whole number in [0, 256]"},
      {replay + "workers: 1.5\nstreams:\n  - {name: a, channel: 0}\n", "workers"},
      {replay + "workers: 1000\nstreams:\n  - {name: a, channel: 0}\n", "workers"},
      {replay + "streams:\n  - {channel: 0}\n", "streams[0].name: missing"},
      {replay + "streams:\n  - {name: 'a b', channel: 0}\n", "streams[0].name"},
      {replay + "streams:\n  - {name: a, channel: 0, colour: red}\n", "streams[0].colour: unknown key"},
      {replay + "streams:\n  - {name: a, channel: 0, combine: {type: coefficients, channels: [0, 1], coefficients: [1, 1]}}\n",
       "streams[0].channel: give either channel or combine"},
      {replay + "streams:\n  - {name: a, combine: {type: coefficients, channels: [0, 3], coefficients: [1, 1]}}\n",
       "streams[0].combine.channels[1]"},
      {replay + "streams:\n  - {name: a, pipeline: {analyzer: {window_s: 0}}}\n", "streams[0]: pipeline.analyzer.window_s"},
      {replay + "streams:\n  - {name: a, gpio: {alert_line: 3}}\n", "streams[0].gpio"},
      {replay + "gpio: {enabled: true}\nstreams:\n  - {name: a, gpio: {alert_line: 3}}\n  - {name: b, gpio: {danger_line: 3}}\n",
       "streams[1].gpio.danger_line: line 3 is already streams[0].gpio.alert_line"},
  };
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const std::string cfg = write("c" + std::to_string(i) + ".yaml", cases[i].yaml);
    const CliResult r = [&] {
      CliResult c;
      c.exit_code = daemon({"--check-config", cfg});
      c.err = err_;
      return c;
    }();
    EXPECT_EQ(r.exit_code, 2) << cases[i].yaml << r.err;
    EXPECT_NE(r.err.find(cases[i].key), std::string::npos) << "expected '" << cases[i].key << "' in: " << r.err;
    EXPECT_NE(r.err.find(cfg), std::string::npos) << r.err;  // names the file
  }
  // At start: the channel the file lacks, found when the file opens (exit 2, not 3).
  const std::string cfg = write("start.yaml", "streams:\n  - {name: a, channel: 0}\n  - {name: b, channel: 2}\n");
  EXPECT_EQ(daemon({"--config", cfg, "--replay", wav, "--speed", "max", "--events", (dir_ / "e.jsonl").string()}), 2);
  EXPECT_NE(err_.find("streams[1].channel: channel 2 out of range (the source has 2 channels, 0-1)"), std::string::npos) << err_;
  EXPECT_EQ(daemon({"--config", cfg, "--replay", wav, "--channel", "1"}), 2);
  EXPECT_NE(err_.find("--channel"), std::string::npos) << err_;
}

// Log rotation with streams: after the event log is renamed away, SIGHUP makes the daemon write to a
// new file at the configured path; together the two files hold every stream's events exactly once
// (the single-channel analyze's, in order). The configuration itself is not re-applied (logged).
TEST_F(DaemonStreams, SighupReopensTheEventLog) {
  const std::string wav = write_rigs(dir_ / "two.wav", 2, 2.0);
  const std::string cfg = write("s.yaml", streams_yaml(2, 2));
  const fs::path log = dir_ / "ev.jsonl", rotated = dir_ / "ev.jsonl.1";
  ChildProcess d({RIDGEWATCHD_PATH, "--config", cfg, "--replay", wav, "--speed", "2", "--events", log.string()}, {},
                 (dir_ / "out").string(), (dir_ / "err").string());
  // Start-up can take several hundred ms on a loaded machine: wait for the log to exist first.
  for (int i = 0; i < 500 && !fs::exists(log); ++i) std::this_thread::sleep_for(10ms);
  std::this_thread::sleep_for(300ms);
  fs::rename(log, rotated);
  d.signal(SIGHUP);
  ASSERT_EQ(d.wait(30s), 0) << slurp(dir_ / "err");
  const std::string err = slurp(dir_ / "err");
  EXPECT_NE(err.find("SIGHUP: reopening the output files"), std::string::npos) << err;
  auto old_part = by_stream(jsonl(slurp(rotated.string())));
  const auto new_part = by_stream(jsonl(slurp(log.string())));
  EXPECT_FALSE(old_part.empty());
  EXPECT_FALSE(new_part.empty());
  for (std::size_t ch = 0; ch < 2; ++ch) {
    const std::string name = "ch" + std::to_string(ch);
    auto all = old_part[name];
    if (const auto it = new_part.find(name); it != new_part.end()) all.insert(all.end(), it->second.begin(), it->second.end());
    const CliResult one = run_cli({"analyze", wav, "--channel", std::to_string(ch)});
    ASSERT_EQ(one.exit_code, 0) << one.err;
    const auto single = jsonl(one.out);
    ASSERT_EQ(all.size(), single.size()) << name;
    for (std::size_t i = 0; i < single.size(); ++i) EXPECT_EQ(all[i]["sample_index"], single[i]["sample_index"]) << name << " " << i;
  }
}

TEST(WorkerPool, RunsEveryTaskOnceOnItsThreadAndRethrows) {
  for (const std::size_t threads : {1u, 2u, 3u}) {
    daemon::WorkerPool pool(threads);
    std::vector<int> counts(10, 0);
    std::vector<std::thread::id> ids(10);
    for (int round = 0; round < 50; ++round)
      pool.run(counts.size(), [&](std::size_t i) {
        ++counts[i];  // no lock: each task index belongs to one thread (TSan checks this)
        if (round == 0) ids[i] = std::this_thread::get_id();
        EXPECT_EQ(ids[i], std::this_thread::get_id()) << "task " << i << " moved thread";
      });
    for (int c : counts) EXPECT_EQ(c, 50);
    EXPECT_EQ(ids[0], std::this_thread::get_id());  // task 0 on the caller
    EXPECT_THROW(pool.run(5, [](std::size_t i) { if (i == 3) throw std::runtime_error("x"); }), std::runtime_error);
    pool.run(1, [](std::size_t) {});  // still usable after an exception
  }
  EXPECT_EQ(daemon::worker_count(3, 16), 3u);
  EXPECT_GE(daemon::worker_count(0, 16), 1u);
  EXPECT_EQ(daemon::worker_count(0, 1), 1u);
}

}  // namespace
}  // namespace ridgewatch::test
