#include "daemon/network_outputs.hpp"

#include <spdlog/spdlog.h>

#include "ridgewatch_version.hpp"

namespace ridgewatch::daemon {

NetworkOutputs::NetworkOutputs(const app::RidgewatchConfig& cfg, const std::string& source_name, double fs,
                               const std::string& stream)
    : telemetry_(source_name, RIDGEWATCH_VERSION, cfg.pipeline.trend, fs, stream), page_(!cfg.http.listen.empty()) {}

std::unique_ptr<NetworkOutputs> NetworkOutputs::start(const app::RidgewatchConfig& cfg, const std::string& source_name,
                                                      double fs, const std::string& stream, bool own_listener) {
  if (cfg.output.mqtt.host.empty() && cfg.http.listen.empty()) return nullptr;
  std::unique_ptr<NetworkOutputs> n(new NetworkOutputs(cfg, source_name, fs, stream));
  if (!cfg.output.mqtt.host.empty()) {
    n->mqtt_ = std::make_unique<MqttSink>(cfg.output.mqtt, source_name, &n->telemetry_, cfg.logging.status_interval_s);
    const MqttSink* m = n->mqtt_.get();
    n->telemetry_.set_mqtt_source([m] { return m->counters(); });
    n->mqtt_->start();  // after the telemetry is complete: the sender thread reads it
    spdlog::info("MQTT: events to {}:{} topic {}/events (QoS {}), spool {} ({} events waiting)", cfg.output.mqtt.host,
                 cfg.output.mqtt.port, m->topic_prefix(), cfg.output.mqtt.qos, cfg.output.mqtt.spool_dir,
                 m->counters().spool_events);
  }
  if (!cfg.http.listen.empty() && own_listener) {
    n->http_ = std::make_unique<HttpServer>(cfg.http.listen, n->telemetry_);
    spdlog::info("HTTP: /metrics and the live page on {} (port {})", cfg.http.listen, n->http_->port());
  }
  return n;
}

NetworkOutputs::~NetworkOutputs() { stop(std::chrono::milliseconds(0)); }

void NetworkOutputs::on_events(std::span<const pipeline::ImpactEvent> events, std::string_view json_lines) {
  if (events.empty()) return;
  if (mqtt_) {
    mqtt_->publish_events(json_lines);
    for (const auto& e : events)
      if (e.alarm.transition()) mqtt_->publish_alarm(e);
  }
  // The newest event's line as written to the event log (serialised once per event).
  std::string_view last = json_lines;
  while (!last.empty() && last.back() == '\n') last.remove_suffix(1);
  if (const auto nl = last.rfind('\n'); nl != std::string_view::npos) last.remove_prefix(nl + 1);
  telemetry_.on_events(events, last);
}

void NetworkOutputs::poll(const DaemonCounters& counters, bool force) {
  const auto now = std::chrono::steady_clock::now();
  if (!force && now - last_poll_ < std::chrono::milliseconds(100)) return;
  last_poll_ = now;
  telemetry_.set_counters(counters);
  if (!mqtt_) return;
  for (const auto& [level, text] : mqtt_->take_log()) spdlog::log(static_cast<spdlog::level::level_enum>(level), "{}", text);
}

void NetworkOutputs::stop(std::chrono::milliseconds drain) {
  if (mqtt_) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::uint64_t waiting = mqtt_->counters().spool_events;
    mqtt_->stop(drain);
    if (waiting > 0 && drain.count() > 0)
      spdlog::info("MQTT: {} events were waiting for the broker at the end of input; drain took {:.3f} s", waiting,
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    for (const auto& [level, text] : mqtt_->take_log()) spdlog::log(static_cast<spdlog::level::level_enum>(level), "{}", text);
    const MqttCounters c = mqtt_->counters();
    if (c.spool_events > 0)
      spdlog::warn("MQTT: {} events not yet acknowledged stay in the spool and are sent after the next start",
                   c.spool_events);
  }
  http_.reset();
}

}  // namespace ridgewatch::daemon
