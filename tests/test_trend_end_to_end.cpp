// End to end: the trend alarms of issue 4 through the real tools. `ridgewatch simulate` makes a
// paper-rig recording (25 Hz shaft: one impact every 40 ms, 51.2 kHz, noise 1 % of the clean peak)
// whose damping steps or drifts (effect damping_drift); `ridgewatch analyze` runs the streaming
// pipeline with its default configuration and prints JSON Lines; the test reads the `alarm` field.
// Impacts are counted from the simulator's truth file, so a missed detection cannot shorten the delay.
// Runtime: ~4 s optimised, ~2 min under ASan+UBSan (about 2 minutes of simulated signal in all).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"

namespace ridgewatch {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using test::run_cli;

constexpr double kZeta0 = 0.024;  // damping_ratio of config/rigs/paper-rig.yaml

class TrendEndToEnd : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("rw_trend_e2e_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  /// Simulates the paper rig; returns the truth JSON. The WAV is dir_/name.wav.
  json simulate(const std::string& name, const std::string& effect, double duration_s, double noise, int seed) {
    const fs::path base = dir_ / name;
    const auto r = run_cli({"simulate", "--rig", std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml",
                            "--effect", effect, "--duration", std::to_string(duration_s), "--noise",
                            std::to_string(noise), "--seed", std::to_string(seed), "--out", base.string()});
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return json::parse(test::slurp(base.string() + ".truth.json"));
  }

  /// Runs analyze on dir_/name.wav with the default configuration; one JSON object per event.
  std::vector<json> analyze(const std::string& name) {
    const auto r = run_cli({"analyze", (dir_ / (name + ".wav")).string()});
    EXPECT_EQ(r.exit_code, 0) << r.err;
    std::vector<json> events;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) events.push_back(json::parse(line));
    return events;
  }

  fs::path dir_;
};

bool alarming(const json& event) {
  const std::string a = event.at("alarm").get<std::string>();
  return a == "alert" || a == "danger";
}

/// Impacts of the truth file with t_from <= t_s <= t_to.
int impacts_between(const json& truth, double t_from, double t_to) {
  int n = 0;
  for (const auto& imp : truth.at("impacts")) {
    const double t = imp.at("t_s").get<double>();
    n += t >= t_from && t <= t_to ? 1 : 0;
  }
  return n;
}

// Damping step +25 % (0.024 -> 0.030) at 12.004 s, 2.4 ms before an impact (impacts at 0.0064 + 0.04 n s),
// so no decay window straddles it. The default baseline learns from the first 256 good events
// (10.2 s), leaving ~45 monitored impacts before the step.
TEST_F(TrendEndToEnd, DampingStepAlarmsWithinTenImpactsAndNotBefore) {
  constexpr double kStepTime = 12.004;
  const std::string effect = "damping_drift:rate_per_s=0,step=" + std::to_string(0.25 * kZeta0) +
                             ",step_time_s=" + std::to_string(kStepTime);
  struct Case {
    double noise;
    int seed;
  };
  for (const Case c : {Case{0.01, 1}, Case{0.01, 2}, Case{0.05, 3}}) {
    SCOPED_TRACE("noise " + std::to_string(c.noise) + " seed " + std::to_string(c.seed));
    const std::string name = "step" + std::to_string(c.seed);
    const json truth = simulate(name, effect, 16.0, c.noise, c.seed);
    const std::vector<json> events = analyze(name);
    ASSERT_GE(events.size(), 390u);  // 400 impacts in 16 s

    int monitored_before = 0;
    double alarm_t = -1.0;
    for (const json& e : events) {
      const double t = e.at("t_s").get<double>();
      if (t < kStepTime) {
        EXPECT_FALSE(alarming(e)) << "alarm before the step at t = " << t;
        monitored_before += e.at("alarm") == "normal" ? 1 : 0;
      } else if (alarm_t < 0.0 && alarming(e)) {
        alarm_t = t;
      }
    }
    EXPECT_GE(monitored_before, 30);  // the baseline was learned well before the step
    ASSERT_GT(alarm_t, 0.0) << "no alarm after the step";
    // +2 ms: an event's onset may sit slightly after the simulator's impact time.
    const int delay = impacts_between(truth, kStepTime, alarm_t + 0.002);
    EXPECT_GE(delay, 1);
    EXPECT_LE(delay, 10);
    std::printf("[trend e2e] +25%% step, noise %.2f seed %d: alarm at impact %d after the step (t = %.3f s)\n",
                c.noise, c.seed, delay, alarm_t);
  }
}

// Slow drift from t = 0: zeta(t) = 0.024 + rate t, +30 % after 60 s (1500 impacts; 0.2 % per 10
// impacts). The baseline is learned while the damping already drifts (the first 10 s: up to +5 %), as it
// would be on a rig; the rise is reported from the start of the recording.
TEST_F(TrendEndToEnd, SlowDriftAlarmsBeforeThirtyPercent) {
  constexpr double kDuration = 60.0;
  const double rate = 0.30 * kZeta0 / kDuration;
  simulate("drift", "damping_drift:rate_per_s=" + std::to_string(rate), kDuration, 0.01, 5);
  const std::vector<json> events = analyze("drift");
  ASSERT_GE(events.size(), 1450u);
  double alarm_t = -1.0;
  for (const json& e : events) {
    if (alarming(e)) {
      alarm_t = e.at("t_s").get<double>();
      break;
    }
  }
  ASSERT_GT(alarm_t, 0.0) << "no alarm during a +30 % drift";
  const double rise = rate * alarm_t / kZeta0;
  EXPECT_LT(rise, 0.30);
  std::printf("[trend e2e] drift +30%% over 60 s, noise 0.01: alarm at t = %.2f s, zeta risen %.1f %%\n", alarm_t,
              100.0 * rise);
}

// Stationary damping, 40 s (1000 impacts, ~740 monitored after the baseline): never an alarm.
TEST_F(TrendEndToEnd, StationaryRecordingNeverAlarms) {
  simulate("steady", "damping_drift:rate_per_s=0", 40.0, 0.01, 6);
  const std::vector<json> events = analyze("steady");
  ASSERT_GE(events.size(), 990u);
  int monitored = 0;
  for (const json& e : events) {
    EXPECT_FALSE(alarming(e)) << "false alarm at t = " << e.at("t_s");
    monitored += e.at("alarm") == "normal" ? 1 : 0;
  }
  EXPECT_GE(monitored, 700);
}

}  // namespace
}  // namespace ridgewatch
