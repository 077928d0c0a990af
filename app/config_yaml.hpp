// The ridgewatch configuration file (YAML): one place maps every component's Config struct to keys.
// `config/ridgewatch.yaml` documents every key with unit and default; `ridgewatchd --print-defaults`
// prints the defaults in the same layout. Unknown or mistyped keys, wrong types and out-of-range values
// are UsageErrors (exit 2) naming the file and the YAML path, e.g.
//   "ridgewatch.yaml: pipeline.analyzer.window_s: must be > 0 (got 0)".
#pragma once

#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "core/pipeline/stream_processor.hpp"

namespace ridgewatch::app {

struct ReplaySourceConfig {
  std::string path;            ///< file to replay (required when source.type is replay)
  std::size_t channel = 0;     ///< 0-based channel
  double rate_hz = 0.0;        ///< sample rate of one-column CSV files; 0: not given
  double speed = 1.0;          ///< 1 = real time, N = N x real time, 0 = as fast as possible
  bool loop = false;           ///< start again at the end (sample indices keep counting)
};

struct AlsaSourceConfig {
  std::string device = "default";
  double rate_hz = 51200.0;
  std::size_t channels = 1;
  std::size_t channel = 0;
  std::string format = "S32_LE";  ///< S16_LE, S32_LE or FLOAT_LE
  std::size_t period_frames = 256;   ///< 5 ms at 51.2 kHz: the period adds to the event latency
  std::size_t buffer_frames = 4096;
  double retry_min_s = 0.5;       ///< device loss: first retry after this, doubling
  double retry_max_s = 30.0;      ///< up to this
};

/// source.combine: the stream analysed is a linear combination of input channels (a derived channel),
/// y = sum_i c_i x_i / s_i with s_i the channel's sensitivity (input units per physical unit).
struct CombineConfig {
  /// none (one channel: source.replay.channel / source.alsa.channel), mesh_velocity (q̇ = r_b1 φ̇1 +
  /// r_b2 φ̇2, paper Appendix A; c = rb1, rb2 of the `rig` file; channels φ̇1, φ̇2 in rad/s after the
  /// sensitivity; y in m/s) or coefficients (c from `coefficients`).
  std::string type = "none";
  std::vector<std::size_t> channels;  ///< 0-based input channels
  std::vector<double> coefficients;   ///< type coefficients: one per channel
  std::vector<double> sensitivity;    ///< one per channel (input units per rad/s or per unit), > 0; [] = all 1
};

struct SourceConfig {
  std::string type = "replay";  ///< replay or alsa
  CombineConfig combine;
  ReplaySourceConfig replay;
  AlsaSourceConfig alsa;
  double ring_buffer_s = 4.0;   ///< acquisition ring buffer length (rounded up to a power of two samples)
};

/// output.mqtt: events, status and alarm transitions to an MQTT broker (off while host is empty).
struct MqttTlsConfig {
  std::string ca_file;    ///< CA certificate (PEM) that verifies the broker; set to enable TLS
  std::string cert_file;  ///< client certificate (PEM), with key_file, for mutual TLS
  std::string key_file;
};

struct MqttConfig {
  std::string host;               ///< broker host name or address; empty: MQTT off
  std::size_t port = 1883;        ///< broker TCP port
  std::string topic_prefix;       ///< empty: ridgewatch/<source_name>
  std::string client_id;          ///< empty: ridgewatch-<source_name>
  std::size_t qos = 1;            ///< 0 or 1 (1: the spool keeps an event until the broker's PUBACK)
  std::string username;
  std::string password_file;      ///< the password is read from this file, never from the config
  MqttTlsConfig tls;
  std::string spool_dir = "/var/lib/ridgewatch/spool";  ///< on-disk store-and-forward queue
  double spool_max_mb = 64.0;     ///< spool size bound, MB; when full the oldest events are dropped and counted
  double keepalive_s = 30.0;      ///< MQTT keep-alive, s
};

/// http: Prometheus /metrics and the live page (off while listen is empty).
struct HttpConfig {
  std::string listen;             ///< "ADDRESS:PORT", e.g. "127.0.0.1:9420"; empty: off
};

/// Capture-on-trigger (`output.capture`): each selected impact window as WAV + sidecar JSON, bounded.
struct CaptureConfig {
  std::string dir;                      ///< "" = off; old spelling `output.capture_dir`
  std::uint64_t max_files = 1000;       ///< files kept in dir (a capture is 2 files); 0 = no limit
  std::uint64_t max_bytes = 100000000;  ///< bytes kept in dir; 0 = no limit
  std::string select = "all";           ///< all, not_ok (status not ok) or alarm (alert or danger)
};

struct OutputConfig {
  std::string events = "-";       ///< JSON Lines event log; "-" = standard output
  std::string csv;                ///< optional CSV event log
  CaptureConfig capture;          ///< capture-on-trigger, oldest captures removed beyond the limits
  std::string source_name;        ///< `source` field of the events; empty: file path or ALSA device
  MqttConfig mqtt;
};

struct GpioConfig {
  bool enabled = false;
  std::string chip = "gpiochip0";
  int tacho_line = -1;    ///< once-per-revolution input line offset, -1: none
  int alert_line = -1;    ///< relay output, energised while not in alert/danger (fail-safe)
  int danger_line = -1;   ///< relay output, energised while not in danger (fail-safe)
  bool active_low = false;
};

struct LoggingConfig {
  std::string level = "info";       ///< trace, debug, info, warn, error
  double repeat_interval_s = 60.0;  ///< identical warnings are logged at most this often
  double status_interval_s = 10.0;  ///< systemd STATUS= and log status line period
};

/// What the rig file (key `rig`) supplied, filled by apply_rig_defaults (app/rig_defaults.hpp).
struct RigModelInfo {
  std::string path;            ///< rig file as resolved; empty: no rig
  double f_d_hz = 0;           ///< model damped natural frequency, Hz
  double mesh_hz = 0;          ///< model mesh frequency, Hz
  double rb1_m = 0, rb2_m = 0; ///< base radii (source.combine mesh_velocity), m
  bool f_expected = false;     ///< pipeline.analyzer.f_expected_hz came from the rig
  bool band = false;           ///< pipeline.detector.band_lo_hz/band_hi_hz came from the rig
  std::string note;            ///< warning about the rig's band, or empty
  /// Warning when rb1/rb2 disagrees with z1/z2 by more than 5 % (base radii of meshing gears are in
  /// the ratio of their teeth, r_b = m z cos α / 2): a wrong radius mixes the shafts' common rotation
  /// into q̇ = r_b1 φ̇1 + r_b2 φ̇2 (source.combine mesh_velocity). Empty when they agree.
  std::string radius_note;
};

/// One of several streams of one daemon (`streams:`): its input, its pipeline (the top-level
/// `pipeline` with the stream's own keys over it), its trend and alarms, its relays.
struct StreamConfig {
  std::string name;            ///< the events' `stream` field; [A-Za-z0-9_.-], unique
  std::size_t channel = 0;     ///< 0-based input channel (when combine.type is none)
  CombineConfig combine;       ///< a derived channel instead of `channel`
  std::string path;            ///< replay: this stream's file (as source.replay.path); "" = source.replay.path
  std::string rig;             ///< this stream's rig file; "" = the top-level rig
  RigModelInfo rig_model;      ///< what the stream's rig (or the top-level one) supplied
  std::set<std::string> given; ///< keys given at the top level or in the stream ("pipeline.analyzer.f_expected_hz")
  pipeline::PipelineConfig pipeline;  ///< the effective pipeline of this stream
  int alert_line = -1;         ///< relay for this stream's alarm (gpio.chip), -1: none
  int danger_line = -1;
};

struct RidgewatchConfig {
  /// Rig description (config/rigs/*.yaml) whose model supplies f_expected_hz and the detector band
  /// when the file does not give them; "" = none. Relative to the configuration file's directory.
  std::string rig;
  RigModelInfo rig_model;
  /// YAML paths the file gave explicitly ("pipeline.analyzer.f_expected_hz"), filled by the parser.
  std::set<std::string> given;
  SourceConfig source;
  pipeline::PipelineConfig pipeline;  ///< sample_rate_hz comes from the source, not from the file
  OutputConfig output;
  GpioConfig gpio;
  LoggingConfig logging;
  HttpConfig http;
  /// Several streams in one daemon; empty: the one stream of `source` (channel or combine) and
  /// `pipeline`. Filled by the parser with each stream's effective pipeline.
  std::vector<StreamConfig> streams;
  /// Threads processing the streams (the daemon's processing loop counts as one); 0 = one per
  /// stream, at most the number of cores.
  std::size_t workers = 0;
};

/// Defaults of every key (pipeline.analyzer.clip_level: null, i.e. from the source's format).
RidgewatchConfig default_config();
/// The gains of source.combine (c_i / s_i, one per channel), checked: UsageError naming the key for a
/// missing rig (mesh_velocity), a wrong coefficient or sensitivity count, or `channels` outside
/// [0, channels_available) when that is known (> 0). `name`: the configuration file, for messages.
/// need_rig false: the checks that do not need the rig (the configuration loader; `analyze --rig` may
/// supply the rig later), gains then 0 for mesh_velocity without a rig.
std::vector<double> combine_gains(const RidgewatchConfig& config, const std::string& name,
                                  std::size_t channels_available = 0, bool need_rig = true);
/// The same for one of several streams (`streams[i].combine` in messages); its radii from the
/// stream's rig model.
std::vector<double> combine_gains(const StreamConfig& stream, const std::string& name, const std::string& key,
                                  std::size_t channels_available = 0, bool need_rig = true);
/// Checks every stream's channel (or combined channels) against the channels of its input, `available`
/// (> 0): UsageError naming `name: streams[i].channel` or `streams[i].combine.channels[k]`.
void check_stream_channels(const RidgewatchConfig& config, const std::string& name, std::size_t stream_index,
                           std::size_t available);
/// Keys whose default depends on the source's sample format, once the source is open: a clip_level of
/// null (NaN) becomes 0.999 x the format's full scale for integer PCM (SourceInfo::full_scale) and
/// stays NaN (no clipping check) for float data in physical units.
void resolve_format_defaults(pipeline::PipelineConfig& pipeline, std::optional<double> full_scale);
/// Reads and checks a configuration file (keys absent from the file keep their defaults).
RidgewatchConfig load_config_file(const std::string& path);
/// Same from text; `name` stands for the file in messages.
RidgewatchConfig parse_config(const std::string& text, const std::string& name);
/// The configuration as YAML in the file's layout (for --print-defaults and logs); `streams` are
/// not printed (each one's pipeline is the top-level one with the stream's keys over it).
std::string to_yaml(const RidgewatchConfig& config);

}  // namespace ridgewatch::app
