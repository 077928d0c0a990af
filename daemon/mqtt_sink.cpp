#include "daemon/mqtt_sink.hpp"

#include <mosquitto.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <sys/socket.h>
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

void MqttSink::cb_connect(struct mosquitto*, void* self, int rc) { static_cast<MqttSink*>(self)->on_connect(rc); }
void MqttSink::cb_publish(struct mosquitto*, void* self, int mid) { static_cast<MqttSink*>(self)->on_publish(mid); }

void MqttSink::on_connect(int rc) {
  if (rc != 0) {
    // Handled after mosquitto_loop() returns (the client cannot be destroyed inside its callback).
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
  // QoS 0 has no acknowledgement: the message counts as sent once libmosquitto has it (its publish
  // callback may already have run inside mosquitto_publish, before the id was known here).
  inflight_.push_back(Inflight{mid, seq, qos == 0});
  if (qos == 0) retire_acknowledged();
}

bool MqttSink::connect() {
  mosq_ = mosquitto_new(client_id_.c_str(), true, this);
  if (!mosq_) {
    log(SPDLOG_LEVEL_ERROR, "MQTT: cannot create a client (out of memory)");
    return false;
  }
  mosquitto_int_option(mosq_, MOSQ_OPT_PROTOCOL_VERSION, MQTT_PROTOCOL_V311);
  mosquitto_max_inflight_messages_set(mosq_, static_cast<unsigned>(kWindow + kMaxPendingAlarms + 2));
  mosquitto_connect_callback_set(mosq_, &MqttSink::cb_connect);
  mosquitto_publish_callback_set(mosq_, &MqttSink::cb_publish);
  if (!cfg_.username.empty()) mosquitto_username_pw_set(mosq_, cfg_.username.c_str(), password_.empty() ? nullptr : password_.c_str());
  if (!cfg_.tls.ca_file.empty()) {
    const int rc = mosquitto_tls_set(mosq_, cfg_.tls.ca_file.c_str(), nullptr,
                                     cfg_.tls.cert_file.empty() ? nullptr : cfg_.tls.cert_file.c_str(),
                                     cfg_.tls.key_file.empty() ? nullptr : cfg_.tls.key_file.c_str(), nullptr);
    if (rc != MOSQ_ERR_SUCCESS) {
      drop_connection(std::string("TLS setup failed: ") + mosquitto_strerror(rc));
      return false;
    }
  }
  const std::string will = "{\"state\":\"offline\",\"source\":" + nlohmann_quote(source_) + "}";
  mosquitto_will_set(mosq_, (prefix_ + "/status").c_str(), static_cast<int>(will.size()), will.data(), 1, true);
  const int rc = mosquitto_connect(mosq_, cfg_.host.c_str(), static_cast<int>(cfg_.port),
                                   static_cast<int>(std::lround(cfg_.keepalive_s)));
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
  if (mosq_) {
    mosquitto_destroy(mosq_);
    mosq_ = nullptr;
  }
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

void MqttSink::set_cork(bool on) {
  // TCP_CORK: the PUBLISH packets of one round (libmosquitto writes each with its own write(2)) are
  // collected in the socket and leave in as few full segments as possible when the cork is pulled,
  // instead of one segment (and one trip through the loopback or network stack) per event.
  const int fd = mosq_ ? mosquitto_socket(mosq_) : -1;
  if (fd < 0) return;
  const int v = on ? 1 : 0;
  ::setsockopt(fd, IPPROTO_TCP, TCP_CORK, &v, sizeof v);
}

void MqttSink::pump() {
  // Events from the spool, in seq order, keeping at most kWindow in flight. Waiting for 32 or 128 to
  // be acknowledged before refilling stalled on the broker's Nagle-delayed PUBACKs (our delayed TCP
  // ACKs are no longer carried by outgoing data): a 15 000-event backlog then took 1.2-2 s to deliver
  // instead of 0.04 s.
  bool corked = false;
  while (mosq_ && inflight_.size() < kWindow) {
    batch_.clear();
    if (spool_.read(sent_through_, kWindow - inflight_.size(), batch_) == 0) break;
    if (!corked) set_cork(corked = true);
    const std::string topic = prefix_ + "/events";
    for (const auto& m : batch_) {
      int mid = 0;
      const int rc = mosquitto_publish(mosq_, &mid, topic.c_str(), static_cast<int>(m.payload.size()), m.payload.data(),
                                       static_cast<int>(cfg_.qos), false);
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
    if (mosquitto_publish(mosq_, &mid, (prefix_ + "/alarm").c_str(), static_cast<int>(a.size()), a.data(), 1, true) ==
        MOSQ_ERR_SUCCESS)
      track(mid, 0, 1);
  }
  const auto now = Clock::now();
  if (telemetry_ && now - last_status_ >= status_interval_) {
    const std::string s = telemetry_->status_json();
    int mid = 0;
    if (mosquitto_publish(mosq_, &mid, (prefix_ + "/status").c_str(), static_cast<int>(s.size()), s.data(), 1, true) ==
        MOSQ_ERR_SUCCESS)
      track(mid, 0, 1);
    last_status_ = now;
  }
  if (corked) set_cork(false);
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
  p.fd = mosquitto_socket(mosq_);
  if (p.fd < 0) return;
  p.events = static_cast<short>(POLLIN | (mosquitto_want_write(mosq_) ? POLLOUT : 0));
  ::poll(&p, 1, static_cast<int>(timeout.count()));
}

int MqttSink::read_socket() {
  // libmosquitto reads packets until a read fails with EAGAIN, but tests errno also after a read that
  // succeeded: a stale EAGAIN from an earlier call would end the loop after one packet.
  errno = 0;
  return mosquitto_loop_read(mosq_, 1);
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
      if (drained || now >= deadline || (!mosq_ && next_attempt_ >= deadline)) break;
    }
    if (now - last_persist_ >= std::chrono::seconds(1)) {
      spool_.persist();
      last_persist_ = now;
    }
    if (!mosq_) {
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
      if (check(read_socket())) check(mosquitto_loop_misc(mosq_));
      continue;
    }
    // One round: the acknowledgements that arrived (each PUBACK frees its event in the spool), then
    // everything the spool holds beyond what was sent (up to the window) in one corked burst.
    if (!check(read_socket())) continue;
    finish_round();
    pump();
    if (!mosq_) continue;
    if (mosquitto_want_write(mosq_) && !check(mosquitto_loop_write(mosq_, 1))) continue;  // socket was full
    if (!check(mosquitto_loop_misc(mosq_))) continue;  // keepalive
    // Pacing: at most one round per kRound (events that arrive meanwhile wait in the spool and go
    // together), so the sender's cost per event does not grow with how fast events come.
    std::this_thread::sleep_until(now + kRound);
    if (unsent_work()) continue;
    if (!inflight_.empty() || mosquitto_want_write(mosq_)) {
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
  if (mosq_ && connected_) {
    const std::string off = "{\"state\":\"offline\",\"source\":" + nlohmann_quote(source_) + "}";
    int mid = 0;
    mosquitto_publish(mosq_, &mid, (prefix_ + "/status").c_str(), static_cast<int>(off.size()), off.data(), 1, true);
    track(mid, 0, 1);
    const auto until = Clock::now() + std::chrono::milliseconds(500);
    while (waiting_for(mid) && Clock::now() < until) {
      wait_socket(std::chrono::milliseconds(10));
      if (read_socket() != MOSQ_ERR_SUCCESS) break;
    }
    finish_round();
    mosquitto_disconnect(mosq_);
  }
  if (mosq_) mosquitto_destroy(mosq_);
  mosq_ = nullptr;
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
