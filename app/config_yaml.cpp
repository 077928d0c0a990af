#include "app/config_yaml.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>
#include <sstream>
#include <stdexcept>

#include "app/rig_defaults.hpp"
#include "app/yaml_reader.hpp"

namespace ridgewatch::app {

namespace {

// The pipeline section, at the top level and in each of `streams`.
template <typename V>
void walk_pipeline(pipeline::PipelineConfig& p, V& v) {
  auto& d = p.detector;
  auto& a = p.analyzer;
  auto& t = p.trend;
  v.map("detector", [&] {
    v.num("band_lo_hz", d.band_lo_hz);
    v.num("band_hi_hz", d.band_hi_hz);
    v.num("sta_s", d.sta_s);
    v.num("lta_s", d.lta_s);
    v.num("trigger_ratio", d.trigger_ratio);
    v.num("holdoff_s", d.holdoff_s);
    v.num("spike_mad", d.spike_mad);
    v.flag("trigger_innovation", d.trigger_innovation);
    v.num("trigger_noise_ratio", d.trigger_noise_ratio);
  });
  v.map("analyzer", [&] {
    v.num("f_expected_hz", a.f_expected_hz);
    v.num("band_rel", a.band_rel);
    v.num("eta0", a.eta0);
    v.num("pretrigger_s", a.pretrigger_s);
    v.num("window_s", a.window_s);
    v.method("method", a.method);
    v.num("min_snr_db", a.min_snr_db);
    v.num("max_ci_ratio", a.max_ci_ratio);
    v.nullable("clip_level", a.clip_level);  // null: from the source format (resolve_format_defaults)
    v.num("ml_band_rel", a.ml_band_rel);
  });
  v.map("trend", [&] {
    v.count("baseline_events", t.baseline_events, 1, 1 << 20);
    v.nullable("baseline_zeta", t.baseline_zeta);
    v.nullable("baseline_ln_sd", t.baseline_ln_sd);
    v.num("min_baseline_ln_sd", t.min_baseline_ln_sd);
    v.num("ewma_lambda", t.ewma_lambda);
    v.num("alert_sigma", t.alert_sigma);
    v.num("danger_sigma", t.danger_sigma);
    v.num("cusum_k", t.cusum_k);
    v.num("cusum_h", t.cusum_h);
    v.unbounded("clip_sigma", t.clip_sigma);
    v.num("hysteresis_sigma", t.hysteresis_sigma);
    v.count("confirm_k", t.confirm_k, 1, 64);
    v.count("confirm_n", t.confirm_n, 1, 64);
    v.flag("latching", t.latching);
    v.flag("alarm_on_decrease", t.alarm_on_decrease);
  });
}

template <typename V>
void walk_combine(CombineConfig& k, V& v) {
  v.text("type", k.type);
  v.indices("channels", k.channels, 1023);
  v.numbers("coefficients", k.coefficients);
  v.numbers("sensitivity", k.sensitivity);
}

// One entry of `streams` (the keys it may give; its pipeline overlays the top-level one).
template <typename V>
void walk_stream(StreamConfig& s, V& v) {
  v.text("name", s.name);
  v.count("channel", s.channel, 0, 1023);
  v.map("combine", [&] { walk_combine(s.combine, v); });
  v.text("path", s.path);
  v.text("rig", s.rig);
  v.map("pipeline", [&] { walk_pipeline(s.pipeline, v); });
  v.map("gpio", [&] {
    v.count("alert_line", s.alert_line, -1, 4095);
    v.count("danger_line", s.danger_line, -1, 4095);
  });
}

// One description of the file layout, walked by the parser and by the printer, so the two cannot
// drift apart. Range checks live in the components' validate() functions and in check_sources().
template <typename V>
void walk(RidgewatchConfig& c, V& v) {
  v.text("rig", c.rig);
  v.map("source", [&] {
    v.text("type", c.source.type);
    v.num("ring_buffer_s", c.source.ring_buffer_s);
    v.map("combine", [&] { walk_combine(c.source.combine, v); });
    v.map("replay", [&] {
      v.text("path", c.source.replay.path);
      v.count("channel", c.source.replay.channel, 0, 1023);
      v.num("rate_hz", c.source.replay.rate_hz);
      v.num("speed", c.source.replay.speed);
      v.flag("loop", c.source.replay.loop);
    });
    v.map("alsa", [&] {
      v.text("device", c.source.alsa.device);
      v.num("rate_hz", c.source.alsa.rate_hz);
      v.count("channels", c.source.alsa.channels, 1, 64);
      v.count("channel", c.source.alsa.channel, 0, 63);
      v.text("format", c.source.alsa.format);
      v.count("period_frames", c.source.alsa.period_frames, 16, 1 << 20);
      v.count("buffer_frames", c.source.alsa.buffer_frames, 32, 1 << 22);
      v.num("retry_min_s", c.source.alsa.retry_min_s);
      v.num("retry_max_s", c.source.alsa.retry_max_s);
    });
  });
  v.map("pipeline", [&] { walk_pipeline(c.pipeline, v); });
  v.map("output", [&] {
    v.text("events", c.output.events);
    v.text("csv", c.output.csv);
    v.map("capture", [&] {
      v.text("dir", c.output.capture.dir);
      v.count("max_files", c.output.capture.max_files, 0, 1LL << 40);
      v.count("max_bytes", c.output.capture.max_bytes, 0, 1LL << 60);
      v.text("select", c.output.capture.select);
    });
    v.legacy_text("capture_dir", c.output.capture.dir);  // old spelling of capture.dir, read only
    v.text("source_name", c.output.source_name);
    v.map("mqtt", [&] {
      auto& m = c.output.mqtt;
      v.text("host", m.host);
      v.count("port", m.port, 1, 65535);
      v.text("topic_prefix", m.topic_prefix);
      v.text("client_id", m.client_id);
      v.count("qos", m.qos, 0, 1);
      v.text("username", m.username);
      v.text("password_file", m.password_file);
      v.map("tls", [&] {
        v.text("ca_file", m.tls.ca_file);
        v.text("cert_file", m.tls.cert_file);
        v.text("key_file", m.tls.key_file);
      });
      v.text("spool_dir", m.spool_dir);
      v.num("spool_max_mb", m.spool_max_mb);
      v.num("keepalive_s", m.keepalive_s);
    });
  });
  v.map("gpio", [&] {
    v.flag("enabled", c.gpio.enabled);
    v.text("chip", c.gpio.chip);
    v.count("tacho_line", c.gpio.tacho_line, -1, 4095);
    v.count("alert_line", c.gpio.alert_line, -1, 4095);
    v.count("danger_line", c.gpio.danger_line, -1, 4095);
    v.flag("active_low", c.gpio.active_low);
  });
  v.map("logging", [&] {
    v.text("level", c.logging.level);
    v.num("repeat_interval_s", c.logging.repeat_interval_s);
    v.num("status_interval_s", c.logging.status_interval_s);
  });
  v.map("http", [&] { v.text("listen", c.http.listen); });
  v.count("workers", c.workers, 0, 256);
  v.streams("streams");  // read after the top level (parse_streams): each overlays its pipeline
}

// Parser: overlays the YAML onto the defaults, rejecting unknown keys.
class Parser {
 public:
  /// `root_path`: where `root` sits in the file ("streams[2]" for an entry of streams), for messages.
  Parser(const YamlReader& r, const YAML::Node& root, std::string root_path = "") : r_(r), prefix_(root_path) {
    stack_.push_back({root, std::move(root_path)});
  }

  void map(const char* key, const std::function<void()>& body) {
    // Collect the keys this section knows by running the body once in "key collection" mode.
    const Frame& parent = stack_.back();
    const std::string path = YamlReader::join(parent.path, key);
    const YAML::Node node = parent.node.IsMap() ? parent.node[key] : YAML::Node();
    known_.back().insert(key);
    if (!node || node.IsNull()) {
      collect_only(body);
      return;
    }
    stack_.push_back({node, path});
    known_.emplace_back();
    body();
    r_.check_map(node, path, known_.back());
    known_.pop_back();
    stack_.pop_back();
  }
  void num(const char* key, double& v) { visit(key, [&](const YAML::Node& p, const std::string& path) { r_.read(p, path, key, v); }); }
  void flag(const char* key, bool& v) { visit(key, [&](const YAML::Node& p, const std::string& path) { r_.read(p, path, key, v); }); }
  void text(const char* key, std::string& v) { visit(key, [&](const YAML::Node& p, const std::string& path) { r_.read(p, path, key, v); }); }
  template <typename Int>
  void count(const char* key, Int& v, long long lo, long long hi) {
    visit(key, [&](const YAML::Node& p, const std::string& path) { r_.read_count(p, path, key, v, lo, hi); });
  }
  void nullable(const char* key, double& v) {
    visit(key, [&](const YAML::Node& p, const std::string& path) {
      const YAML::Node n = p[key];
      if (n && n.IsNull()) {
        v = NAN;
      } else {
        r_.read(p, path, key, v);
      }
    });
  }
  /// null means "no limit" (+infinity).
  void unbounded(const char* key, double& v) {
    visit(key, [&](const YAML::Node& p, const std::string& path) {
      const YAML::Node n = p[key];
      if (n && n.IsNull()) {
        v = INFINITY;
      } else {
        r_.read(p, path, key, v);
      }
    });
  }
  void method(const char* key, dsp::DampingMethod& m) {
    visit(key, [&](const YAML::Node& p, const std::string& path) {
      std::string text;
      r_.read(p, path, key, text);
      if (!p[key]) return;
      if (!dsp::parse_damping_method(text, m))
        r_.fail(YamlReader::join(path, key), "must be one of two-point, ridge-ls, ml (got '" + text + "')");
    });
  }
  /// A flow or block sequence of numbers.
  void numbers(const char* key, std::vector<double>& v) {
    visit(key, [&](const YAML::Node& p, const std::string& path) {
      const YAML::Node n = p[key];
      if (!n || n.IsNull()) return;
      const std::string where = YamlReader::join(path, key);
      if (!n.IsSequence()) r_.fail(where, "must be a list of numbers, e.g. [1, 0.5]");
      v.clear();
      for (std::size_t i = 0; i < n.size(); ++i) v.push_back(r_.number(n[i], where + "[" + std::to_string(i) + "]"));
    });
  }
  /// A sequence of whole numbers in [0, hi] (channel indices).
  void indices(const char* key, std::vector<std::size_t>& v, std::size_t hi) {
    std::vector<double> x;
    numbers(key, x);
    if (collecting_ || x.empty()) return;
    const std::string where = YamlReader::join(stack_.back().path, key);
    v.clear();
    for (std::size_t i = 0; i < x.size(); ++i) {
      if (x[i] != std::floor(x[i]) || x[i] < 0 || x[i] > static_cast<double>(hi))
        r_.fail(where + "[" + std::to_string(i) + "]",
                "must be a whole number in [0, " + std::to_string(hi) + "] (got " + YamlReader::format(x[i]) + ")");
      v.push_back(static_cast<std::size_t>(x[i]));
    }
  }
  /// An old spelling: read like text() (overriding the new key only when given), never printed.
  void legacy_text(const char* key, std::string& v) {
    visit(key, [&](const YAML::Node& p, const std::string& path) {
      if (!p[key]) return;
      const std::string before = v;
      r_.read(p, path, key, v);
      if (!before.empty() && before != v)
        r_.fail(YamlReader::join(path, key), "old spelling of capture.dir; give only one of the two");
    });
  }
  /// A key read later by its own code (streams: parse_streams); only marked as known here.
  void streams(const char* key) { known_.back().insert(key); }
  void check_top() { r_.check_map(stack_.front().node, prefix_, known_.front()); }
  /// The YAML paths given, relative to the root ("pipeline.analyzer.f_expected_hz").
  std::set<std::string> given() const {
    if (prefix_.empty()) return given_;
    std::set<std::string> relative;
    for (const auto& g : given_) relative.insert(g.substr(prefix_.size() + 1));
    return relative;
  }

 private:
  struct Frame {
    YAML::Node node;
    std::string path;
  };

  template <typename F>
  void visit(const char* key, F&& read) {
    known_.back().insert(key);
    if (collecting_) return;
    const Frame& f = stack_.back();
    if (f.node.IsMap() && f.node[key]) given_.insert(YamlReader::join(f.path, key));
    read(f.node, f.path);
  }
  void collect_only(const std::function<void()>& body) {
    // The section is absent: nothing to read, but nested map() calls still need a frame.
    const bool was = collecting_;
    collecting_ = true;
    known_.emplace_back();
    stack_.push_back({YAML::Node(), ""});
    body();
    stack_.pop_back();
    known_.pop_back();
    collecting_ = was;
  }

  const YamlReader& r_;
  std::string prefix_;
  std::vector<Frame> stack_;
  std::vector<std::set<std::string>> known_{1};
  bool collecting_ = false;
  std::set<std::string> given_;
};

// Printer: writes the current values in the same layout.
class Printer {
 public:
  void map(const char* key, const std::function<void()>& body) {
    line(key, "");
    ++depth_;
    body();
    --depth_;
  }
  void num(const char* key, double v) { line(key, YamlReader::format(v)); }
  void nullable(const char* key, double v) { line(key, std::isfinite(v) ? YamlReader::format(v) : "null"); }
  void unbounded(const char* key, double v) { line(key, std::isfinite(v) ? YamlReader::format(v) : "null"); }
  void flag(const char* key, bool v) { line(key, v ? "true" : "false"); }
  void text(const char* key, const std::string& v) {
    YAML::Emitter e;
    e << YAML::DoubleQuoted << v;
    line(key, e.c_str());
  }
  template <typename Int>
  void count(const char* key, Int v, long long, long long) { line(key, std::to_string(v)); }
  void method(const char* key, dsp::DampingMethod m) { line(key, std::string(dsp::to_string(m))); }
  void legacy_text(const char*, const std::string&) {}
  void streams(const char*) {}  // not printed (config_yaml.hpp)
  void numbers(const char* key, const std::vector<double>& v) {
    std::string t = "[";
    for (std::size_t i = 0; i < v.size(); ++i) t += (i ? ", " : "") + YamlReader::format(v[i]);
    line(key, t + "]");
  }
  void indices(const char* key, const std::vector<std::size_t>& v, std::size_t) {
    std::string t = "[";
    for (std::size_t i = 0; i < v.size(); ++i) t += (i ? ", " : "") + std::to_string(v[i]);
    line(key, t + "]");
  }
  std::string str() const { return out_.str(); }

 private:
  void line(const char* key, const std::string& value) {
    out_ << std::string(2 * depth_, ' ') << key << ":" << (value.empty() ? "" : " " + value) << "\n";
  }
  std::ostringstream out_;
  int depth_ = 0;
};

void check_values(const YamlReader& r, const RidgewatchConfig& c) {
  const SourceConfig& s = c.source;
  if (s.type != "replay" && s.type != "alsa") r.fail("source.type", "must be replay or alsa (got '" + s.type + "')");
  if (!(s.ring_buffer_s >= 0.05 && s.ring_buffer_s <= 600))
    r.fail("source.ring_buffer_s", "must be in [0.05, 600] s (got " + YamlReader::format(s.ring_buffer_s) + ")");
  if (s.replay.rate_hz != 0 && !(s.replay.rate_hz >= 100 && s.replay.rate_hz <= 5e6))
    r.fail("source.replay.rate_hz", "must be 0 (not given) or in [100, 5000000] Hz (got " + YamlReader::format(s.replay.rate_hz) + ")");
  if (!(s.replay.speed >= 0 && s.replay.speed <= 1e6))
    r.fail("source.replay.speed", "must be 0 (as fast as possible) or a factor > 0 (got " + YamlReader::format(s.replay.speed) + ")");
  if (!(s.alsa.rate_hz >= 100 && s.alsa.rate_hz <= 5e6))
    r.fail("source.alsa.rate_hz", "must be in [100, 5000000] Hz (got " + YamlReader::format(s.alsa.rate_hz) + ")");
  if (s.alsa.channel >= s.alsa.channels)
    r.fail("source.alsa.channel", "must be below source.alsa.channels (" + std::to_string(s.alsa.channels) + ")");
  if (s.alsa.format != "S16_LE" && s.alsa.format != "S32_LE" && s.alsa.format != "FLOAT_LE")
    r.fail("source.alsa.format", "must be S16_LE, S32_LE or FLOAT_LE (got '" + s.alsa.format + "')");
  if (s.alsa.buffer_frames < 2 * s.alsa.period_frames)
    r.fail("source.alsa.buffer_frames", "must be at least 2 x source.alsa.period_frames");
  if (!(s.alsa.retry_min_s > 0 && s.alsa.retry_max_s >= s.alsa.retry_min_s && s.alsa.retry_max_s <= 3600))
    r.fail("source.alsa.retry_min_s", "need 0 < retry_min_s <= retry_max_s <= 3600 s");
  combine_gains(c, r.name(), s.type == "alsa" ? s.alsa.channels : 0, false);
  if (c.output.events.empty()) r.fail("output.events", "must be a path or - (standard output)");
  if (const auto& sel = c.output.capture.select; sel != "all" && sel != "not_ok" && sel != "alarm")
    r.fail("output.capture.select", "must be all, not_ok or alarm (got '" + sel + "')");
  static const std::set<std::string> levels = {"trace", "debug", "info", "warn", "error"};
  if (!levels.count(c.logging.level)) r.fail("logging.level", "must be trace, debug, info, warn or error (got '" + c.logging.level + "')");
  if (!(c.logging.repeat_interval_s >= 0)) r.fail("logging.repeat_interval_s", "must be >= 0");
  if (!(c.logging.status_interval_s > 0)) r.fail("logging.status_interval_s", "must be > 0");
  if (const MqttConfig& m = c.output.mqtt; !m.host.empty()) {
    if (m.spool_dir.empty()) r.fail("output.mqtt.spool_dir", "must name a directory when output.mqtt.host is set");
    if (!(m.spool_max_mb >= 0.01 && m.spool_max_mb <= 1e6))
      r.fail("output.mqtt.spool_max_mb", "must be in [0.01, 1000000] MB (got " + YamlReader::format(m.spool_max_mb) + ")");
    if (!(m.keepalive_s >= 5 && m.keepalive_s <= 65535))
      r.fail("output.mqtt.keepalive_s", "must be in [5, 65535] s (got " + YamlReader::format(m.keepalive_s) + ")");
    if (m.tls.cert_file.empty() != m.tls.key_file.empty())
      r.fail("output.mqtt.tls", "cert_file and key_file must be given together");
    if (!m.tls.cert_file.empty() && m.tls.ca_file.empty())
      r.fail("output.mqtt.tls.ca_file", "must be set when a client certificate is given");
    if (!m.password_file.empty() && m.username.empty())
      r.fail("output.mqtt.username", "must be set when output.mqtt.password_file is");
    if (m.topic_prefix.find_first_of("+#") != std::string::npos)
      r.fail("output.mqtt.topic_prefix", "must not contain the MQTT wildcards + or #");
  }
  if (!c.http.listen.empty()) {
    const auto colon = c.http.listen.rfind(':');
    bool ok = colon != std::string::npos && colon > 0 && colon + 1 < c.http.listen.size();
    long port = 0;
    if (ok) {
      const std::string p = c.http.listen.substr(colon + 1);
      ok = p.find_first_not_of("0123456789") == std::string::npos && p.size() <= 5;
      if (ok) port = std::stol(p);
    }
    if (!ok || port < 1 || port > 65535)
      r.fail("http.listen", "must be ADDRESS:PORT with a port in [1, 65535], e.g. 127.0.0.1:9420 (got '" + c.http.listen + "')");
  }
  if (c.gpio.enabled && c.gpio.chip.empty()) r.fail("gpio.chip", "must name a GPIO chip when gpio.enabled");
  // The pipeline's own checks. A replayed file's rate is known only when it opens (the checks run
  // again then, with the real rate); here the largest accepted rate stands in for it.
  pipeline::PipelineConfig p = c.pipeline;
  p.sample_rate_hz = s.type == "alsa" ? s.alsa.rate_hz : 5e6;
  try {
    pipeline::validate(p);
  } catch (const std::invalid_argument& e) {
    r.fail("", std::string("pipeline.") + e.what());
  }
}

}  // namespace

namespace {
// combine_gains for the combination `k` at YAML path `where`, radii from `rig`.
std::vector<double> gains_of(const CombineConfig& k, const RigModelInfo& rig, const std::string& name,
                             const std::string& where, std::size_t available, bool need_rig) {
  auto fail = [&](const std::string& key, const std::string& what) {
    throw UsageError(name + ": " + where + "." + key + ": " + what);
  };
  const std::size_t n = k.channels.size();
  if (k.type == "none") {
    if (n || !k.coefficients.empty() || !k.sensitivity.empty())
      fail("type", "is none, but channels/coefficients/sensitivity are given (set type: mesh_velocity or coefficients)");
    return {};
  }
  if (k.type != "mesh_velocity" && k.type != "coefficients")
    fail("type", "must be none, mesh_velocity or coefficients (got '" + k.type + "')");
  if (n == 0) fail("channels", "must list the input channels combined (e.g. [0, 1])");
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < i; ++j)
      if (k.channels[j] == k.channels[i])
        fail("channels", "channel " + std::to_string(k.channels[i]) + " is listed twice");
    if (available > 0 && k.channels[i] >= available)
      fail("channels[" + std::to_string(i) + "]",
           "channel " + std::to_string(k.channels[i]) + " out of range (the source has " + std::to_string(available) +
               " channels, 0-" + std::to_string(available - 1) + ")");
  }
  if (!k.sensitivity.empty() && k.sensitivity.size() != n)
    fail("sensitivity",
         "needs one value per channel (" + std::to_string(n) + "), got " + std::to_string(k.sensitivity.size()));
  for (std::size_t i = 0; i < k.sensitivity.size(); ++i)
    if (!(k.sensitivity[i] > 0)) fail("sensitivity[" + std::to_string(i) + "]", "must be > 0");
  std::vector<double> coef;
  if (k.type == "mesh_velocity") {
    if (n != 2)
      fail("channels", "mesh_velocity needs exactly two channels, [φ̇1 of the pinion, φ̇2 of the wheel] (got " +
                           std::to_string(n) + ")");
    if (!k.coefficients.empty()) fail("coefficients", "are taken from the rig file for mesh_velocity; leave them out");
    if (rig.path.empty()) {
      if (need_rig) fail("type", "mesh_velocity needs the rig file (key rig, or --rig) for the base radii rb1, rb2");
      coef = {0.0, 0.0};
    } else {
      coef = {rig.rb1_m, rig.rb2_m};  // q̇ = r_b1 φ̇1 + r_b2 φ̇2, paper Appendix A
    }
  } else {
    if (k.coefficients.size() != n)
      fail("coefficients",
           "needs one value per channel (" + std::to_string(n) + "), got " + std::to_string(k.coefficients.size()));
    coef = k.coefficients;
  }
  for (std::size_t i = 0; i < n; ++i)
    if (!k.sensitivity.empty()) coef[i] /= k.sensitivity[i];
  return coef;
}
}  // namespace

std::vector<double> combine_gains(const RidgewatchConfig& c, const std::string& name, std::size_t available,
                                  bool need_rig) {
  return gains_of(c.source.combine, c.rig_model, name, "source.combine", available, need_rig);
}

std::vector<double> combine_gains(const StreamConfig& s, const std::string& name, const std::string& key,
                                  std::size_t available, bool need_rig) {
  return gains_of(s.combine, s.rig_model, name, key, available, need_rig);
}

void check_stream_channels(const RidgewatchConfig& c, const std::string& name, std::size_t i, std::size_t available) {
  const StreamConfig& s = c.streams.at(i);
  const std::string key = "streams[" + std::to_string(i) + "]";
  if (s.combine.type != "none") {
    combine_gains(s, name, key + ".combine", available, false);
    return;
  }
  if (s.channel >= available)
    throw UsageError(name + ": " + key + ".channel: channel " + std::to_string(s.channel) + " out of range (the source has " +
                     std::to_string(available) + " channels, 0-" + std::to_string(available - 1) + ")");
}

RidgewatchConfig default_config() {
  RidgewatchConfig c;
  c.pipeline.analyzer.clip_level = NAN;  // from the source's format when it opens
  return c;
}

void resolve_format_defaults(pipeline::PipelineConfig& p, std::optional<double> full_scale) {
  if (std::isnan(p.analyzer.clip_level) && full_scale) p.analyzer.clip_level = 0.999 * *full_scale;
}

namespace {
// A stream name goes into events, topics and directory names: a short plain word.
bool plain_name(const std::string& n) {
  return !n.empty() && n.size() <= 64 &&
         n.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-") == std::string::npos &&
         n != "." && n != "..";
}

// streams[i]: the top-level pipeline (with its rig's defaults) overlaid by the stream's keys, then
// by the stream's own rig for the keys neither gives.
StreamConfig parse_stream(const YamlReader& r, const YAML::Node& node, const RidgewatchConfig& c, std::size_t i) {
  const std::string key = "streams[" + std::to_string(i) + "]";
  if (!node.IsMap()) r.fail(key, "must be a mapping (name, channel or combine, pipeline, gpio, ...)");
  StreamConfig s;
  s.pipeline = c.pipeline;
  s.rig_model = c.rig_model;
  Parser p(r, node, key);
  walk_stream(s, p);
  p.check_top();
  s.given = c.given;
  for (const auto& g : p.given()) s.given.insert(g);
  if (!node["name"]) r.fail(key + ".name", "missing (required: the events' stream field)");
  if (!plain_name(s.name))
    r.fail(key + ".name", "must be 1-64 letters, digits, '_', '.' or '-' (got '" + s.name + "')");
  for (std::size_t j = 0; j < c.streams.size(); ++j)
    if (c.streams[j].name == s.name)
      r.fail(key + ".name", "'" + s.name + "' is also the name of streams[" + std::to_string(j) + "]; names must differ");
  if (node["channel"] && s.combine.type != "none") r.fail(key + ".channel", "give either channel or combine, not both");
  if (!s.path.empty() && c.source.type != "replay") r.fail(key + ".path", "only with source.type replay");
  if (!s.rig.empty()) {
    std::filesystem::path rig(s.rig);
    if (rig.is_relative()) rig = std::filesystem::path(r.name()).parent_path() / rig;
    RidgewatchConfig t;
    t.given = s.given;
    t.pipeline = s.pipeline;
    apply_rig_defaults(t, rig.string(), r.name() + ": " + key + ".rig");
    s.pipeline = t.pipeline;
    s.rig_model = t.rig_model;
  }
  pipeline::PipelineConfig v = s.pipeline;
  v.sample_rate_hz = c.source.type == "alsa" ? c.source.alsa.rate_hz : 5e6;  // as check_values
  try {
    pipeline::validate(v);
  } catch (const std::invalid_argument& e) {
    r.fail(key, std::string("pipeline.") + e.what());
  }
  if ((s.alert_line >= 0 || s.danger_line >= 0) && !c.gpio.enabled) r.fail(key + ".gpio", "relay lines need gpio.enabled: true");
  return s;
}

void parse_streams(const YamlReader& r, const YAML::Node& root, RidgewatchConfig& c) {
  const YAML::Node list = root["streams"];
  if (!list || list.IsNull()) return;
  if (!list.IsSequence()) r.fail("streams", "must be a list of streams (- name: ..., channel: ...)");
  if (list.size() == 0) return;
  if (c.source.combine.type != "none") r.fail("source.combine", "not with streams: give each stream its own combine");
  std::vector<std::pair<int, std::string>> lines;  // relay and tacho lines in use, and by whom
  for (const auto& [line, who] : {std::pair{c.gpio.tacho_line, "gpio.tacho_line"}, {c.gpio.alert_line, "gpio.alert_line"},
                                  {c.gpio.danger_line, "gpio.danger_line"}})
    if (line >= 0) lines.emplace_back(line, who);
  for (std::size_t i = 0; i < list.size(); ++i) {
    c.streams.push_back(parse_stream(r, list[i], c, i));
    const StreamConfig& s = c.streams.back();
    const std::string key = "streams[" + std::to_string(i) + "]";
    combine_gains(s, r.name(), key + ".combine", c.source.type == "alsa" ? c.source.alsa.channels : 0, false);
    if (c.source.type == "alsa") check_stream_channels(c, r.name(), i, c.source.alsa.channels);
    for (const auto& [line, who] : {std::pair{s.alert_line, key + ".gpio.alert_line"}, {s.danger_line, key + ".gpio.danger_line"}}) {
      if (line < 0) continue;
      for (const auto& [used, by] : lines)
        if (used == line) r.fail(who, "line " + std::to_string(line) + " is already " + by);
      lines.emplace_back(line, who);
    }
  }
}

RidgewatchConfig parse_config_unguarded(const std::string& text, const std::string& name) {
  const YamlReader r(name);
  const YAML::Node root = r.parse(text);
  RidgewatchConfig c = default_config();
  if (root.IsNull()) {  // an empty file means all defaults
    check_values(r, c);
    return c;
  }
  Parser p(r, root);
  walk(c, p);
  p.check_top();
  c.given = p.given();
  if (!c.rig.empty()) {
    // Relative to the configuration file's directory, like any path a deployment ships beside it.
    std::filesystem::path rig(c.rig);
    if (rig.is_relative()) rig = std::filesystem::path(name).parent_path() / rig;
    apply_rig_defaults(c, rig.string(), name + ": rig");
  }
  check_values(r, c);
  parse_streams(r, root, c);
  return c;
}
}  // namespace

RidgewatchConfig parse_config(const std::string& text, const std::string& name) {
  // Any structure yaml-cpp itself rejects while the keys are read (e.g. a subscript of a scalar, a
  // key that is not a scalar) is a configuration error with the file's name and yaml-cpp's line and
  // column, never an internal error (found by fuzz/fuzz_config).
  try {
    return parse_config_unguarded(text, name);
  } catch (const YAML::Exception& e) {
    throw UsageError(name + ": unexpected YAML structure: " + e.what());
  }
}

RidgewatchConfig load_config_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw UsageError(path + ": cannot open configuration file");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_config(text.str(), path);
}

std::string to_yaml(const RidgewatchConfig& config) {
  RidgewatchConfig c = config;
  Printer p;
  walk(c, p);
  return p.str();
}

}  // namespace ridgewatch::app
