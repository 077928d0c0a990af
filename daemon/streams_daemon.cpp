#include "daemon/streams_daemon.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "app/args.hpp"
#include "app/event_json.hpp"
#include "app/rig_defaults.hpp"
#include "core/pipeline/stream_processor.hpp"
#include "core/rt/spsc_ring_buffer.hpp"
#include "daemon/capture_store.hpp"
#include "daemon/event_log.hpp"
#include "daemon/log_limiter.hpp"
#include "daemon/mqtt_sink.hpp"
#include "daemon/network_outputs.hpp"
#include "daemon/notifier.hpp"
#include "daemon/sources.hpp"
#include "daemon/worker_pool.hpp"
#include "drivers/alsa_source.hpp"

namespace ridgewatch::daemon {

namespace {

using Clock = std::chrono::steady_clock;
constexpr std::size_t kMaxChunk = 8192;  // samples per stream and processing step, as the one-stream loop

struct Stream {
  const app::StreamConfig* cfg = nullptr;
  std::string key;     // "streams[i]" for messages
  std::string source;  // the events' source field
  std::unique_ptr<rt::SpscRingBuffer<float>> ring;
  std::unique_ptr<pipeline::StreamProcessor> processor;
  std::vector<pipeline::ImpactEvent> events;  // this step's, written by the stream's worker
  std::size_t consumed = 0;                   // samples of this step
  std::unique_ptr<drivers::SampleSource> replay;  // replay: this stream's reader (its device's thread)
  std::vector<double> gains;                      // ALSA: weight of each device channel
  std::vector<float> block;                       // ALSA: this stream's samples of one period
  GpioLines relays;
  std::unique_ptr<CaptureStore> captures;
  std::unique_ptr<NetworkOutputs> net;
  std::optional<app::ModelGap> model_gap;
  std::uint64_t events_total = 0, events_ok = 0;
  pipeline::ImpactEvent last_event;
  bool have_last = false;
};

// One acquisition thread: an ALSA device (all channels) or one replayed file (one reader per stream).
struct Device {
  std::vector<Stream*> streams;
  std::unique_ptr<drivers::SampleSource> alsa;
  std::thread thread;
  std::atomic<bool> done{false};
  std::string error;  // written before done (release)
};


class StreamsDaemon {
 public:
  StreamsDaemon(const DaemonOptions& options, DaemonStats& stats) : options_(options), cfg_(options.config), stats_(stats) {
    limiter_.set_interval(cfg_.logging.repeat_interval_s);
  }
  ~StreamsDaemon() { stop_devices(); }
  int run(std::atomic<bool>& stop_flag, std::atomic<bool>& reload_flag, std::atomic<bool>& latch_flag);

 private:
  std::string config_name() const { return options_.config_path.empty() ? "configuration" : options_.config_path; }
  void open_inputs();
  void make_stream(Stream& s, std::optional<double> full_scale);
  void open_listener();
  void open_outputs();
  void acquire_replay(Device& d);
  void acquire_alsa(Device& d);
  void acquire(Device& d);
  void process_step(WorkerPool& pool);
  void emit();
  void after_events(Stream& s);
  void drive_relays();
  void capture(Stream& s, const pipeline::ImpactEvent& e);
  bool impact_window(Stream& s, const pipeline::ImpactEvent& e, std::vector<float>& window, std::uint64_t& first);
  void stop_devices();
  bool devices_done() const;
  bool any_pending() const;
  std::uint64_t impacts_detected() const;
  std::string status_text() const;
  void warn_limited(const std::string& key, const std::string& message);
  void poll_network(bool force);
  int finish();

  const DaemonOptions& options_;
  const app::RidgewatchConfig cfg_;
  DaemonStats& stats_;
  double fs_ = 0.0;
  bool live_ = false;
  std::vector<std::unique_ptr<Stream>> streams_;
  std::vector<std::unique_ptr<Device>> devices_;
  std::unique_ptr<HttpServer> http_;  // after streams_: stopped before the telemetries it reads go
  GpioLines gpio_;  // the top-level lines: relays on the worst alarm of all streams, tacho
  TachoMeter tacho_;
  std::unique_ptr<LineFile> events_out_, csv_out_;
  std::string batch_, csv_batch_;
  SystemdNotifier notifier_;
  LogLimiter limiter_{60.0};
  Clock::time_point steady_at_start_;
  std::chrono::system_clock::time_point wall_at_start_;
  double latency_sum_ms_ = 0.0;
  std::uint64_t latency_count_ = 0;
  std::vector<float> window_;

  std::atomic<bool> acq_stop_{false};
  std::atomic<std::uint64_t> acq_samples_{0};
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  std::mutex space_mutex_;
  std::condition_variable space_;
  std::atomic<bool> producer_waiting_{false};
};

void StreamsDaemon::warn_limited(const std::string& key, const std::string& message) {
  std::uint64_t suppressed = 0;
  if (!limiter_.allow(key, Clock::now(), suppressed)) return;
  if (suppressed > 0)
    spdlog::warn("{} (repeated {} more times since last reported)", message, suppressed);
  else
    spdlog::warn("{}", message);
}

// Readers and devices, then each stream's processor at the input's sample rate.
void StreamsDaemon::open_inputs() {
  live_ = cfg_.source.type == "alsa";
  for (std::size_t i = 0; i < cfg_.streams.size(); ++i) {
    auto s = std::make_unique<Stream>();
    s->cfg = &cfg_.streams[i];
    s->key = "streams[" + std::to_string(i) + "]";
    streams_.push_back(std::move(s));
  }
  std::optional<double> full_scale;
  if (live_) {
    auto device = std::make_unique<Device>();
    device->alsa = options_.source_factory ? options_.source_factory(cfg_.source) : open_source(cfg_.source);
    auto* alsa = dynamic_cast<drivers::AlsaSource*>(device->alsa.get());
    if (alsa == nullptr) throw app::UsageError("streams: source.type alsa needs an ALSA device");
    const std::size_t channels = device->alsa->info().channels;
    fs_ = device->alsa->info().sample_rate_hz;
    full_scale = device->alsa->info().full_scale;
    for (std::size_t i = 0; i < streams_.size(); ++i) {
      Stream& s = *streams_[i];
      app::check_stream_channels(cfg_, config_name(), i, channels);
      s.gains.assign(channels, 0.0);
      if (s.cfg->combine.type == "none") {
        s.gains[s.cfg->channel] = 1.0;
      } else {
        const std::vector<double> g = app::combine_gains(*s.cfg, config_name(), s.key + ".combine", channels);
        for (std::size_t k = 0; k < g.size(); ++k) s.gains[s.cfg->combine.channels[k]] += g[k];
      }
      s.source = !cfg_.output.source_name.empty() ? cfg_.output.source_name : device->alsa->info().name;
      device->streams.push_back(&s);
    }
    devices_.push_back(std::move(device));
  } else {
    std::vector<std::string> device_paths;  // the file of each device
    for (std::size_t i = 0; i < streams_.size(); ++i) {
      Stream& s = *streams_[i];
      s.replay = open_stream_replay(cfg_, i, config_name());
      const std::string path = stream_path(cfg_, i);
      s.source = !cfg_.output.source_name.empty() ? cfg_.output.source_name : path;
      const double fs = s.replay->info().sample_rate_hz;
      if (fs_ == 0.0) fs_ = fs;
      if (fs != fs_)
        throw drivers::InputError(path + ": sample rate " + std::to_string(fs) + " Hz differs from the other streams' " +
                                  std::to_string(fs_) + " Hz");
      // The streams of one file share its device (one thread); another file is another device.
      Device* device = nullptr;
      for (std::size_t d = 0; d < devices_.size(); ++d)
        if (device_paths[d] == path) device = devices_[d].get();
      if (device == nullptr) {
        devices_.push_back(std::make_unique<Device>());
        device_paths.push_back(path);
        device = devices_.back().get();
      }
      device->streams.push_back(&s);
    }
  }
  for (std::size_t i = 0; i < streams_.size(); ++i) {
    const std::optional<double> fsc = live_ ? full_scale : streams_[i]->replay->info().full_scale;
    make_stream(*streams_[i], fsc);
  }
  open_listener();
}

void StreamsDaemon::make_stream(Stream& s, std::optional<double> full_scale) {
  pipeline::PipelineConfig p = s.cfg->pipeline;
  p.sample_rate_hz = fs_;
  // A derived channel has no full scale; a single channel has the format's.
  app::resolve_format_defaults(p, s.cfg->combine.type == "none" ? full_scale : std::nullopt);
  try {
    pipeline::validate(p);
  } catch (const std::invalid_argument& e) {
    throw app::UsageError(config_name() + ": " + s.key + ": pipeline." + e.what() + " (at the source's sample rate " +
                          std::to_string(fs_) + " Hz)");
  }
  s.processor = std::make_unique<pipeline::StreamProcessor>(p);
  // Ring: at least ring_buffer_s of samples plus the look-back of captures, as the one-stream daemon.
  const double history_s = p.analyzer.pretrigger_s + p.analyzer.window_s + 0.5;
  const auto usable = static_cast<std::size_t>(std::ceil(cfg_.source.ring_buffer_s * fs_));
  const auto history = static_cast<std::size_t>(std::ceil(history_s * fs_));
  s.ring = std::make_unique<rt::SpscRingBuffer<float>>(std::bit_ceil(usable + history), history);
  s.events.reserve(256);
  if (const app::RigModelInfo& m = s.cfg->rig_model; !m.path.empty()) {
    s.model_gap.emplace(m.f_d_hz);
    spdlog::info("stream {}: rig {}: model f_d {:.1f} Hz; f_expected_hz {:.1f} ({}), detector band {:.0f}-{:.0f} Hz ({})",
                 s.cfg->name, m.path, m.f_d_hz, p.analyzer.f_expected_hz, m.f_expected ? "rig" : "configuration",
                 p.detector.band_lo_hz, p.detector.band_hi_hz, m.band ? "rig" : "configuration");
  }
  if (!cfg_.output.capture.dir.empty()) {
    app::CaptureConfig c = cfg_.output.capture;
    c.dir = (std::filesystem::path(c.dir) / s.cfg->name).string();  // one directory per stream
    std::error_code ec;
    std::filesystem::create_directories(c.dir, ec);
    s.captures = std::make_unique<CaptureStore>(c);
  }
  if (!cfg_.output.mqtt.host.empty() || !cfg_.http.listen.empty()) {
    // MQTT per stream: its own topics <prefix>/<stream>/..., client and spool, so `seq` counts per
    // stream. The stream's telemetry feeds the one HTTP listener of all streams (open_listener).
    app::RidgewatchConfig c = cfg_;
    c.pipeline = p;
    if (!c.output.mqtt.host.empty()) {
      const std::string base_name = !cfg_.output.source_name.empty() ? cfg_.output.source_name : s.source;
      auto& m = c.output.mqtt;
      m.topic_prefix = (m.topic_prefix.empty() ? default_topic_prefix(base_name) : m.topic_prefix) + "/" + s.cfg->name;
      m.client_id = (m.client_id.empty() ? default_client_id(base_name) : m.client_id) + "-" + s.cfg->name;
      m.spool_dir = (std::filesystem::path(m.spool_dir) / s.cfg->name).string();
    }
    s.net = NetworkOutputs::start(c, s.source, fs_, s.cfg->name, false);
  }
}

// http.listen: one listener for every stream's /metrics (a `stream` label) and page data.
void StreamsDaemon::open_listener() {
  if (cfg_.http.listen.empty()) return;
  std::vector<const Telemetry*> telemetries;
  for (const auto& s : streams_) telemetries.push_back(&s->net->telemetry());
  http_ = std::make_unique<HttpServer>(cfg_.http.listen, std::move(telemetries));
  spdlog::info("HTTP: /metrics and the live page of {} streams on {} (port {})", streams_.size(), cfg_.http.listen,
               http_->port());
}

void StreamsDaemon::open_outputs() {
  events_out_ = std::make_unique<LineFile>(cfg_.output.events);
  if (events_out_->fault()) spdlog::error("{}", events_out_->last_error());
  csv_out_.reset();
  if (!cfg_.output.csv.empty()) {
    csv_out_ = std::make_unique<LineFile>(cfg_.output.csv, event_csv_header(true));
    if (csv_out_->fault()) spdlog::error("{}", csv_out_->last_error());
  }
}

// Replayed file: one reader per stream, read in lockstep, written straight into the rings' free slots
// once every ring has room (lossless however fast; see the one-stream daemon's acquire()).
void StreamsDaemon::acquire_replay(Device& d) {
  const bool unpaced = !(cfg_.source.replay.speed > 0);
  const std::size_t wanted = unpaced ? std::size_t{8192} : static_cast<std::size_t>(std::clamp(fs_ / 400.0, 32.0, 65536.0));
  std::size_t usable = SIZE_MAX;
  for (const Stream* s : d.streams) usable = std::min(usable, s->ring->usable_items());
  const std::size_t block = std::clamp<std::size_t>(usable / 2, 1, wanted);
  std::vector<std::span<float>> slots(d.streams.size());
  const std::uint64_t limit = options_.max_samples;
  std::uint64_t acquired = 0;
  auto room = [&](std::size_t n) {
    return std::all_of(d.streams.begin(), d.streams.end(), [n](Stream* s) { return s->ring->writable_items() >= n; });
  };
  while (!acq_stop_.load(std::memory_order_relaxed)) {
    std::size_t want = block;
    if (limit > 0) {
      if (acquired >= limit) break;
      want = static_cast<std::size_t>(std::min<std::uint64_t>(want, limit - acquired));
    }
    const std::size_t resume = std::max(want, usable / 4);
    if (!room(want)) {
      while (!room(resume) && !acq_stop_.load(std::memory_order_relaxed)) {
        std::unique_lock<std::mutex> lock(space_mutex_);
        producer_waiting_.store(true);
        space_.wait_for(lock, std::chrono::milliseconds(2), [&] { return room(resume) || acq_stop_.load(std::memory_order_relaxed); });
        producer_waiting_.store(false);
      }
    }
    if (acq_stop_.load(std::memory_order_relaxed)) break;
    std::size_t n = want;
    for (std::size_t k = 0; k < d.streams.size(); ++k) {
      slots[k] = d.streams[k]->ring->write_space(want);  // shorter where the storage wraps
      n = std::min(n, slots[k].size());
    }
    if (n == 0) continue;  // no room after all (cannot happen after the wait above; never read 0 = end)
    const std::size_t got = d.streams[0]->replay->read_float(slots[0].first(n));
    if (got == 0) break;
    for (std::size_t k = 1; k < d.streams.size(); ++k) {
      // The same file: every reader delivers the same number of samples.
      for (std::size_t have = 0; have < got;) {
        const std::size_t m = d.streams[k]->replay->read_float(slots[k].subspan(have, got - have));
        if (m == 0) throw drivers::InputError(d.streams[k]->source + ": channels end at different sample counts");
        have += m;
      }
    }
    for (Stream* s : d.streams) s->ring->commit(got);
    acquired += got;
    acq_samples_.fetch_add(got, std::memory_order_relaxed);
    wake_.notify_one();
  }
}

// ALSA: every channel of a period at once; each stream's channel or weighted sum (double precision)
// into its ring. Live capture cannot hold the device up: a full ring drops and counts (a gap).
void StreamsDaemon::acquire_alsa(Device& d) {
  auto& alsa = dynamic_cast<drivers::AlsaSource&>(*d.alsa);
  const std::size_t channels = alsa.info().channels;
  const std::size_t block = static_cast<std::size_t>(std::clamp(fs_ / 400.0, 32.0, 65536.0));
  std::vector<double> frames(block * channels);
  for (Stream* s : d.streams) s->block.assign(block, 0.0f);
  const std::uint64_t limit = options_.max_samples;
  std::uint64_t acquired = 0;
  while (!acq_stop_.load(std::memory_order_relaxed)) {
    std::size_t want = block;
    if (limit > 0) {
      if (acquired >= limit) break;
      want = static_cast<std::size_t>(std::min<std::uint64_t>(want, limit - acquired));
    }
    const drivers::AlsaSource::ReadResult r = alsa.read_frames(std::span<double>(frames.data(), want * channels));
    if (r.count == 0) break;
    for (Stream* s : d.streams) {
      for (std::size_t i = 0; i < r.count; ++i) {
        double y = 0.0;
        for (std::size_t c = 0; c < channels; ++c) y += s->gains[c] * frames[i * channels + c];
        s->block[i] = static_cast<float>(y);
      }
      s->ring->skip(r.gap_frames_before);
      s->ring->write(std::span<const float>(s->block.data(), r.count));
    }
    acquired += r.count;
    acq_samples_.fetch_add(r.count, std::memory_order_relaxed);
    wake_.notify_one();
  }
}

void StreamsDaemon::acquire(Device& d) {
  try {
    if (d.alsa)
      acquire_alsa(d);
    else
      acquire_replay(d);
  } catch (const std::exception& e) {
    d.error = e.what();
  }
  d.done.store(true, std::memory_order_release);
  wake_.notify_one();
}

void StreamsDaemon::stop_devices() {
  acq_stop_.store(true);
  for (auto& d : devices_) {
    if (d->alsa) interrupt_source(*d->alsa);
    for (Stream* s : d->streams)
      if (s->replay) interrupt_source(*s->replay);
  }
  space_.notify_all();
  for (auto& d : devices_)
    if (d->thread.joinable()) d->thread.join();
}

bool StreamsDaemon::devices_done() const {
  return std::all_of(devices_.begin(), devices_.end(), [](const auto& d) { return d->done.load(std::memory_order_acquire); });
}

bool StreamsDaemon::any_pending() const {
  return std::any_of(streams_.begin(), streams_.end(), [](const auto& s) { return s->ring->fill_items() > 0; });
}

std::uint64_t StreamsDaemon::impacts_detected() const {
  std::uint64_t n = 0;
  for (const auto& s : streams_) n += s->processor->impacts_detected();
  return n;
}

// One processing step: every stream's new samples (up to kMaxChunk) on its worker, in place in its ring.
void StreamsDaemon::process_step(WorkerPool& pool) {
  pool.run(streams_.size(), [this](std::size_t i) {
    Stream& s = *streams_[i];
    const auto regions = s.ring->read_regions();
    const std::span<const float> chunk = regions.first.first(std::min(regions.first.size(), kMaxChunk));
    s.consumed = chunk.size();
    if (chunk.empty()) return;
    s.processor->process(chunk, regions.first_stream_index, s.events);
    s.ring->consume(chunk.size());
  });
  for (const auto& s : streams_) stats_.samples += s->consumed;
  if (producer_waiting_.load()) space_.notify_all();
}

// The step's events: one block per log (the streams in order, each in time order), MQTT per stream.
void StreamsDaemon::emit() {
  batch_.clear();
  csv_batch_.clear();
  std::size_t count = 0;
  std::string lines;
  for (const auto& sp : streams_) {
    Stream& s = *sp;
    if (s.events.empty()) continue;
    lines.clear();
    for (const auto& e : s.events) {
      const std::string wall =
          live_ ? iso8601_utc(wall_at_start_ + std::chrono::duration_cast<std::chrono::system_clock::duration>(
                                                   std::chrono::duration<double>(e.t_s)))
                : std::string();
      app::append_event_json(lines, e, s.source, wall, s.cfg->name);
      lines += '\n';
      if (csv_out_) {
        csv_batch_ += event_csv_row(e, s.source, s.cfg->name);
        csv_batch_ += '\n';
      }
    }
    if (s.net) s.net->on_events(s.events, lines);  // MQTT: spooled before the event log is written
    batch_ += lines;
    count += s.events.size();
  }
  if (count == 0) return;
  if (const std::size_t lost = events_out_->write_lines(batch_, count); lost > 0) {
    stats_.events_failed_to_write += lost;
    warn_limited("events-write", events_out_->last_error() + "; " + std::to_string(lost) + " events not written (" +
                                     std::to_string(stats_.events_failed_to_write) + " lost so far); processing continues");
  }
  if (csv_out_ && csv_out_->write_lines(csv_batch_, count) > 0) warn_limited("csv-write", csv_out_->last_error());
  for (const auto& sp : streams_) {
    after_events(*sp);
    sp->events.clear();
  }
  drive_relays();
}

// Counters, captures, the page's envelopes, alarm transitions of one stream's new events.
void StreamsDaemon::after_events(Stream& s) {
  const double speed = live_ ? 1.0 : cfg_.source.replay.speed;
  for (const auto& e : s.events) {
    const bool ok = e.status == pipeline::ImpactStatus::ok;
    ++stats_.events;
    ++s.events_total;
    if (ok) {
      ++stats_.events_ok;
      ++s.events_ok;
      if (s.model_gap) s.model_gap->add_ok(e.f_hz);
    }
    if (speed > 0) {
      // As the one-stream daemon: now minus the moment the window's last sample was due.
      const double end_s = e.window_end_index > 0 ? static_cast<double>(e.window_end_index) / fs_
                                                  : e.t_s + s.cfg->pipeline.analyzer.window_s;
      const double ms = std::chrono::duration<double, std::milli>(Clock::now() - steady_at_start_).count() - 1e3 * end_s / speed;
      latency_sum_ms_ += ms;
      ++latency_count_;
      stats_.latency_mean_ms = latency_sum_ms_ / static_cast<double>(latency_count_);
      stats_.latency_max_ms = std::isfinite(stats_.latency_max_ms) ? std::max(stats_.latency_max_ms, ms) : ms;
      if (s.net) s.net->observe_latency(1e-3 * ms);
    }
    s.last_event = e;
    s.have_last = true;
    if (s.captures && s.captures->selected(e)) capture(s, e);
    if (s.net && s.net->wants_envelope(e)) {
      std::uint64_t first = 0;
      if (impact_window(s, e, window_, first)) s.net->add_envelope(e, window_, first);
    }
    if (e.alarm.transition()) {
      const auto level = e.alarm.level;
      const std::string msg = fmt::format("stream {}: alarm {} -> {} at t = {:.3f} s (sample {}), zeta = {:.5f}",
                                          s.cfg->name, trend::to_string(e.alarm.previous), trend::to_string(level), e.t_s,
                                          e.sample_index, e.zeta);
      if (level == trend::AlarmLevel::alert || level == trend::AlarmLevel::danger)
        spdlog::warn("{}", msg);
      else
        spdlog::info("{}", msg);
    }
  }
}

// Fail-safe relays (energised = healthy): each stream's on its own alarm, the top-level ones on the
// worst alarm of all streams.
void StreamsDaemon::drive_relays() {
  using trend::AlarmLevel;
  auto set = [](GpioLines& g, AlarmLevel level) {
    if (g.alert) g.alert->set_healthy(level != AlarmLevel::alert && level != AlarmLevel::danger);
    if (g.danger) g.danger->set_healthy(level != AlarmLevel::danger);
  };
  AlarmLevel worst = AlarmLevel::learning;
  for (const auto& s : streams_) {
    const AlarmLevel level = s->processor->trend().state().level;
    set(s->relays, level);
    if (static_cast<int>(level) > static_cast<int>(worst)) worst = level;
  }
  set(gpio_, worst);
}

bool StreamsDaemon::impact_window(Stream& s, const pipeline::ImpactEvent& e, std::vector<float>& window,
                                  std::uint64_t& first) {
  const double pre_s = s.cfg->pipeline.analyzer.pretrigger_s;
  const double win_s = s.cfg->pipeline.analyzer.window_s;
  const auto pre = static_cast<std::uint64_t>(std::ceil(pre_s * fs_));
  first = e.sample_index > pre ? e.sample_index - pre : 0;
  auto length = static_cast<std::uint64_t>(std::ceil((pre_s + win_s) * fs_));
  if (e.window_end_index > first) length = std::min(length, e.window_end_index - first);
  const std::uint64_t consumed = s.ring->read_stream_index();
  if (first + length > consumed) length = consumed > first ? consumed - first : 0;
  window.resize(static_cast<std::size_t>(length));
  return length > 0 && s.ring->copy_lookback(first, window) == rt::LookbackStatus::ok;
}

void StreamsDaemon::capture(Stream& s, const pipeline::ImpactEvent& e) {
  std::uint64_t first = 0;
  if (!impact_window(s, e, window_, first)) {
    warn_limited("capture", "stream " + s.cfg->name + ": capture of the impact at sample " +
                                std::to_string(e.sample_index) + " skipped: its samples are no longer in the ring buffer");
    return;
  }
  const std::uint64_t removed_before = s.captures->removed();
  const std::string err = s.captures->write(e, s.source, window_, first, fs_);
  stats_.captures_removed += s.captures->removed() - removed_before;
  ++(err.empty() ? stats_.captures_written : stats_.captures_failed);
  if (!err.empty()) warn_limited("capture-write", "capture failed: " + err + "; processing continues");
}

std::string StreamsDaemon::status_text() const {
  trend::AlarmLevel worst = trend::AlarmLevel::learning;
  std::string per_stream;
  for (const auto& s : streams_) {
    const trend::AlarmLevel level = s->processor->trend().state().level;
    if (static_cast<int>(level) > static_cast<int>(worst)) worst = level;
    per_stream += fmt::format("{}{} {} ({} ok, last zeta {})", per_stream.empty() ? "" : "; ", s->cfg->name,
                              trend::to_string(level), s->events_ok,
                              s->have_last ? format_zeta(s->last_event.zeta) : std::string("-"));
    if (s->model_gap) per_stream += ", " + s->model_gap->text();
  }
  std::uint64_t overruns = 0;
  for (const auto& s : streams_) overruns += s->ring->overrun_items();
  std::string text = fmt::format("{} streams, {} samples, {} impacts ({} ok), alarm {} (worst); {}; {} overruns, {} write failures",
                                 streams_.size(), stats_.samples, stats_.events, stats_.events_ok, trend::to_string(worst),
                                 per_stream, overruns, stats_.events_failed_to_write);
  if (gpio_.tacho) text += fmt::format(", shaft {:.1f} rpm", 60.0 * stats_.shaft_hz);
  if (!cfg_.output.capture.dir.empty())
    text += fmt::format(", captures {} written, {} removed, {} failed", stats_.captures_written, stats_.captures_removed,
                        stats_.captures_failed);
  return text;
}

void StreamsDaemon::poll_network(bool force) {
  for (const auto& s : streams_) {
    if (!s->net) continue;
    DaemonCounters c{s->processor->samples_seen(), s->processor->impacts_detected(), s->ring->overrun_items(),
                     s->processor->gaps_seen(), s->processor->spikes_seen(), stats_.events_failed_to_write};
    s->net->poll(c, force);
  }
}

int StreamsDaemon::run(std::atomic<bool>& stop_flag, std::atomic<bool>& reload_flag, std::atomic<bool>& latch_flag) {
  try {
    open_inputs();
  } catch (const drivers::InputError& e) {
    spdlog::critical("{}", e.what());
    return app::kExitBadInput;
  }
  open_outputs();
  if (options_.gpio_factory || cfg_.gpio.enabled) {
    try {
      gpio_ = options_.gpio_factory ? options_.gpio_factory(cfg_.gpio) : open_gpio(cfg_.gpio);
      for (auto& s : streams_) {
        if (s->cfg->alert_line < 0 && s->cfg->danger_line < 0) continue;
        app::GpioConfig g = cfg_.gpio;
        g.tacho_line = -1;
        g.alert_line = s->cfg->alert_line;
        g.danger_line = s->cfg->danger_line;
        s->relays = options_.gpio_factory ? options_.gpio_factory(g) : open_gpio(g);
      }
    } catch (const drivers::GpioError& e) {
      spdlog::critical("{}", e.what());
      return app::kExitBadInput;
    }
    drive_relays();  // healthy until the trends say otherwise
  }
  WorkerPool pool(worker_count(cfg_.workers, streams_.size()));
  wall_at_start_ = std::chrono::system_clock::now();
  steady_at_start_ = Clock::now();
  for (auto& d : devices_) d->thread = std::thread([this, dev = d.get()] { acquire(*dev); });
  spdlog::info("started: {} streams from {} device(s) at {} Hz on {} worker thread(s), events to {}", streams_.size(),
               devices_.size(), fs_, pool.threads(), cfg_.output.events);
  notifier_.ready(status_text());

  auto last_status = Clock::now(), last_ping = Clock::now();
  std::uint64_t samples_at_last_ping = 0, impacts_at_stop = 0;
  bool stopping = false;
  Clock::time_point stop_deadline{};
  for (;;) {
    if (!stopping && stop_flag.exchange(false)) {
      // As the one-stream daemon: finish the impacts detected before the stop, within one window + 1 s.
      stopping = true;
      impacts_at_stop = impacts_detected();
      double extra_s = 1.0;
      for (const auto& s : streams_)
        extra_s = std::max(extra_s, s->cfg->pipeline.analyzer.pretrigger_s + s->cfg->pipeline.analyzer.window_s + 1.0);
      stop_deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(extra_s));
      notifier_.stopping();
      spdlog::info("stop requested: finishing the impacts in progress");
    }
    if (stopping && !acq_stop_.load() && (impacts_at_stop <= stats_.events || Clock::now() >= stop_deadline)) stop_devices();
    if (reload_flag.exchange(false)) {
      ++stats_.reloads;
      notifier_.reloading();
      spdlog::info("SIGHUP: reopening the output files; with streams, configuration changes take effect after a restart");
      open_outputs();
      notifier_.ready(status_text());
    }
    if (latch_flag.exchange(false)) {
      for (auto& s : streams_) s->processor->trend().reset_latch();
      spdlog::info("alarm latches reset (all streams)");
    }
    if (any_pending()) {
      process_step(pool);
      emit();
    } else if (devices_done()) {
      if (!any_pending()) break;  // every device ended (or stop) and everything is processed
    } else {
      std::unique_lock<std::mutex> lock(wake_mutex_);
      wake_.wait_for(lock, std::chrono::milliseconds(1), [this] { return any_pending() || devices_done(); });
    }
    if (gpio_.tacho) tacho_.poll(*gpio_.tacho, stats_);
    poll_network(false);
    const auto now = Clock::now();
    if (notifier_.watchdog_enabled() && now - last_ping >= notifier_.watchdog_interval() / 3) {
      const std::uint64_t acquired = acq_samples_.load(std::memory_order_relaxed);
      if (acquired > samples_at_last_ping) {
        notifier_.watchdog();
        samples_at_last_ping = acquired;
        last_ping = now;
      } else {
        warn_limited("stall", "no samples from the source: withholding the watchdog ping");
      }
    }
    if (now - last_status >= std::chrono::duration<double>(cfg_.logging.status_interval_s)) {
      notifier_.status(status_text());
      spdlog::info("status: {}", status_text());
      last_status = now;
    }
  }
  return finish();
}

// End of input or stop: flush every stream, sync, drain the network outputs, report.
int StreamsDaemon::finish() {
  stop_devices();
  for (auto& s : streams_) s->processor->flush(s->events);
  emit();
  for (const auto& s : streams_) {
    stats_.overruns += s->ring->overrun_items();
    stats_.gaps += s->processor->gaps_seen();
    stats_.spikes += s->processor->spikes_seen();
  }
  events_out_->sync();
  if (csv_out_) csv_out_->sync();
  poll_network(true);
  if (options_.before_network_stop) options_.before_network_stop(http_ ? http_->port() : 0);
  http_.reset();
  for (auto& s : streams_)
    if (s->net) s->net->stop(std::chrono::seconds(3));
  spdlog::info("stopped: {}", status_text());
  if (latency_count_ > 0)
    spdlog::info("event latency after the decay window: mean {:.2f} ms, max {:.2f} ms over {} events",
                 stats_.latency_mean_ms, stats_.latency_max_ms, latency_count_);
  int code = app::kExitOk;
  for (const auto& d : devices_) {
    if (d->error.empty()) continue;
    spdlog::error("source failed: {}", d->error);
    ++stats_.source_errors;
    code = app::kExitBadInput;
  }
  return code;
}

}  // namespace

int run_streams(const DaemonOptions& options, DaemonStats& stats, std::atomic<bool>& stop_flag,
                std::atomic<bool>& reload_flag, std::atomic<bool>& latch_reset_flag) {
  StreamsDaemon d(options, stats);
  return d.run(stop_flag, reload_flag, latch_reset_flag);
}

std::size_t worker_count(std::size_t workers, std::size_t streams) {
  if (workers > 0) return workers;
  const std::size_t cores = std::max(1u, std::thread::hardware_concurrency());
  return std::clamp<std::size_t>(streams, 1, cores);
}

}  // namespace ridgewatch::daemon
