// Live state of the daemon for the network outputs: Prometheus /metrics (text exposition format
// 0.0.4, written here; prometheus-cpp is not packaged in Debian 12), the live page's JSON
// (/api/state) and the MQTT status message.
//
// The processing thread feeds it (on_events, set_counters; a mutex held for microseconds per
// processing step, never across I/O); the HTTP and MQTT threads read snapshots.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/pipeline/impact_event.hpp"
#include "core/trend/trend_monitor.hpp"

namespace ridgewatch::daemon {

/// Counters of the MQTT sender, read by /metrics and the page (filled by MqttSink::counters()).
struct MqttCounters {
  bool enabled = false, connected = false;
  std::uint64_t spool_events = 0, spool_bytes = 0, dropped = 0, send_failures = 0, published = 0;
  std::uint64_t acked_seq = 0, last_seq = 0;
};

struct DaemonCounters {
  std::uint64_t samples = 0, impacts_detected = 0, overruns = 0, gaps = 0, spikes = 0, write_failures = 0;
};

/// One metric family of the exposition text: its "# HELP"/"# TYPE" header and its sample lines.
struct MetricFamily {
  std::string header, samples;
};

class Telemetry {
 public:
  /// `stream`: the stream's name when the daemon runs several (`streams:`); every sample of
  /// /metrics then carries a `stream` label and the page's JSON a "stream" member. Empty: one stream,
  /// no label.
  Telemetry(std::string source_name, std::string version, const trend::TrendConfig& trend, double sample_rate_hz,
            std::string stream = {});

  // Processing thread.
  /// `last_json`: the newest event's event-log JSON when the caller has it (else it is built here).
  void on_events(std::span<const pipeline::ImpactEvent> events, std::string_view last_json = {});
  void set_counters(const DaemonCounters& c);
  void observe_latency(double seconds);
  /// True when the page wants the samples of this event's window (at most 5 per second of wall time).
  bool wants_envelope(const pipeline::ImpactEvent& e);
  /// The event's window (pretrigger + decay, first sample at window_first_index): reduced to a
  /// peak-|x| envelope of at most 160 points for the page.
  void add_envelope(const pipeline::ImpactEvent& e, std::span<const float> window, std::uint64_t window_first_index);

  /// Supplies the MQTT counters when scraped (set once before the threads start).
  void set_mqtt_source(std::function<MqttCounters()> f) { mqtt_ = std::move(f); }

  // Any thread.
  const std::string& stream() const { return stream_; }
  std::string prometheus_text() const;  ///< this stream's /metrics
  /// The metric families in a fixed order (the same for every Telemetry), for merging several streams.
  std::vector<MetricFamily> metric_families() const;
  std::string state_json() const;   ///< the live page's data
  std::string status_json() const;  ///< the retained MQTT status message ("state":"online")
  std::uint64_t events_total() const;

 private:
  struct Compact {
    std::uint64_t n;  // 1-based event number
    double t_s, zeta, lo, hi, f_hz, snr_db;
    pipeline::ImpactStatus status;
    trend::AlarmLevel alarm;
  };
  struct Envelope {
    std::uint64_t n;
    double t_s, zeta, lo, hi, f_hz, dt_s, onset_s;
    std::vector<float> env;
  };
  static constexpr std::size_t kStatuses = 10;
  static constexpr std::array<double, 12> kLatencyBuckets = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05,
                                                              0.1,   0.25,   0.5,   1.0,  2.5,   10.0};

  std::string source_, version_, stream_;
  trend::TrendConfig trend_;
  double fs_;
  std::function<MqttCounters()> mqtt_;

  mutable std::mutex mutex_;
  std::array<std::uint64_t, kStatuses> by_status_{};
  std::uint64_t events_ = 0, transitions_ = 0;
  trend::AlarmState alarm_;
  double alarm_since_t_s_ = 0.0;
  std::string last_event_json_;
  DaemonCounters counters_;
  std::array<std::uint64_t, kLatencyBuckets.size()> latency_buckets_{};
  std::uint64_t latency_count_ = 0;
  double latency_sum_ = 0.0;
  std::deque<Compact> recent_;
  std::deque<Envelope> envelopes_;
  std::chrono::steady_clock::time_point last_envelope_wall_{};  // processing thread only
};

/// The /metrics text of several streams: each family's header once, then every stream's samples
/// (the text format wants a family's samples together). All pointers non-null, at least one.
std::string prometheus_exposition(std::span<const Telemetry* const> telemetries);

/// Prometheus label value escaping (backslash, double quote, newline).
std::string prometheus_escape(std::string_view value);

}  // namespace ridgewatch::daemon
