// The daemon's network outputs in one place: MQTT (store-and-forward through the on-disk spool) and
// the HTTP listener (/metrics, the live page), both fed from Telemetry. The daemon calls these few
// hooks from its processing thread; none of them waits for the network.
#pragma once

#include <chrono>
#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "app/config_yaml.hpp"
#include "daemon/http_server.hpp"
#include "daemon/metrics.hpp"
#include "daemon/mqtt_sink.hpp"

namespace ridgewatch::daemon {

class NetworkOutputs {
 public:
  /// Null when neither output.mqtt.host nor http.listen is set. Throws app::UsageError naming the key
  /// (spool directory, password file, TLS files, listen address).
  /// Several streams: `stream` names this one (a label on /metrics), and `own_listener` false keeps
  /// the telemetry for http.listen but leaves the listener to the caller (one for all streams).
  static std::unique_ptr<NetworkOutputs> start(const app::RidgewatchConfig& cfg, const std::string& source_name,
                                               double sample_rate_hz, const std::string& stream = {},
                                               bool own_listener = true);
  ~NetworkOutputs();

  /// A processing step's events and their event-log JSON lines (`json_lines`, one per event):
  /// spooled for MQTT, counted for /metrics and the page.
  void on_events(std::span<const pipeline::ImpactEvent> events, std::string_view json_lines);
  bool wants_envelope(const pipeline::ImpactEvent& e) { return page_ && telemetry_.wants_envelope(e); }
  void add_envelope(const pipeline::ImpactEvent& e, std::span<const float> window, std::uint64_t first) {
    telemetry_.add_envelope(e, window, first);
  }
  void observe_latency(double seconds) { telemetry_.observe_latency(seconds); }
  /// Called every loop iteration: refreshes the counters (at most every 100 ms) and logs what the
  /// sender thread reported.
  void poll(const DaemonCounters& counters, bool force = false);
  /// End of run: waits up to `drain` for the MQTT spool to empty, then stops both outputs.
  void stop(std::chrono::milliseconds drain);

  Telemetry& telemetry() { return telemetry_; }
  const MqttSink* mqtt() const { return mqtt_.get(); }
  int http_port() const { return http_ ? http_->port() : 0; }

 private:
  NetworkOutputs(const app::RidgewatchConfig& cfg, const std::string& source_name, double fs, const std::string& stream);
  Telemetry telemetry_;
  bool page_ = false;  // http.listen is set: the live page shows envelopes
  std::unique_ptr<MqttSink> mqtt_;
  std::unique_ptr<HttpServer> http_;
  std::chrono::steady_clock::time_point last_poll_{};
};

}  // namespace ridgewatch::daemon
