// GPIO: the libgpiod driver's error paths (this machine has no gpiochip), the timestamp-to-sample
// conversion, and the fake lines the daemon tests use.
#include "drivers/gpio.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "drivers/gpio_fake.hpp"

namespace rd = ridgewatch::drivers;
using namespace std::chrono_literals;

namespace {

template <typename F>
void expect_gpio_error(F&& make, const std::string& needle) {
  try {
    make();
    ADD_FAILURE() << "expected GpioError containing: " << needle;
  } catch (const rd::GpioError& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(Gpio, MissingChipIsAClearError) {
  const rd::GpioLineConfig missing{.chip = "ridgewatch-no-such-chip", .offset = 3};
  expect_gpio_error([&] { rd::GpiodTachoInput tacho(missing, rd::TachoEdges::rising); },
                    "gpio ridgewatch-no-such-chip: cannot open chip");
  expect_gpio_error([&] { rd::GpiodRelayOutput relay(missing); }, "gpio ridgewatch-no-such-chip: cannot open chip");
  const rd::GpioLineConfig missing_path{.chip = "/dev/gpiochip97", .offset = 0};
  expect_gpio_error([&] { rd::GpiodRelayOutput relay(missing_path); }, "gpio /dev/gpiochip97: cannot open chip");
}

TEST(Gpio, NonGpioDeviceAndEmptyNameAreClearErrors) {
  expect_gpio_error([] { rd::GpiodRelayOutput relay({.chip = "/dev/null", .offset = 0}); },
                    "gpio /dev/null: cannot open chip");
  expect_gpio_error([] { rd::GpiodTachoInput tacho({.chip = "", .offset = 0}, rd::TachoEdges::both); },
                    "chip name is empty");
}

TEST(Gpio, LineOffsetOutOfRangeIsAClearError) {
  if (!std::filesystem::exists("/dev/gpiochip0"))
    GTEST_SKIP() << "no /dev/gpiochip0 on this machine: the bad-offset path needs a real chip";
  expect_gpio_error([] { rd::GpiodRelayOutput relay({.chip = "gpiochip0", .offset = 100000}); },
                    "gpio gpiochip0 line 100000: no such line");
}

TEST(Gpio, TimestampToSampleIndex) {
  // Anchor: sample 51200 taken at t = 10 s. At 51.2 kHz one sample is 19.53 us.
  const std::int64_t anchor_ns = 10'000'000'000;
  EXPECT_EQ(rd::timestamp_to_sample_index(anchor_ns, anchor_ns, 51200, 51200.0), 51200u);
  EXPECT_EQ(rd::timestamp_to_sample_index(anchor_ns + 1'000'000'000, anchor_ns, 51200, 51200.0), 102400u);
  EXPECT_EQ(rd::timestamp_to_sample_index(anchor_ns - 500'000'000, anchor_ns, 51200, 51200.0), 25600u);
  // 29 us after the anchor = 1.48 samples -> 1 (nearest); 30 us = 1.536 -> 2.
  EXPECT_EQ(rd::timestamp_to_sample_index(anchor_ns + 29'000, anchor_ns, 0, 51200.0), 1u);
  EXPECT_EQ(rd::timestamp_to_sample_index(anchor_ns + 30'000, anchor_ns, 0, 51200.0), 2u);
  EXPECT_EQ(rd::timestamp_to_sample_index(0, anchor_ns, 100, 51200.0), 0u) << "before the stream clamps to 0";
}

TEST(GpioFake, TachoEdgesInjectedFromAnotherThreadArrive) {
  rd::FakeTachoInput tacho;
  std::thread injector([&] {
    std::this_thread::sleep_for(5ms);
    tacho.inject({.timestamp_ns = 1000, .rising = true});
    tacho.inject({.timestamp_ns = 2000, .rising = false});
  });
  std::vector<rd::TachoEdge> edges;
  // 10 s is only an upper bound for a hung test; the edges arrive after ~5 ms.
  while (edges.size() < 2) tacho.wait_edges(10s, edges);
  injector.join();
  ASSERT_EQ(edges.size(), 2u);
  EXPECT_EQ(edges[0].timestamp_ns, 1000);
  EXPECT_TRUE(edges[0].rising);
  EXPECT_EQ(edges[1].timestamp_ns, 2000);
  EXPECT_FALSE(edges[1].rising);
}

TEST(GpioFake, TachoTimeoutAndErrors) {
  rd::FakeTachoInput tacho("tacho A");
  std::vector<rd::TachoEdge> edges;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(tacho.wait_edges(20ms, edges), 0u);
  // A 20 ms timeout must wait at least about that long (condition variables do not return early
  // without a notification, spurious wake-ups are re-checked by the predicate).
  EXPECT_GE(std::chrono::steady_clock::now() - t0, 15ms);
  tacho.inject_error();
  EXPECT_EQ(tacho.wait_edges(1s, edges), 0u);
  EXPECT_EQ(tacho.errors(), 1u);
  EXPECT_EQ(tacho.name(), "tacho A");
}

TEST(GpioFake, RelayRecordsFailSafeValues) {
  rd::FakeRelayOutput alert("alert");
  EXPECT_FALSE(alert.energised()) << "starts in the alarm (de-energised) state";
  alert.set_healthy(true);
  alert.set_healthy(false);
  alert.set_healthy(true);
  EXPECT_TRUE(alert.energised());
  EXPECT_EQ(alert.history(), (std::vector<bool>{true, false, true}));
  alert.fail_writes(true);
  alert.set_healthy(false);
  EXPECT_EQ(alert.errors(), 1u);
  EXPECT_TRUE(alert.healthy()) << "a failed write leaves the recorded value";
  // Through the interface, as the daemon uses it.
  rd::RelayOutput& as_interface = alert;
  alert.fail_writes(false);
  as_interface.set_healthy(false);
  EXPECT_FALSE(alert.energised());
}

}  // namespace
