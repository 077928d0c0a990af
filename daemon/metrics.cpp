#include "daemon/metrics.hpp"

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <type_traits>
#include <nlohmann/json.hpp>

#include "app/event_json.hpp"

namespace ridgewatch::daemon {

namespace {

constexpr std::size_t kRecentEvents = 300;  // events shown on the page's trend
constexpr std::size_t kEnvelopes = 6;       // last impacts' envelopes on the page
constexpr std::size_t kEnvelopePoints = 160;
constexpr double kEnvelopeEvery_s = 0.2;    // wall time between captured envelopes

// Prometheus sample value: Go's ParseFloat spellings for the special values.
std::string prom_value(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Builds the metric families of one stream: family() starts one, sample() adds a line whose label
// set begins with the stream's label when there is one.
class FamilyWriter {
 public:
  explicit FamilyWriter(const std::string& stream)
      : stream_label_(stream.empty() ? std::string() : "stream=\"" + prometheus_escape(stream) + "\"") {}

  void family(const char* name, const char* type, const char* help) {
    MetricFamily& f = families_.emplace_back();
    f.header = std::string("# HELP ") + name + ' ' + help + "\n# TYPE " + name + ' ' + type + '\n';
  }
  // `labels`: the sample's own labels without braces (name="value",...), or empty.
  void sample(std::string_view name, std::string_view labels, double v) { line(name, labels) += prom_value(v) + '\n'; }
  void sample(std::string_view name, std::string_view labels, std::uint64_t v) {
    line(name, labels) += std::to_string(v) + '\n';
  }
  // A family of one unlabelled sample (most of them).
  template <typename Value>
  void one(const char* name, const char* type, const char* help, Value v) {
    family(name, type, help);
    sample(name, "", v);
  }
  std::vector<MetricFamily> take() { return std::move(families_); }

 private:
  std::string& line(std::string_view name, std::string_view labels) {
    std::string& out = families_.back().samples;
    out += name;
    if (!stream_label_.empty() || !labels.empty()) {
      out += '{';
      out += stream_label_;
      if (!stream_label_.empty() && !labels.empty()) out += ',';
      out += labels;
      out += '}';
    }
    out += ' ';
    return out;
  }
  std::string stream_label_;
  std::vector<MetricFamily> families_;
};

// A JSON number: the shortest text that reads back as the same value; NaN and infinities (which JSON
// cannot spell) as null, as nlohmann::json writes them.
// A float is written as the shortest text for the float itself, not for its double widening.
template <typename Real>
  requires std::is_floating_point_v<Real>
void json_number(std::string& out, Real v) {
  if (!std::isfinite(v)) {
    out += "null";
    return;
  }
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
}

void json_number(std::string& out, std::uint64_t v) {
  char buf[24];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
}

double zeta_of(double ln_zeta) { return std::isfinite(ln_zeta) ? std::exp(ln_zeta) : NAN; }

}  // namespace

std::string prometheus_escape(std::string_view value) {
  std::string out;
  out.reserve(value.size());
  for (const char c : value) {
    if (c == '\\') {
      out += "\\\\";
    } else if (c == '"') {
      out += "\\\"";
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out += c;
    }
  }
  return out;
}

Telemetry::Telemetry(std::string source_name, std::string version, const trend::TrendConfig& trend, double fs,
                     std::string stream)
    : source_(std::move(source_name)),
      version_(std::move(version)),
      stream_(std::move(stream)),
      trend_(trend),
      fs_(fs) {}

void Telemetry::on_events(std::span<const pipeline::ImpactEvent> events, std::string_view last_json) {
  if (events.empty()) return;
  // The JSON of the newest event, outside the lock.
  std::string last = last_json.empty() ? app::event_json(events.back(), source_) : std::string(last_json);
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& e : events) {
    ++events_;
    ++by_status_[std::min<std::size_t>(static_cast<std::size_t>(e.status), kStatuses - 1)];
    if (e.alarm.transition()) {
      ++transitions_;
      alarm_since_t_s_ = e.t_s;
    }
    alarm_ = e.alarm;
    recent_.push_back(Compact{events_, e.t_s, e.zeta, e.zeta_ci95_lo, e.zeta_ci95_hi, e.f_hz, e.snr_db, e.status,
                              e.alarm.level});
    if (recent_.size() > kRecentEvents) recent_.pop_front();
  }
  last_event_json_ = std::move(last);
}

void Telemetry::set_counters(const DaemonCounters& c) {
  std::lock_guard<std::mutex> lock(mutex_);
  counters_ = c;
}

void Telemetry::observe_latency(double seconds) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (std::size_t i = 0; i < kLatencyBuckets.size(); ++i)
    if (seconds <= kLatencyBuckets[i]) ++latency_buckets_[i];  // cumulative buckets, as exposed
  ++latency_count_;
  latency_sum_ += seconds;
}

bool Telemetry::wants_envelope(const pipeline::ImpactEvent&) {
  // The page polls once a second: a few envelopes per second of wall time are all it can show (a
  // fast replay would otherwise copy and reduce a window for every fourth impact).
  const auto now = std::chrono::steady_clock::now();
  if (now - last_envelope_wall_ < std::chrono::duration<double>(kEnvelopeEvery_s)) return false;
  last_envelope_wall_ = now;
  return true;
}

void Telemetry::add_envelope(const pipeline::ImpactEvent& e, std::span<const float> window, std::uint64_t first) {
  if (window.empty()) return;
  Envelope env;
  env.t_s = e.t_s;
  env.zeta = e.zeta;
  env.lo = e.zeta_ci95_lo;
  env.hi = e.zeta_ci95_hi;
  env.f_hz = e.f_hz;
  const std::size_t per = (window.size() + kEnvelopePoints - 1) / kEnvelopePoints;
  env.dt_s = static_cast<double>(per) / fs_;
  // Time of the first point relative to the detected onset (negative: the pretrigger).
  env.onset_s = (static_cast<double>(first) - static_cast<double>(e.sample_index)) / fs_;
  env.env.reserve(kEnvelopePoints);
  for (std::size_t i = 0; i < window.size(); i += per) {
    float peak = 0.0f;
    for (std::size_t j = i; j < std::min(window.size(), i + per); ++j) peak = std::max(peak, std::fabs(window[j]));
    env.env.push_back(peak);
  }
  std::lock_guard<std::mutex> lock(mutex_);
  env.n = events_ + 1;  // called before on_events() for this event's block: refined below
  for (auto it = recent_.rbegin(); it != recent_.rend(); ++it)
    if (it->t_s == e.t_s) env.n = it->n;
  envelopes_.push_back(std::move(env));
  if (envelopes_.size() > kEnvelopes) envelopes_.pop_front();
}

std::uint64_t Telemetry::events_total() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return events_;
}

std::string Telemetry::prometheus_text() const {
  const Telemetry* self = this;
  return prometheus_exposition(std::span<const Telemetry* const>(&self, 1));
}

std::string prometheus_exposition(std::span<const Telemetry* const> telemetries) {
  std::vector<std::vector<MetricFamily>> all;
  all.reserve(telemetries.size());
  for (const Telemetry* t : telemetries) all.push_back(t->metric_families());
  std::string out;
  out.reserve(4096 * all.size());
  for (std::size_t f = 0; f < all.front().size(); ++f) {
    out += all.front()[f].header;
    for (const auto& families : all) out += families[f].samples;
  }
  return out;
}

std::vector<MetricFamily> Telemetry::metric_families() const {
  const MqttCounters m = mqtt_ ? mqtt_() : MqttCounters{};
  std::lock_guard<std::mutex> lock(mutex_);
  FamilyWriter w(stream_);
  const std::uint64_t one = 1;
  w.family("ridgewatch_build_info", "gauge", "ridgewatchd build and monitored source (always 1).");
  w.sample("ridgewatch_build_info",
           "version=\"" + prometheus_escape(version_) + "\",source=\"" + prometheus_escape(source_) + "\"", one);
  w.family("ridgewatch_events_total", "counter", "Impact events written, by status.");
  for (std::size_t i = 0; i < kStatuses; ++i)
    w.sample("ridgewatch_events_total",
             "status=\"" + std::string(pipeline::to_string(static_cast<pipeline::ImpactStatus>(i))) + "\"",
             by_status_[i]);
  w.one("ridgewatch_impacts_detected_total", "counter", "Impact onsets detected (each yields one event).",
        counters_.impacts_detected);
  w.one("ridgewatch_samples_total", "counter", "Input samples processed.", counters_.samples);
  w.one("ridgewatch_damping_ewma_ratio", "gauge",
        "EWMA of the damping ratio zeta (exp of the EWMA of ln zeta); NaN while learning.",
        zeta_of(alarm_.ewma_ln_zeta));
  w.one("ridgewatch_damping_baseline_ratio", "gauge",
        "Baseline damping ratio zeta (learned or configured); NaN while learning.",
        zeta_of(alarm_.baseline_ln_zeta));
  const double s_e = alarm_.baseline_ln_sd * std::sqrt(trend_.ewma_lambda / (2.0 - trend_.ewma_lambda));
  w.one("ridgewatch_damping_alert_limit_ratio", "gauge", "Damping ratio at which the EWMA enters alert (upper limit).",
        zeta_of(alarm_.baseline_ln_zeta + trend_.alert_sigma * s_e));
  w.one("ridgewatch_damping_danger_limit_ratio", "gauge",
        "Damping ratio at which the EWMA enters danger (upper limit).",
        zeta_of(alarm_.baseline_ln_zeta + trend_.danger_sigma * s_e));
  w.one("ridgewatch_alarm_level", "gauge", "Trend alarm level: 0 learning, 1 normal, 2 alert, 3 danger.",
        static_cast<std::uint64_t>(alarm_.level));
  w.one("ridgewatch_alarm_transitions_total", "counter", "Alarm level changes.", transitions_);
  w.family("ridgewatch_cusum", "gauge", "CUSUM of the standardised ln zeta, in baseline standard deviations.");
  w.sample("ridgewatch_cusum", "direction=\"up\"", alarm_.cusum_up);
  w.sample("ridgewatch_cusum", "direction=\"down\"", alarm_.cusum_down);
  w.one("ridgewatch_ring_overrun_samples_total", "counter",
        "Samples lost because the acquisition ring buffer was full.",
        counters_.overruns);
  w.one("ridgewatch_input_gaps_total", "counter", "Gaps in the input stream (xruns, device loss, overruns).",
        counters_.gaps);
  w.one("ridgewatch_input_spikes_total", "counter", "Isolated outlier samples removed before detection.",
        counters_.spikes);
  w.one("ridgewatch_event_write_failures_total", "counter", "Events that could not be written to the event log.",
        counters_.write_failures);
  w.family("ridgewatch_event_latency_seconds", "histogram",
           "Time from the end of an impact's decay window to its event being written (paced or live input only).");
  for (std::size_t i = 0; i < kLatencyBuckets.size(); ++i)
    w.sample("ridgewatch_event_latency_seconds_bucket", "le=\"" + prom_value(kLatencyBuckets[i]) + "\"",
             latency_buckets_[i]);
  w.sample("ridgewatch_event_latency_seconds_bucket", "le=\"+Inf\"", latency_count_);
  w.sample("ridgewatch_event_latency_seconds_sum", "", latency_sum_);
  w.sample("ridgewatch_event_latency_seconds_count", "", latency_count_);
  w.one("ridgewatch_mqtt_enabled", "gauge", "1 when output.mqtt is configured.", std::uint64_t{m.enabled});
  w.one("ridgewatch_mqtt_connected", "gauge", "1 while connected to the MQTT broker.", std::uint64_t{m.connected});
  w.one("ridgewatch_mqtt_spool_events", "gauge", "Events in the MQTT spool waiting for the broker's acknowledgement.",
        m.spool_events);
  w.one("ridgewatch_mqtt_spool_bytes", "gauge", "Size of the MQTT spool on disk.", m.spool_bytes);
  w.one("ridgewatch_mqtt_spool_dropped_total", "counter",
        "Events dropped from the full MQTT spool (oldest first) or not spooled (write error).",
        m.dropped);
  w.one("ridgewatch_mqtt_send_failures_total", "counter",
        "Failed MQTT connection attempts, publishes and lost connections.",
        m.send_failures);
  w.one("ridgewatch_mqtt_published_total", "counter",
        "Event messages acknowledged by the broker (QoS 1) or sent (QoS 0).",
        m.published);
  return w.take();
}

std::string Telemetry::state_json() const {
  const MqttCounters m = mqtt_ ? mqtt_() : MqttCounters{};
  std::unique_lock<std::mutex> lock(mutex_);
  using nlohmann::json;
  const double s_e = alarm_.baseline_ln_sd * std::sqrt(trend_.ewma_lambda / (2.0 - trend_.ewma_lambda));
  const double b = alarm_.baseline_ln_zeta;
  json j;
  j["source"] = source_;
  if (!stream_.empty()) j["stream"] = stream_;
  j["version"] = version_;
  j["events"] = events_;
  j["alarm"] = {{"level", trend::to_string(alarm_.level)},
                {"since_t_s", alarm_since_t_s_},
                {"cusum_up", alarm_.cusum_up},
                {"cusum_down", alarm_.cusum_down}};
  j["baseline_zeta"] = zeta_of(b);
  j["ewma_zeta"] = zeta_of(alarm_.ewma_ln_zeta);
  j["limits"] = {{"alert_hi", zeta_of(b + trend_.alert_sigma * s_e)},
                 {"danger_hi", zeta_of(b + trend_.danger_sigma * s_e)},
                 {"alert_lo", trend_.alarm_on_decrease ? zeta_of(b - trend_.alert_sigma * s_e) : NAN},
                 {"danger_lo", trend_.alarm_on_decrease ? zeta_of(b - trend_.danger_sigma * s_e) : NAN}};
  json st = json::object();
  for (std::size_t i = 0; i < kStatuses; ++i)
    if (by_status_[i] > 0) st[std::string(pipeline::to_string(static_cast<pipeline::ImpactStatus>(i)))] = by_status_[i];
  j["by_status"] = st;
  // Impact rate over the last 10 s of signal among the recent events.
  double rate = NAN;
  if (recent_.size() >= 2) {
    const double t_end = recent_.back().t_s;
    std::size_t k = 0;
    double t_first = t_end;
    for (auto it = recent_.rbegin(); it != recent_.rend() && t_end - it->t_s <= 10.0; ++it, ++k) t_first = it->t_s;
    if (k >= 2 && t_end > t_first) rate = static_cast<double>(k - 1) / (t_end - t_first);
  }
  j["impact_rate_hz"] = rate;
  j["health"] = {{"samples", counters_.samples},
                 {"overrun_samples", counters_.overruns},
                 {"gaps", counters_.gaps},
                 {"spikes", counters_.spikes},
                 {"write_failures", counters_.write_failures},
                 {"mqtt", {{"enabled", m.enabled}, {"connected", m.connected}, {"spool_events", m.spool_events},
                           {"dropped", m.dropped}, {"send_failures", m.send_failures}, {"published", m.published}}}};
  // The 300 recent events and the envelopes (most of the ~80 kB) are copied under the lock and
  // written by hand after it: the processing thread never waits for their serialisation, and a
  // request costs ~0.1 ms instead of ~1 ms with a JSON object per event.
  const std::vector<Compact> recent(recent_.begin(), recent_.end());
  const std::vector<Envelope> envelopes(envelopes_.begin(), envelopes_.end());
  lock.unlock();
  std::string out = j.dump(-1, ' ', false, json::error_handler_t::replace);
  out.pop_back();  // the closing brace; the two arrays follow
  out.reserve(out.size() + 160 * recent.size() + 1200 * envelopes.size() + 40);
  out += ",\"recent\":[";
  for (const auto& c : recent) {
    if (out.back() == '}') out += ',';
    out += "{\"n\":";
    json_number(out, c.n);
    for (const auto& [key, v] : {std::pair{",\"t_s\":", c.t_s}, {",\"zeta\":", c.zeta}, {",\"lo\":", c.lo},
                                 {",\"hi\":", c.hi}, {",\"f_hz\":", c.f_hz}, {",\"snr_db\":", c.snr_db}}) {
      out += key;
      json_number(out, v);
    }
    out += ",\"status\":\"";
    out += pipeline::to_string(c.status);
    out += "\",\"alarm\":\"";
    out += trend::to_string(c.alarm);
    out += "\"}";
  }
  out += "],\"envelopes\":[";
  for (const auto& e : envelopes) {
    if (out.back() == ']' || out.back() == '}') out += ',';
    out += "{\"n\":";
    json_number(out, e.n);
    for (const auto& [key, v] : {std::pair{",\"t_s\":", e.t_s}, {",\"zeta\":", e.zeta}, {",\"lo\":", e.lo},
                                 {",\"hi\":", e.hi}, {",\"f_hz\":", e.f_hz}, {",\"dt_s\":", e.dt_s},
                                 {",\"start_s\":", e.onset_s}}) {
      out += key;
      json_number(out, v);
    }
    out += ",\"envelope\":[";
    for (std::size_t i = 0; i < e.env.size(); ++i) {
      if (i > 0) out += ',';
      json_number(out, e.env[i]);
    }
    out += "]}";
  }
  out += "]}";
  return out;
}

std::string Telemetry::status_json() const {
  const MqttCounters m = mqtt_ ? mqtt_() : MqttCounters{};
  std::lock_guard<std::mutex> lock(mutex_);
  using nlohmann::json;
  json j;
  j["state"] = "online";
  j["source"] = source_;
  j["alarm"] = trend::to_string(alarm_.level);
  j["baseline_zeta"] = zeta_of(alarm_.baseline_ln_zeta);
  j["ewma_zeta"] = zeta_of(alarm_.ewma_ln_zeta);
  j["events"] = events_;
  j["events_ok"] = by_status_[0];
  j["samples"] = counters_.samples;
  j["overrun_samples"] = counters_.overruns;
  j["gaps"] = counters_.gaps;
  j["spool_events"] = m.spool_events;
  j["spool_dropped"] = m.dropped;
  j["last_seq"] = m.last_seq;
  j["last_event"] = last_event_json_.empty() ? json(nullptr) : json::parse(last_event_json_, nullptr, false);
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

}  // namespace ridgewatch::daemon
