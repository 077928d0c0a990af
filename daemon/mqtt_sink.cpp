#include "daemon/mqtt_sink.hpp"

#include <mosquitto.h>
#include <poll.h>
#include <pthread.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>

#include "app/args.hpp"
#include "app/event_json.hpp"

namespace ridgewatch::daemon {

namespace {

using Clock = std::chrono::steady_clock;

constexpr std::size_t kWindow = 256;        // event messages in flight (published, not yet PUBACKed)
// The sender works in rounds at most this often: what the processing thread spooled meanwhile goes
// out in one corked burst. 1 ms keeps a 60 000 events/s replay flowing (5 ms let a 15 000-event
// replay end with 1 600-6 200 events waiting and a 0.14-0.35 s drain) and adds at most 1 ms to the
// delivery of a live event.
constexpr std::chrono::milliseconds kRound{1};
constexpr std::size_t kMaxPendingAlarms = 64;
// Reconnect backoff: 0.5 s doubling to 4 s (a broker back after an outage is used within 4 s; one
// attempt every 4 s costs a broker nothing).
constexpr double kBackoffMax_s = 4.0;

std::once_flag g_lib_init;

std::string nlohmann_quote(const std::string& s) {
  return nlohmann::json(s).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string safe_level(const std::string& s) {
  // A file path as source name: keep its last component without the extension.
  std::string base = s;
  if (const auto slash = base.find_last_of('/'); slash != std::string::npos) base = base.substr(slash + 1);
  if (const auto dot = base.find_last_of('.'); dot != std::string::npos && dot > 0) base = base.substr(0, dot);
  for (char& c : base)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == '.')) c = '_';
  return base.empty() ? std::string("source") : base;
}

std::string read_password(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw app::UsageError("output.mqtt.password_file: cannot read '" + path + "'");
  std::string line;
  std::getline(in, line);
  while (!line.empty() && (line.back() == '\r' || line.back() == '\n')) line.pop_back();
  if (line.empty()) throw app::UsageError("output.mqtt.password_file: '" + path + "' is empty (the password is its first line)");
  return line;
}

void check_readable(const std::string& key, const std::string& path) {
  if (path.empty()) return;
  std::ifstream in(path);
  if (!in) throw app::UsageError("output.mqtt.tls." + key + ": cannot read '" + path + "'");
}

}  // namespace

std::string default_topic_prefix(const std::string& source_name) { return "ridgewatch/" + safe_level(source_name); }
std::string default_client_id(const std::string& source_name) { return "ridgewatch-" + safe_level(source_name); }

static Spool open_spool(const app::MqttConfig& c) {
  try {
    return Spool(c.spool_dir, static_cast<std::uint64_t>(c.spool_max_mb * 1e6));
  } catch (const SpoolError& e) {
    throw app::UsageError(std::string("output.mqtt.spool_dir: ") + e.what());
  }
}

MqttSink::MqttSink(const app::MqttConfig& config, const std::string& source_name, const Telemetry* telemetry,
                   double status_interval_s)
    : cfg_(config),
      prefix_(config.topic_prefix.empty() ? default_topic_prefix(source_name) : config.topic_prefix),
      client_id_(config.client_id.empty() ? default_client_id(source_name) : config.client_id),
      source_(source_name),
      telemetry_(telemetry),
      status_interval_(status_interval_s),
      spool_(open_spool(config)) {
  std::call_once(g_lib_init, [] { mosquitto_lib_init(); });
  while (!prefix_.empty() && prefix_.back() == '/') prefix_.pop_back();
  events_topic_ = prefix_ + "/events";
  if (!cfg_.password_file.empty()) password_ = read_password(cfg_.password_file);
  check_readable("ca_file", cfg_.tls.ca_file);
  check_readable("cert_file", cfg_.tls.cert_file);
  check_readable("key_file", cfg_.tls.key_file);
  ack_pointer_ = spool_.acked();
  sent_through_ = ack_pointer_;
}

void MqttSink::start() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!thread_.joinable() && !stop_) thread_ = std::thread([this] { run(); });
}

MqttSink::~MqttSink() { stop(std::chrono::milliseconds(0)); }

bool MqttSink::publish_events(std::string_view json_lines) {
  const bool ok = spool_.append(json_lines) != 0;
  signal_work();
  return ok;
}

void MqttSink::signal_work() {
  bool wake = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    work_ = true;
    wake = idle_;
  }
  // Only an idle sender is woken: a busy one takes the events in its next round anyway, and waking
  // it per processing step would cost a context switch each on a single core.
  if (wake) cv_.notify_one();
}

void MqttSink::publish_alarm(const pipeline::ImpactEvent& e) {
  std::string msg = "{\"level\":\"" + std::string(trend::to_string(e.alarm.level)) + "\",\"previous\":\"" +
                    std::string(trend::to_string(e.alarm.previous)) + "\",\"event\":";
  app::append_event_json(msg, e, source_);
  msg += '}';
  std::lock_guard<std::mutex> lock(mutex_);
  alarms_.push_back(std::move(msg));
  // The topic is retained state: when the broker is away for long, the newest transitions matter.
  if (alarms_.size() > kMaxPendingAlarms) alarms_.pop_front();
  work_ = true;
  if (idle_) cv_.notify_one();
}

void MqttSink::log(int level, std::string text) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (log_.size() < 100) log_.emplace_back(level, std::move(text));
  has_log_.store(true, std::memory_order_release);
}

std::vector<std::pair<int, std::string>> MqttSink::take_log() {
  std::vector<std::pair<int, std::string>> out;
  if (!has_log_.load(std::memory_order_acquire)) return out;
  std::lock_guard<std::mutex> lock(mutex_);
  out.swap(log_);
  has_log_.store(false, std::memory_order_release);
  return out;
}

MqttCounters MqttSink::counters() const {
  MqttCounters c;
  c.enabled = true;
  c.connected = connected_flag_.load(std::memory_order_relaxed);
  c.spool_events = spool_.depth();
  c.spool_bytes = spool_.bytes();
  c.dropped = spool_.dropped() + spool_.write_failures();
  c.send_failures = send_failures_.load(std::memory_order_relaxed);
  c.published = published_.load(std::memory_order_relaxed);
  c.acked_seq = spool_.acked();
  c.last_seq = spool_.last_seq();
  return c;
}

void MqttSink::on_connect(int rc) {
  if (rc != 0) {
    // Handled after the link's read() returns (the link cannot be destroyed inside its callback).
    refused_ = std::string("broker refused the connection: ") + mosquitto_connack_string(rc);
    return;
  }
  connected_ = true;
  connected_flag_.store(true);
  backoff_ = std::chrono::duration<double>(0.5);
  last_logged_failure_.clear();
  log(SPDLOG_LEVEL_INFO, "MQTT: connected to " + cfg_.host + ":" + std::to_string(cfg_.port) + " as " + client_id_ +
                             ", topics " + prefix_ + "/{events,status,alarm}; " + std::to_string(spool_.depth()) +
                             " spooled events to send");
  last_status_ = Clock::time_point{};  // publish the status right away
}

void MqttSink::on_publish(int mid) {
  // The broker acknowledges QoS 1 messages in the order they were published (MQTT 3.1.1, 4.6), so
  // the entry is nearly always the oldest; the scan is a fallback.
  for (auto& f : inflight_) {
    if (f.mid == mid && !f.done) {
      f.done = true;
      break;
    }
  }
  retire_acknowledged();
}

void MqttSink::retire_acknowledged() {
  // Every event up to the oldest one still waiting is acknowledged; the spool learns it once per
  // round (finish_round), not per message.
  while (!inflight_.empty() && inflight_.front().done) {
    if (inflight_.front().seq != 0) {
      ack_pointer_ = std::max(ack_pointer_, inflight_.front().seq);
      ++acked_in_round_;
    }
    inflight_.pop_front();
  }
}

void MqttSink::finish_round() {
  if (acked_in_round_ > 0) published_.fetch_add(acked_in_round_, std::memory_order_relaxed);
  acked_in_round_ = 0;
  if (ack_pointer_ > spool_acked_told_) {
    spool_.ack_through(ack_pointer_);
    spool_acked_told_ = ack_pointer_;
  }
}

bool MqttSink::waiting_for(int mid) const {
  return std::any_of(inflight_.begin(), inflight_.end(), [mid](const Inflight& f) { return f.mid == mid && !f.done; });
}

void MqttSink::track(int mid, std::uint64_t seq, int qos) {
  // QoS 0 has no acknowledgement: the message counts as sent once the link has it (libmosquitto's
  // publish callback may already have run inside mosquitto_publish, before the id was known here).
  inflight_.push_back(Inflight{mid, seq, qos == 0});
  if (qos == 0) retire_acknowledged();
}

bool MqttSink::connect() {
  MqttLink::Options o;
  o.client_id = client_id_;
  o.username = cfg_.username;
  o.password = password_;
  o.will_topic = prefix_ + "/status";
  o.will_payload = "{\"state\":\"offline\",\"source\":" + nlohmann_quote(source_) + "}";
  o.keepalive_s = static_cast<int>(std::lround(cfg_.keepalive_s));
  std::string error;
  link_ = make_mqtt_link(cfg_, o, *this, error);
  if (!link_) {
    drop_connection(error);
    return false;
  }
  const int rc = link_->connect(cfg_.host, static_cast<int>(cfg_.port));
  if (rc != MOSQ_ERR_SUCCESS) {
    drop_connection("cannot connect to " + cfg_.host + ":" + std::to_string(cfg_.port) + ": " +
                    (rc == MOSQ_ERR_ERRNO ? std::string(std::strerror(errno)) : std::string(mosquitto_strerror(rc))));
    return false;
  }
  sent_through_ = spool_.acked();
  ack_pointer_ = spool_acked_told_ = sent_through_;
  inflight_.clear();
  return true;
}

void MqttSink::drop_connection(const std::string& why) {
  link_.reset();
  const bool was = connected_;
  connected_ = false;
  connected_flag_.store(false);
  finish_round();  // what the broker did acknowledge leaves the spool
  inflight_.clear();
  send_failures_.fetch_add(1, std::memory_order_relaxed);
  // Unacknowledged events are resent from the spool by the next connection.
  const std::string text = "MQTT: " + why + (was && why.find("lost") == std::string::npos ? " (connection lost)" : "") + "; retrying in " +
                           fmt::format("{:.1f}", backoff_.count()) + " s, " + std::to_string(spool_.depth()) +
                           " events spooled";
  if (why != last_logged_failure_ || was) log(SPDLOG_LEVEL_WARN, text);
  last_logged_failure_ = why;
  next_attempt_ = Clock::now() + std::chrono::duration_cast<Clock::duration>(backoff_);
  backoff_ = std::min(backoff_ * 2.0, std::chrono::duration<double>(kBackoffMax_s));
}

void MqttSink::pump() {
  // Events from the spool, in seq order, keeping at most kWindow in flight. Waiting for 32 or 128 to
  // be acknowledged before refilling stalled on the broker's Nagle-delayed PUBACKs (our delayed TCP
  // ACKs are no longer carried by outgoing data): a 15 000-event backlog then took 1.2-2 s to deliver
  // instead of 0.04 s.
  bool corked = false;
  while (link_ && inflight_.size() < kWindow) {
    batch_.clear();
    if (spool_.read(sent_through_, kWindow - inflight_.size(), batch_) == 0) break;
    if (!corked) link_->burst(corked = true);
    for (const auto& m : batch_) {
      int mid = 0;
      const int rc = link_->publish(&mid, events_topic_, m.payload, static_cast<int>(cfg_.qos), false);
      if (rc != MOSQ_ERR_SUCCESS) {
        drop_connection(std::string("publish failed: ") + mosquitto_strerror(rc));
        return;
      }
      sent_through_ = m.seq;
      track(mid, m.seq, static_cast<int>(cfg_.qos));
    }
  }
  std::deque<std::string> alarms;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    alarms.swap(alarms_);
  }
  for (const auto& a : alarms) {
    int mid = 0;
    if (link_->publish(&mid, prefix_ + "/alarm", a, 1, true) == MOSQ_ERR_SUCCESS) track(mid, 0, 1);
  }
  const auto now = Clock::now();
  if (telemetry_ && now - last_status_ >= status_interval_) {
    const std::string s = telemetry_->status_json();
    int mid = 0;
    if (link_->publish(&mid, prefix_ + "/status", s, 1, true) == MOSQ_ERR_SUCCESS) track(mid, 0, 1);
    last_status_ = now;
  }
  if (corked) link_->burst(false);
}

bool MqttSink::check(int rc) {
  if (!refused_.empty()) {
    drop_connection(refused_);
    refused_.clear();
    return false;
  }
  if (rc != MOSQ_ERR_SUCCESS) {
    drop_connection(rc == MOSQ_ERR_ERRNO ? std::string(std::strerror(errno)) : std::string(mosquitto_strerror(rc)));
    return false;
  }
  return true;
}

void MqttSink::wait_socket(std::chrono::milliseconds timeout) {
  pollfd p{};
  p.fd = link_->socket();
  if (p.fd < 0) return;
  p.events = static_cast<short>(POLLIN | (link_->want_write() ? POLLOUT : 0));
  ::poll(&p, 1, static_cast<int>(timeout.count()));
}

bool MqttSink::unsent_work() {
  if (spool_.last_seq() > sent_through_ && inflight_.size() < kWindow) return true;
  std::lock_guard<std::mutex> lock(mutex_);
  return !alarms_.empty();
}

void MqttSink::run() {
  pthread_setname_np(pthread_self(), "rw-mqtt");  // visible in top -H, perf and journal stack traces
  for (;;) {
    bool stopping = false;
    Clock::time_point deadline;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopping = stop_;
      deadline = drain_deadline_;
    }
    const auto now = Clock::now();
    if (stopping) {
      const bool drained = spool_.depth() == 0 && inflight_.empty();
      // Without a connection, give up at once when the next attempt would come after the deadline.
      if (drained || now >= deadline || (!link_ && next_attempt_ >= deadline)) break;
    }
    if (now - last_persist_ >= std::chrono::seconds(1)) {
      spool_.persist();
      last_persist_ = now;
    }
    if (!link_) {
      if (now < next_attempt_) {
        // Until the next attempt (a stop ends the wait; while stopping, the deadline does).
        const auto until = std::min(next_attempt_, now + std::chrono::milliseconds(100));
        std::unique_lock<std::mutex> lock(mutex_);
        if (stopping)
          cv_.wait_until(lock, std::min(until, deadline));
        else
          cv_.wait_until(lock, until, [this] { return stop_; });
        continue;
      }
      connect();
      continue;
    }
    if (!connected_) {
      // CONNACK pending.
      wait_socket(std::chrono::milliseconds(10));
      if (check(link_->read())) check(link_->misc());
      continue;
    }
    // One round: the acknowledgements that arrived (each PUBACK frees its event in the spool), then
    // everything the spool holds beyond what was sent (up to the window) in one burst.
    if (!check(link_->read())) continue;
    finish_round();
    pump();
    if (!link_) continue;
    if (link_->want_write() && !check(link_->write())) continue;  // plain TCP: the round's one send(2)
    if (!check(link_->misc())) continue;  // keepalive
    // Pacing: at most one round per kRound (events that arrive meanwhile wait in the spool and go
    // together), so the sender's cost per event does not grow with how fast events come.
    std::this_thread::sleep_until(now + kRound);
    if (unsent_work()) continue;
    if (!inflight_.empty() || link_->want_write()) {
      wait_socket(std::chrono::milliseconds(10));  // acknowledgements expected
      continue;
    }
    // Idle: until the processing thread spools events (or an alarm), the next status, or 100 ms
    // (keepalive, connection health, stop).
    auto until = Clock::now() + std::chrono::milliseconds(100);
    if (telemetry_) until = std::min(until, last_status_ + std::chrono::duration_cast<Clock::duration>(status_interval_));
    std::unique_lock<std::mutex> lock(mutex_);
    idle_ = true;
    cv_.wait_until(lock, until, [this] { return work_ || stop_; });
    idle_ = false;
    work_ = false;
  }
  // Clean stop: the offline status replaces the retained online one (the Last Will is not sent then).
  if (link_ && connected_) {
    const std::string off = "{\"state\":\"offline\",\"source\":" + nlohmann_quote(source_) + "}";
    int mid = 0;
    if (link_->publish(&mid, prefix_ + "/status", off, 1, true) == MOSQ_ERR_SUCCESS) track(mid, 0, 1);
    const auto until = Clock::now() + std::chrono::milliseconds(500);
    while (waiting_for(mid) && Clock::now() < until) {
      if (link_->write() != MOSQ_ERR_SUCCESS) break;
      wait_socket(std::chrono::milliseconds(10));
      if (link_->read() != MOSQ_ERR_SUCCESS) break;
    }
    finish_round();
    link_->disconnect();
  }
  link_.reset();
  connected_flag_.store(false);
  spool_.persist();
}

void MqttSink::stop(std::chrono::milliseconds drain) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!thread_.joinable()) return;
    stop_ = true;
    drain_deadline_ = Clock::now() + drain;
  }
  cv_.notify_one();
  thread_.join();
}

}  // namespace ridgewatch::daemon
