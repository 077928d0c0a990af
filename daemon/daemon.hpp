// ridgewatchd's composition: source -> acquisition thread -> SPSC ring buffer -> processing loop
// (StreamProcessor) -> event log / CSV / captures / GPIO relays / systemd notification.
//
// Threads: exactly two. The acquisition thread only reads the source and writes the ring buffer (it
// never blocks on the consumer; overruns are counted by the ring). The processing loop runs on the
// calling thread and owns everything else. Signals only set flags (see request_*), which the
// processing loop polls between blocks, so configuration changes happen at block boundaries.
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "app/config_yaml.hpp"
#include "drivers/gpio.hpp"
#include "drivers/sample_source.hpp"

namespace ridgewatch::daemon {

/// The GPIO lines the daemon drives (any may be null).
struct GpioLines {
  std::unique_ptr<drivers::RelayOutput> alert;   ///< energised while the alarm is below alert
  std::unique_ptr<drivers::RelayOutput> danger;  ///< energised while the alarm is below danger
  std::unique_ptr<drivers::TachoInput> tacho;    ///< once-per-revolution pulses
};

/// Opens the configured libgpiod lines (throws drivers::GpioError naming the chip and line).
GpioLines open_gpio(const app::GpioConfig& config);

struct DaemonOptions {
  app::RidgewatchConfig config;
  std::string config_path;  ///< re-read on SIGHUP; empty: reload keeps the current configuration
  /// Command-line overrides re-applied after every reload (so --replay/--events survive SIGHUP).
  std::function<void(app::RidgewatchConfig&)> overrides;
  /// Replaces open_gpio (tests pass fake lines). Called once at start when set or gpio.enabled.
  std::function<GpioLines(const app::GpioConfig&)> gpio_factory;
  /// Replaces open_source (tests inject an AlsaSource on a local ALSA configuration with failure seams).
  std::function<std::unique_ptr<drivers::SampleSource>(const app::SourceConfig&)> source_factory;
  /// Stop acquiring after this many samples (0: no limit): the end of input then, as for a file
  /// (accelerated soak runs with --loop; `ridgewatchd --max-samples N`).
  std::uint64_t max_samples = 0;
  /// Tests: called on the processing thread after the last event was written, while the HTTP
  /// listener still serves (argument: its port, 0 when off) and before MQTT drains and stops.
  std::function<void(int http_port)> before_network_stop;
};

/// Counters for the status line, tests and the exit summary.
struct DaemonStats {
  std::uint64_t samples = 0, events = 0, events_ok = 0, overruns = 0, gaps = 0, spikes = 0;
  std::uint64_t events_failed_to_write = 0, source_errors = 0, reloads = 0, reloads_rejected = 0;
  std::uint64_t tacho_pulses = 0;
  std::uint64_t captures_written = 0, captures_removed = 0, captures_failed = 0;  ///< output.capture
  /// Paced/live input only: time from the end of an impact's decay window (when its last sample was
  /// due from the source) to its event being written, ms. NaN when not measured.
  double latency_max_ms = NAN;
  double latency_mean_ms = NAN;
  double shaft_hz = 0.0;  ///< from the last two tacho pulses (0 without tacho)
};

/// The shaft speed from the tacho line's rising edges (both daemons poll it between processing steps):
/// counts the pulses into stats.tacho_pulses and sets stats.shaft_hz from the last two (Hz).
class TachoMeter {
 public:
  /// Takes the edges that arrived since the last call (does not wait).
  void poll(drivers::TachoInput& tacho, DaemonStats& stats);

 private:
  std::vector<drivers::TachoEdge> edges_;
  std::int64_t last_pulse_ns_ = 0;
};

class Daemon {
 public:
  explicit Daemon(DaemonOptions options);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  /// Runs until the source ends (replay without loop) or a stop is requested. Returns the exit code:
  /// 0 after a clean stop or end of input, 3 when the source cannot be opened or fails for good.
  /// Every event detected before the stop is written.
  int run();

  const DaemonStats& stats() const;

  // Async-signal-safe requests (set from signal handlers; acted on by run()).
  static void request_stop();
  static void request_reload();
  static void request_latch_reset();
  /// Clears pending requests (tests run several daemons in one process).
  static void clear_requests();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Opens the configured source (replay file with pacing/looping, or ALSA). Throws drivers::InputError
/// (file or device problems) or app::UsageError (configuration).
std::unique_ptr<drivers::SampleSource> open_source(const app::SourceConfig& config);
/// The same, with source.combine (a derived channel; its mesh_velocity radii from config.rig):
/// UsageError naming `config_name` and the source.combine key for a channel the file or device lacks.
std::unique_ptr<drivers::SampleSource> open_source(const app::RidgewatchConfig& config, const std::string& config_name);

}  // namespace ridgewatch::daemon
