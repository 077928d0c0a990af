// MQTT output (MQTT 3.1.1; daemon/mqtt_link.hpp): events, a retained status and retained alarm transitions.
//
//   <prefix>/events  one event per message: the event-log JSON object with "seq" first (QoS 1 default)
//   <prefix>/status  retained: {"state":"online", alarm, baseline, EWMA, counters, last_event};
//                    Last Will (and a clean stop) {"state":"offline"} retained
//   <prefix>/alarm   retained: one message per alarm transition
//
// Nothing is lost: the processing thread only appends events to the on-disk Spool (no network); a
// sender thread owns the connection (MqttLink: MQTT 3.1.1 over plain TCP written here, libmosquitto
// for TLS) and works in rounds, at most one per kRound: it reads the PUBACKs that arrived
// (acknowledging their events in the spool once per round), then publishes what the spool holds
// beyond what was sent, in seq order, up to a window of messages in flight, in one burst (plain TCP:
// one send(2)); with nothing to do it sleeps until the processing thread spools again. A lost
// connection throws the client away; the next one (after a backoff of 0.5 s doubling to 4 s) resends from the oldest
// unacknowledged event, so consumers see every seq at least once, in order, and de-duplicate by seq.
// Alarm and status messages are not spooled: they are state, and the newest one is retained.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "app/config_yaml.hpp"
#include "core/pipeline/impact_event.hpp"
#include "daemon/metrics.hpp"
#include "daemon/mqtt_link.hpp"
#include "daemon/spool.hpp"

namespace ridgewatch::daemon {

/// Topic prefix and client id when the configuration leaves them empty: ridgewatch/<source> and
/// ridgewatch-<source>, the source name reduced to characters safe in a topic level.
std::string default_topic_prefix(const std::string& source_name);
std::string default_client_id(const std::string& source_name);

class MqttSink : private MqttLink::Events {
 public:
  /// Opens the spool and reads the password file; throws app::UsageError naming the key when either
  /// fails or the TLS files are not usable. `telemetry` supplies the status message (may be null; it
  /// must be fully set up before start()).
  MqttSink(const app::MqttConfig& config, const std::string& source_name, const Telemetry* telemetry,
           double status_interval_s);
  ~MqttSink() override;
  MqttSink(const MqttSink&) = delete;
  /// Starts the sender thread (which connects by itself and retries).
  void start();
  MqttSink& operator=(const MqttSink&) = delete;

  // Processing thread (never blocks on the network).
  /// Spools a block of event JSON lines (each "{...}\n"); false when the spool write failed.
  bool publish_events(std::string_view json_lines);
  /// Queues the retained alarm message for an event whose alarm level changed.
  void publish_alarm(const pipeline::ImpactEvent& e);

  /// Waits up to `drain` for the spool to empty (while connected), publishes the offline status,
  /// disconnects and joins the thread. What is still unacknowledged stays in the spool.
  void stop(std::chrono::milliseconds drain);

  MqttCounters counters() const;
  /// Log lines from the sender thread, taken by the processing thread (the logger is single-threaded).
  std::vector<std::pair<int, std::string>> take_log();
  const std::string& topic_prefix() const { return prefix_; }

 private:
  void run();
  bool connect();
  void drop_connection(const std::string& why);
  void pump();
  bool check(int rc);
  void wait_socket(std::chrono::milliseconds timeout);
  bool unsent_work();
  void signal_work();
  void on_connect(int rc) override;
  void on_publish(int mid) override;
  void retire_acknowledged();
  void finish_round();
  bool waiting_for(int mid) const;
  void track(int mid, std::uint64_t seq, int qos);
  void log(int level, std::string text);

  app::MqttConfig cfg_;
  std::string prefix_, events_topic_, client_id_, source_, password_;
  const Telemetry* telemetry_;
  std::chrono::duration<double> status_interval_;
  Spool spool_;

  // Sender thread only.
  std::unique_ptr<MqttLink> link_;  // null between connections
  bool connected_ = false;
  struct Inflight {
    int mid;            // message id (MQTT packet identifier)
    std::uint64_t seq;  // event seq (0: status or alarm message)
    bool done;          // acknowledged (QoS 1) or handed over (QoS 0)
  };
  std::deque<Inflight> inflight_;  // publish order
  std::uint64_t sent_through_ = 0;  // highest seq published on this connection
  std::uint64_t ack_pointer_ = 0;   // every event <= this is acknowledged
  std::uint64_t spool_acked_told_ = 0, acked_in_round_ = 0;
  std::vector<Spool::Message> batch_;
  std::chrono::duration<double> backoff_{0.5};
  std::chrono::steady_clock::time_point next_attempt_{}, last_status_{}, last_persist_{};
  std::string last_logged_failure_;
  std::string refused_;  // CONNACK refusal seen in the callback

  std::thread thread_;
  mutable std::mutex mutex_;  // guards the fields below
  std::condition_variable cv_;
  bool stop_ = false;
  bool idle_ = false;  // the sender waits for work (only then does the producer notify)
  bool work_ = false;  // events or an alarm arrived since the sender last went idle
  std::chrono::steady_clock::time_point drain_deadline_{};
  std::deque<std::string> alarms_;  // pending alarm messages (bounded)
  std::vector<std::pair<int, std::string>> log_;
  std::atomic<bool> has_log_{false};
  std::atomic<bool> connected_flag_{false};
  std::atomic<std::uint64_t> send_failures_{0}, published_{0};
};

}  // namespace ridgewatch::daemon
