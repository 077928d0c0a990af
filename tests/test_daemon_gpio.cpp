// The daemon in-process with fake GPIO lines: fail-safe relays follow the alarm level, the tacho
// pulses give the shaft speed. Input: the bundled damping-step case (zeta 0.024 -> 0.036 at t = 1 s).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "daemon/daemon.hpp"
#include "drivers/gpio_fake.hpp"

using namespace ridgewatch;
namespace fs = std::filesystem;

namespace {

// Forwards to a fake the test keeps, so its history outlives the daemon.
class SharedRelay : public drivers::RelayOutput {
 public:
  explicit SharedRelay(std::shared_ptr<drivers::FakeRelayOutput> fake) : fake_(std::move(fake)) {}
  void set_healthy(bool healthy) override { fake_->set_healthy(healthy); }
  bool healthy() const override { return fake_->healthy(); }
  const std::string& name() const override { return fake_->name(); }
  std::uint64_t errors() const override { return fake_->errors(); }

 private:
  std::shared_ptr<drivers::FakeRelayOutput> fake_;
};

}  // namespace

TEST(DaemonGpio, RelaysDropOutOnTheDampingStepAndTachoGivesShaftSpeed) {
  const auto dir = fs::temp_directory_path() / ("ridgewatchd-gpio-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  app::RidgewatchConfig cfg = app::default_config();
  cfg.source.replay.path = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-damping-step.wav";
  cfg.source.replay.speed = 0.0;
  cfg.output.events = (dir / "ev.jsonl").string();
  cfg.pipeline.trend.baseline_zeta = 0.024;  // configured baseline: 2 s of data is too short to learn one
  cfg.pipeline.trend.baseline_ln_sd = 0.03;

  auto alert = std::make_shared<drivers::FakeRelayOutput>("alert");
  auto danger = std::make_shared<drivers::FakeRelayOutput>("danger");
  auto tacho = std::make_shared<drivers::FakeTachoInput>("tacho");
  // 1500 rpm: a pulse every 40 ms (kernel timestamps in ns).
  for (int i = 0; i < 5; ++i) tacho->inject({1'000'000'000LL + i * 40'000'000LL, true});

  daemon::DaemonOptions options;
  options.config = cfg;
  options.gpio_factory = [&](const app::GpioConfig&) {
    daemon::GpioLines lines;
    lines.alert = std::make_unique<SharedRelay>(alert);
    lines.danger = std::make_unique<SharedRelay>(danger);
    lines.tacho = std::make_unique<drivers::SharedTachoInput>(tacho);
    return lines;
  };
  daemon::Daemon::clear_requests();
  daemon::Daemon d(std::move(options));
  ASSERT_EQ(d.run(), 0);

  // Events: find the first alarm and check it comes after the step at 1 s.
  std::ifstream f(dir / "ev.jsonl");
  std::string line;
  double first_alarm_t = -1;
  std::size_t n = 0;
  while (std::getline(f, line)) {
    const auto j = nlohmann::json::parse(line);
    ++n;
    if (first_alarm_t < 0 && (j["alarm"] == "alert" || j["alarm"] == "danger")) first_alarm_t = j["t_s"].get<double>();
  }
  ASSERT_EQ(n, 50u);
  ASSERT_GT(first_alarm_t, 1.0) << "alarm before the step";
  EXPECT_LT(first_alarm_t, 1.0 + 10 * 0.04 + 0.01) << "alarm later than 10 impacts after the step";

  // Alert relay: energised (healthy) at start, de-energised once the alarm is raised.
  const auto h = alert->history();
  ASSERT_FALSE(h.empty());
  EXPECT_TRUE(h.front());
  EXPECT_FALSE(h.back());
  EXPECT_EQ(std::count(h.begin(), h.end(), false) > 0, true);
  EXPECT_TRUE(danger->history().front());
  // Tacho: 5 pulses 40 ms apart -> 25 Hz shaft.
  EXPECT_EQ(d.stats().tacho_pulses, 5u);
  EXPECT_NEAR(d.stats().shaft_hz, 25.0, 1e-9);
  fs::remove_all(dir);
}
