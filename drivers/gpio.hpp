// GPIO lines for the daemon: a tacho / once-per-revolution input with kernel edge timestamps, and
// alert/danger relay outputs. Interfaces here, the libgpiod 1.6 implementation below them, and an
// in-memory fake for tests in drivers/gpio_fake.hpp.
//
// Relay outputs are FAIL-SAFE: energised = healthy. set_healthy(true) drives the line active (relay
// energised); set_healthy(false) (alarm) drives it inactive, which is also what a dead daemon, a cut
// wire or a lost supply looks like, so every failure of the monitor itself reads as an alarm. The
// implementation drives the line inactive (alarm) when it is destroyed: a stopped monitor is not a
// healthy one. `active_low` inverts the electrical level (for relay boards that energise on a low
// line): "active" then means a low pin, handled by libgpiod's ACTIVE_LOW flag, so the fail-safe
// logic above is unchanged.
//
// Tacho timestamps are the kernel's edge timestamps in nanoseconds (libgpiod 1.6 / uAPI v1: CLOCK_MONOTONIC
// on kernels >= 5.7, CLOCK_REALTIME before). The daemon anchors them to the sample stream with
// timestamp_to_sample_index(): one (timestamp, sample index) pair taken when a block arrives plus
// the sample rate.
//
// Errors at construction (chip not found, line offset out of range, line busy) throw GpioError naming
// the chip and line: "gpio gpiochip7: cannot open chip: No such file or directory". At run time, a
// failing read or write is counted (errors()) and described by last_error(), never thrown.
#pragma once

#include <chrono>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

struct gpiod_chip;
struct gpiod_line;

namespace ridgewatch::drivers {

class GpioError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Consumer label of every requested line (shown by gpioinfo).
inline constexpr const char* kGpioConsumer = "ridgewatchd";

struct TachoEdge {
  std::int64_t timestamp_ns = 0;  ///< kernel timestamp of the edge, ns
  bool rising = true;             ///< rising (inactive -> active) or falling edge
};

enum class TachoEdges { rising, falling, both };

/// Sample index of an event at `timestamp_ns`, given that sample `anchor_index` was taken at
/// `anchor_ns` on the same clock: anchor_index + (timestamp_ns - anchor_ns) * rate / 1e9, rounded to the
/// nearest sample. Events before index 0 clamp to 0.
inline std::uint64_t timestamp_to_sample_index(std::int64_t timestamp_ns, std::int64_t anchor_ns,
                                               std::uint64_t anchor_index, double sample_rate_hz) {
  const double index = static_cast<double>(anchor_index) +
                       static_cast<double>(timestamp_ns - anchor_ns) * 1e-9 * sample_rate_hz;
  return index <= 0.0 ? 0 : static_cast<std::uint64_t>(std::llround(index));
}

class TachoInput {
 public:
  virtual ~TachoInput() = default;
  /// Waits up to `timeout` for edges and appends every pending one to `out` (oldest first). Returns
  /// how many were appended; 0 on timeout or on a counted error.
  virtual std::size_t wait_edges(std::chrono::nanoseconds timeout, std::vector<TachoEdge>& out) = 0;
  virtual const std::string& name() const = 0;
  virtual std::uint64_t errors() const = 0;
};

class RelayOutput {
 public:
  virtual ~RelayOutput() = default;
  /// true: energise (line active); false: alarm (line inactive). See the fail-safe note above.
  virtual void set_healthy(bool healthy) = 0;
  virtual bool healthy() const = 0;
  virtual const std::string& name() const = 0;
  virtual std::uint64_t errors() const = 0;
};

struct GpioLineConfig {
  std::string chip;      ///< gpiochip name ("gpiochip0"), number ("0"), label or path ("/dev/gpiochip0")
  unsigned offset = 0;   ///< line offset on the chip
  bool active_low = false;  ///< the line is active (relay energised / pulse present) when the pin is low
};

/// libgpiod 1.6 tacho input: the line requested for edge events with consumer "ridgewatchd".
class GpiodTachoInput : public TachoInput {
 public:
  /// Throws GpioError naming chip and line.
  GpiodTachoInput(const GpioLineConfig& config, TachoEdges edges);
  ~GpiodTachoInput() override;
  GpiodTachoInput(const GpiodTachoInput&) = delete;
  GpiodTachoInput& operator=(const GpiodTachoInput&) = delete;

  std::size_t wait_edges(std::chrono::nanoseconds timeout, std::vector<TachoEdge>& out) override;
  const std::string& name() const override { return name_; }
  std::uint64_t errors() const override { return errors_; }
  const std::string& last_error() const { return last_error_; }

 private:
  std::string name_;
  gpiod_chip* chip_ = nullptr;
  gpiod_line* line_ = nullptr;
  std::uint64_t errors_ = 0;
  std::string last_error_;
};

/// libgpiod 1.6 relay output, requested as output with consumer "ridgewatchd".
class GpiodRelayOutput : public RelayOutput {
 public:
  /// Starts in the alarm state (de-energised) until the daemon declares health. Throws GpioError.
  explicit GpiodRelayOutput(const GpioLineConfig& config);
  ~GpiodRelayOutput() override;  ///< de-energises (alarm), then releases the line
  GpiodRelayOutput(const GpiodRelayOutput&) = delete;
  GpiodRelayOutput& operator=(const GpiodRelayOutput&) = delete;

  void set_healthy(bool healthy) override;
  bool healthy() const override { return healthy_; }
  const std::string& name() const override { return name_; }
  std::uint64_t errors() const override { return errors_; }
  const std::string& last_error() const { return last_error_; }

 private:
  std::string name_;
  gpiod_chip* chip_ = nullptr;
  gpiod_line* line_ = nullptr;
  bool healthy_ = false;
  std::uint64_t errors_ = 0;
  std::string last_error_;
};

/// `ridgewatchd --list-devices`: every GPIO chip (/dev/gpiochip*) with its label and, per line, the
/// offset, name, direction and consumer (like gpioinfo). Never throws.
std::string describe_gpio_chips();

}  // namespace ridgewatch::drivers
