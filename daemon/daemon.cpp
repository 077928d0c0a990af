#include "daemon/daemon.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <ctime>
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
#include "daemon/network_outputs.hpp"
#include "daemon/notifier.hpp"
#include "daemon/sources.hpp"
#include "daemon/streams_daemon.hpp"

namespace ridgewatch::daemon {

namespace {

std::atomic<bool> g_stop{false};
std::atomic<bool> g_reload{false};
std::atomic<bool> g_latch_reset{false};

using Clock = std::chrono::steady_clock;

}  // namespace

void Daemon::request_stop() { g_stop.store(true, std::memory_order_relaxed); }
void Daemon::request_reload() { g_reload.store(true, std::memory_order_relaxed); }
void Daemon::request_latch_reset() { g_latch_reset.store(true, std::memory_order_relaxed); }
void Daemon::clear_requests() {
  g_stop.store(false);
  g_reload.store(false);
  g_latch_reset.store(false);
}

struct Daemon::Impl {
  DaemonOptions options;
  app::RidgewatchConfig cfg;
  DaemonStats stats;
  double fs = 0.0;
  bool live = false;
  std::string source_name;
  std::string batch;  // emit(): the lines of one block, storage reused

  std::unique_ptr<drivers::SampleSource> source;
  std::unique_ptr<rt::SpscRingBuffer<float>> ring;
  std::unique_ptr<pipeline::StreamProcessor> processor;
  std::unique_ptr<LineFile> events_out, csv_out;
  std::unique_ptr<NetworkOutputs> net;  // MQTT and HTTP (null when neither is configured)
  std::unique_ptr<CaptureStore> captures;  // null: output.capture.dir empty
  pipeline::ImpactEvent last_event;        // for the status line
  bool have_last_event = false;
  std::optional<app::ModelGap> model_gap;  // measured f vs the rig model's f_d (config key rig)

  std::thread acquisition;
  std::atomic<bool> acq_stop{false};
  std::atomic<bool> acq_done{false};
  std::atomic<std::uint64_t> acq_samples{0};
  std::string acq_error;  // written by the acquisition thread before acq_done (release)
  // Wakes the processing loop when a block has been written or the acquisition ended. The producer
  // notifies without taking the mutex (it never blocks on the consumer); a wake-up lost between the
  // consumer's check and its wait costs at most the wait's time-out.
  std::mutex wake_mutex;
  std::condition_variable wake;
  // Replay only: the producer waits here for room in a full ring (it used to poll every 200 us, which
  // on one core stole time from the consumer). The consumer notifies after consuming, and only when the
  // producer says it is waiting; a wake-up lost to that race costs at most the wait's time-out.
  std::mutex space_mutex;
  std::condition_variable space;
  std::atomic<bool> producer_waiting{false};
  std::atomic<std::size_t> producer_resume_items{0};  // free space the waiting producer wants

  GpioLines gpio;
  TachoMeter tacho_meter;
  std::uint64_t relay_errors_seen = 0;

  SystemdNotifier notifier;
  LogLimiter limiter{60.0};
  std::chrono::system_clock::time_point wall_at_start;
  Clock::time_point steady_at_start;
  double latency_sum_ms = 0.0;
  std::uint64_t latency_count = 0;

  // Latency of one event: now minus the moment the last sample of its window was due from a paced
  // (or live) source. Not meaningful as fast as possible.
  void record_latency(const pipeline::ImpactEvent& e) {
    const double speed = live ? 1.0 : cfg.source.replay.speed;
    if (!(speed > 0)) return;
    // The window's last sample (the decay window ends with the decay: window_s is only its maximum).
    const double end_s = e.window_end_index > 0 ? static_cast<double>(e.window_end_index) / fs
                                                : static_cast<double>(e.sample_index) / fs + cfg.pipeline.analyzer.window_s;
    const double due_s = end_s / speed;
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - steady_at_start).count() - 1e3 * due_s;
    latency_sum_ms += ms;
    ++latency_count;
    stats.latency_mean_ms = latency_sum_ms / static_cast<double>(latency_count);
    stats.latency_max_ms = std::isfinite(stats.latency_max_ms) ? std::max(stats.latency_max_ms, ms) : ms;
    if (net) net->observe_latency(1e-3 * ms);
  }

  void warn_limited(const std::string& key, const std::string& message) {
    std::uint64_t suppressed = 0;
    if (!limiter.allow(key, Clock::now(), suppressed)) return;
    if (suppressed > 0)
      spdlog::warn("{} (repeated {} more times since last reported)", message, suppressed);
    else
      spdlog::warn("{}", message);
  }

  void open_outputs() {
    events_out = std::make_unique<LineFile>(cfg.output.events);
    if (events_out->fault()) spdlog::error("{}", events_out->last_error());
    csv_out.reset();
    if (!cfg.output.csv.empty()) {
      csv_out = std::make_unique<LineFile>(cfg.output.csv, event_csv_header());
      if (csv_out->fault()) spdlog::error("{}", csv_out->last_error());
    }
  }

  void make_processor() {
    pipeline::PipelineConfig p = cfg.pipeline;
    p.sample_rate_hz = fs;
    app::resolve_format_defaults(p, source->info().full_scale);  // clip_level from the sample format
    try {
      pipeline::validate(p);
    } catch (const std::invalid_argument& e) {
      throw app::UsageError(std::string("pipeline.") + e.what() + " (at the source's sample rate " +
                            std::to_string(fs) + " Hz)");
    }
    processor = std::make_unique<pipeline::StreamProcessor>(p);
    model_gap.reset();
    if (const app::RigModelInfo& m = cfg.rig_model; !m.path.empty()) {
      model_gap.emplace(m.f_d_hz);
      spdlog::info("rig {}: model f_d {:.1f} Hz, mesh {:.1f} Hz; f_expected_hz {:.1f} ({}), detector band {:.0f}-{:.0f} Hz ({})",
                   m.path, m.f_d_hz, m.mesh_hz, p.analyzer.f_expected_hz, m.f_expected ? "rig" : "configuration",
                   p.detector.band_lo_hz, p.detector.band_hi_hz, m.band ? "rig" : "configuration");
      if (!m.note.empty()) spdlog::warn("rig {}: {}", m.path, m.note);
    }
  }

  void acquire() {
    // Live or paced: blocks of ~2.5 ms, since a paced source hands a block over when its last sample is
    // due and the block length adds directly to the event latency (the ring's per-block cost is ~40 ns,
    // bench_ring_buffer). As fast as possible there is no latency to keep: 8192-sample blocks (the consumer's
    // chunk) amortise the per-call cost of the file reader and the wake-ups while a block is still in
    // cache when it is processed (measured with both threads on one core, scripts/bench-daemon.sh:
    // 0.39 s CPU for the 600 s file with 8192, 0.40 with 4096, 0.43 with 65536).
    const bool unpaced = !live && !(cfg.source.replay.speed > 0);
    // A block never exceeds half the ring, so a lossless replay always finds room for it eventually.
    const std::size_t wanted = unpaced ? std::size_t{8192} : static_cast<std::size_t>(std::clamp(fs / 400.0, 32.0, 65536.0));
    const std::size_t block = std::clamp<std::size_t>(ring->usable_items() / 2, 1, wanted);
    std::vector<float> out(live ? block : 0);  // live: the read buffer; replay decodes into the ring
    try {
      const std::uint64_t limit = options.max_samples;
      std::uint64_t acquired = 0;
      while (!acq_stop.load(std::memory_order_relaxed)) {
        std::size_t want = block;
        if (limit > 0) {
          if (acquired >= limit) break;
          want = static_cast<std::size_t>(std::min<std::uint64_t>(want, limit - acquired));
        }
        // Single precision straight from the decoder (the pipeline's input; the same values as
        // rounding read()'s doubles, SampleSource::read_float).
        std::size_t n = 0;
        if (live) {
          // Live capture cannot hold the device up: read, and a full ring drops and counts the rest
          // (overrun, a gap downstream).
          n = source->read_float(std::span<float>(out.data(), want));
          acquired += n;
          if (const std::uint64_t lost = take_source_gap(*source); lost > 0) ring->skip(lost);
          if (n == 0) break;
          ring->write(std::span<const float>(out.data(), n));
        } else {
          // A replayed file waits for the consumer (lossless, however fast the replay), then decodes
          // straight into the ring (write_space/commit: no copy). A full ring is refilled only once a
          // quarter of it is free again: producer and consumer then alternate in large batches (on
          // one core every alternation costs two context switches).
          const std::size_t resume = std::max(want, ring->usable_items() / 4);
          if (ring->writable_items() < want) {
            while (ring->writable_items() < resume && !acq_stop.load(std::memory_order_relaxed)) {
              std::unique_lock<std::mutex> lock(space_mutex);
              producer_resume_items.store(resume);
              producer_waiting.store(true);
              space.wait_for(lock, std::chrono::milliseconds(2), [&] {
                return ring->writable_items() >= resume || acq_stop.load(std::memory_order_relaxed);
              });
              producer_waiting.store(false);
            }
          }
          if (acq_stop.load(std::memory_order_relaxed)) break;
          const std::span<float> slots = ring->write_space(want);  // shorter where the storage wraps
          n = source->read_float(slots);
          acquired += n;
          if (const std::uint64_t lost = take_source_gap(*source); lost > 0) ring->skip(lost);
          if (n == 0) break;
          ring->commit(n);
        }
        acq_samples.fetch_add(n, std::memory_order_relaxed);
        wake.notify_one();
      }
    } catch (const std::exception& e) {
      acq_error = e.what();
    }
    acq_done.store(true, std::memory_order_release);
    wake.notify_one();
  }

  void emit(const std::vector<pipeline::ImpactEvent>& events) {
    if (events.empty()) return;
    // The events of one processing step go out as one block: one write(2) per log instead of one per
    // event (a system call per 400-byte line was ~7 % of the daemon's CPU in a 2000x replay). They are
    // all known at this point, so the block delays none of them.
    batch.clear();
    for (const auto& e : events) {
      const std::string wall = live ? iso8601_utc(wall_at_start + std::chrono::duration_cast<std::chrono::system_clock::duration>(
                                                                      std::chrono::duration<double>(e.t_s)))
                                    : std::string();
      app::append_event_json(batch, e, source_name, wall);
      batch += '\n';
    }
    if (net) net->on_events(events, batch);  // MQTT: spooled before the event log is written
    if (const std::size_t lost = events_out->write_lines(batch, events.size()); lost > 0) {
      // The lines that did not make it are the block's last ones.
      stats.events_failed_to_write += lost;
      const std::uint64_t first = events[events.size() - lost].sample_index, last = events.back().sample_index;
      warn_limited("events-write",
                   events_out->last_error() +
                       (lost == 1 ? "; event at sample " + std::to_string(first)
                                  : "; " + std::to_string(lost) + " events at samples " + std::to_string(first) + " to " +
                                        std::to_string(last)) +
                       " not written (" + std::to_string(stats.events_failed_to_write) +
                       " lost so far); processing continues");
    }
    if (csv_out) {
      batch.clear();
      for (const auto& e : events) {
        batch += event_csv_row(e, source_name);
        batch += '\n';
      }
      if (csv_out->write_lines(batch, events.size()) > 0) warn_limited("csv-write", csv_out->last_error());
    }
    for (const auto& e : events) {
      ++stats.events;
      if (e.status == pipeline::ImpactStatus::ok) ++stats.events_ok;
      if (model_gap && e.status == pipeline::ImpactStatus::ok) model_gap->add_ok(e.f_hz);
      record_latency(e);
      last_event = e;
      have_last_event = true;
      if (captures && captures->selected(e)) capture(e);
      if (net && net->wants_envelope(e)) {
        std::uint64_t first = 0;
        if (impact_window(e, envelope_window, first)) net->add_envelope(e, envelope_window, first);
      }
      drive_relays(e.alarm.level);
      if (e.alarm.transition()) {
        const auto level = e.alarm.level;
        const std::string msg = fmt::format("alarm {} -> {} at t = {:.3f} s (sample {}), zeta = {:.5f}",
                                            trend::to_string(e.alarm.previous), trend::to_string(level), e.t_s,
                                            e.sample_index, e.zeta);
        if (level == trend::AlarmLevel::alert || level == trend::AlarmLevel::danger)
          spdlog::warn("{}", msg);
        else
          spdlog::info("{}", msg);
      }
    }
  }

  // Fail-safe relays: energised = healthy, so a dead daemon or a cut wire reads as an alarm.
  void drive_relays(trend::AlarmLevel level) {
    using trend::AlarmLevel;
    if (gpio.alert) gpio.alert->set_healthy(level != AlarmLevel::alert && level != AlarmLevel::danger);
    if (gpio.danger) gpio.danger->set_healthy(level != AlarmLevel::danger);
    const std::uint64_t errors = (gpio.alert ? gpio.alert->errors() : 0) + (gpio.danger ? gpio.danger->errors() : 0);
    if (errors > relay_errors_seen) {
      relay_errors_seen = errors;
      warn_limited("relay", "GPIO relay output failed (" + std::to_string(errors) + " errors so far)");
    }
  }

  void poll_tacho() {
    if (gpio.tacho) tacho_meter.poll(*gpio.tacho, stats);
  }

  // The samples of an impact's window (pretrigger + decay) from the ring's history; false when they
  // are gone. The window has been consumed by the processor already; a window cut by the end of the
  // stream or a gap is taken as far as it goes.
  bool impact_window(const pipeline::ImpactEvent& e, std::vector<float>& window, std::uint64_t& first) {
    const double pre_s = cfg.pipeline.analyzer.pretrigger_s;
    const double win_s = cfg.pipeline.analyzer.window_s;
    const auto pre = static_cast<std::uint64_t>(std::ceil(pre_s * fs));
    first = e.sample_index > pre ? e.sample_index - pre : 0;
    auto length = static_cast<std::uint64_t>(std::ceil((pre_s + win_s) * fs));
    if (e.window_end_index > first) length = std::min(length, e.window_end_index - first);  // the analysed window
    const std::uint64_t consumed = ring->read_stream_index();
    if (first + length > consumed) length = consumed > first ? consumed - first : 0;
    window.resize(static_cast<std::size_t>(length));
    return length > 0 && ring->copy_lookback(first, window) == rt::LookbackStatus::ok;
  }
  std::vector<float> envelope_window;

  void capture(const pipeline::ImpactEvent& e) {
    std::vector<float> window;
    std::uint64_t first = 0;
    if (!impact_window(e, window, first)) {
      warn_limited("capture", "capture of the impact at sample " + std::to_string(e.sample_index) +
                                  " skipped: its samples are no longer in the ring buffer");
      return;
    }
    const std::uint64_t removed_before = captures->removed();
    const std::string err = captures->write(e, source_name, window, first, fs);
    stats.captures_removed += captures->removed() - removed_before;
    ++(err.empty() ? stats.captures_written : stats.captures_failed);
    if (!err.empty())
      warn_limited("capture-write", "capture failed: " + err + " (" + std::to_string(stats.captures_failed) +
                                        " failed so far); processing continues");
  }

  // A new store when the capture settings change (start, SIGHUP); the counts carry on.
  void open_captures() {
    const app::CaptureConfig& c = cfg.output.capture;
    if (c.dir.empty()) {
      captures.reset();
      return;
    }
    const auto& o = captures ? captures->config() : app::CaptureConfig{};
    if (captures && o.dir == c.dir && o.max_files == c.max_files && o.max_bytes == c.max_bytes && o.select == c.select)
      return;
    captures = std::make_unique<CaptureStore>(c);
    stats.captures_removed += captures->removed();  // old captures over the limits, removed at start
  }

  void reload() {
    ++stats.reloads;
    notifier.reloading();
    if (options.config_path.empty()) {
      spdlog::info("SIGHUP: no configuration file to reload; reopening outputs");
    } else {
      try {
        app::RidgewatchConfig next = app::load_config_file(options.config_path);
        if (options.overrides) options.overrides(next);
        if (next.source.type != cfg.source.type || next.source.replay.path != cfg.source.replay.path ||
            next.source.alsa.device != cfg.source.alsa.device)
          spdlog::warn("SIGHUP: source changes take effect after a restart; keeping the current source");
        // A derived channel's gains are fixed when the source opens (radii of the rig at that time).
        if (next.source.combine.type != "none" &&
            (next.rig_model.rb1_m != cfg.rig_model.rb1_m || next.rig_model.rb2_m != cfg.rig_model.rb2_m))
          spdlog::warn("SIGHUP: the rig's base radii changed; source.combine keeps the old ones until a restart");
        next.source = cfg.source;
        if (next.output.mqtt.host != cfg.output.mqtt.host || next.http.listen != cfg.http.listen)
          spdlog::warn("SIGHUP: output.mqtt and http changes take effect after a restart; keeping the current ones");
        next.output.mqtt = cfg.output.mqtt;
        next.http = cfg.http;
        // Check the new pipeline at the real sample rate before touching anything.
        pipeline::PipelineConfig p = next.pipeline;
        p.sample_rate_hz = fs;
        pipeline::validate(p);
        // Finish the impact in progress with the old settings, then switch at this block boundary.
        std::vector<pipeline::ImpactEvent> tail;
        processor->flush(tail);
        emit(tail);
        cfg = next;
        limiter.set_interval(cfg.logging.repeat_interval_s);
        make_processor();
        spdlog::info("SIGHUP: configuration reloaded from {}", options.config_path);
      } catch (const std::exception& e) {
        ++stats.reloads_rejected;
        spdlog::error("SIGHUP: new configuration rejected, keeping the old one: {}", e.what());
      }
    }
    open_outputs();  // reopen (log rotation) or switch to new paths
    open_captures();
    notifier.ready(status_text());
  }

  DaemonCounters counters() const {
    return {stats.samples, processor->impacts_detected(), ring->overrun_items(), processor->gaps_seen(),
            processor->spikes_seen(), stats.events_failed_to_write};
  }

  std::string status_text() const {
    std::string text = fmt::format("{} samples, {} impacts ({} ok), alarm {}", stats.samples, stats.events,
                                   stats.events_ok,
                                   processor ? trend::to_string(processor->trend().state().level) : "?");
    if (have_last_event)
      text += fmt::format(", last zeta {} ({})", format_zeta(last_event.zeta), pipeline::to_string(last_event.status));
    if (processor) {
      // EWMA z-score in EWMA standard deviations, the unit of alert_sigma/danger_sigma (trend_monitor.cpp).
      const trend::AlarmState& a = processor->trend().state();
      const double lambda = cfg.pipeline.trend.ewma_lambda;
      const double z = (a.ewma_ln_zeta - a.baseline_ln_zeta) / (a.baseline_ln_sd * std::sqrt(lambda / (2.0 - lambda)));
      if (std::isfinite(a.baseline_ln_zeta))
        text += fmt::format(", baseline zeta {}, EWMA z {:+.2f} (alert {:g}, danger {:g})",
                            format_zeta(std::exp(a.baseline_ln_zeta)), std::isfinite(z) ? z : 0.0,
                            cfg.pipeline.trend.alert_sigma, cfg.pipeline.trend.danger_sigma);
      else
        text += ", baseline learning";
    }
    if (model_gap) text += ", " + model_gap->text();
    text += fmt::format(", {} overruns, {} write failures", stats.overruns, stats.events_failed_to_write);
    if (captures)
      text += fmt::format(", captures {} written, {} removed, {} failed", stats.captures_written,
                          stats.captures_removed, stats.captures_failed);
    if (gpio.tacho) text += fmt::format(", shaft {:.1f} rpm", 60.0 * stats.shaft_hz);
    return text;
  }
};

Daemon::Daemon(DaemonOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->options = std::move(options);
  impl_->cfg = impl_->options.config;
  impl_->limiter.set_interval(impl_->cfg.logging.repeat_interval_s);
}

Daemon::~Daemon() {
  if (impl_->acquisition.joinable()) {
    impl_->acq_stop.store(true);
    impl_->acquisition.join();
  }
}

const DaemonStats& Daemon::stats() const { return impl_->stats; }

int Daemon::run() {
  Impl& d = *impl_;
  if (!d.cfg.streams.empty()) return run_streams(d.options, d.stats, g_stop, g_reload, g_latch_reset);
  try {
    d.source = d.options.source_factory ? d.options.source_factory(d.cfg.source)
                                         : open_source(d.cfg, d.options.config_path.empty() ? "configuration" : d.options.config_path);
  } catch (const drivers::InputError& e) {
    spdlog::critical("{}", e.what());
    return app::kExitBadInput;
  }
  const drivers::SourceInfo& info = d.source->info();
  d.fs = info.sample_rate_hz;
  d.live = d.cfg.source.type == "alsa";
  d.source_name = !d.cfg.output.source_name.empty() ? d.cfg.output.source_name : info.name;
  d.make_processor();  // UsageError propagates (exit 2): the pipeline does not fit this sample rate
  d.open_outputs();
  d.net = NetworkOutputs::start(d.cfg, d.source_name, d.fs);  // UsageError (exit 2) naming the key
  d.open_captures();
  if (d.options.gpio_factory || d.cfg.gpio.enabled) {
    try {
      d.gpio = d.options.gpio_factory ? d.options.gpio_factory(d.cfg.gpio) : open_gpio(d.cfg.gpio);
    } catch (const drivers::GpioError& e) {
      spdlog::critical("{}", e.what());
      return app::kExitBadInput;
    }
    d.drive_relays(trend::AlarmLevel::learning);  // healthy until the trend says otherwise
  }

  // Ring: at least ring_buffer_s of samples, plus history for capture look-back.
  const double history_s = d.cfg.pipeline.analyzer.pretrigger_s + d.cfg.pipeline.analyzer.window_s + 0.5;
  const auto usable = static_cast<std::size_t>(std::ceil(d.cfg.source.ring_buffer_s * d.fs));
  const auto history = static_cast<std::size_t>(std::ceil(history_s * d.fs));
  d.ring = std::make_unique<rt::SpscRingBuffer<float>>(std::bit_ceil(usable + history), history);

  d.wall_at_start = std::chrono::system_clock::now();
  d.steady_at_start = Clock::now();
  d.acquisition = std::thread([&d] { d.acquire(); });
  spdlog::info("started: source {} at {} Hz, events to {}", d.source_name, d.fs, d.cfg.output.events);
  d.notifier.ready(d.status_text());

  constexpr std::size_t kMaxChunk = 8192;
  std::vector<pipeline::ImpactEvent> events;
  events.reserve(256);
  auto last_status = Clock::now();
  bool hinted_survey = false;
  auto last_ping = Clock::now();
  std::uint64_t samples_at_last_ping = 0;
  bool stopping = false;
  Clock::time_point stop_deadline{};
  std::uint64_t impacts_at_stop = 0;

  for (;;) {
    if (!stopping && g_stop.exchange(false)) {
      // Let the impact in progress complete: keep acquiring until every detected impact has its
      // event, but no longer than one analysis window plus a second (a stalled input must not hold
      // the shutdown up), then stop the acquisition.
      stopping = true;
      impacts_at_stop = d.processor->impacts_detected();
      const double extra_s = d.cfg.pipeline.analyzer.pretrigger_s + d.cfg.pipeline.analyzer.window_s + 1.0;
      stop_deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(extra_s));
      d.notifier.stopping();
      spdlog::info("stop requested: finishing the impact in progress");
    }
    if (stopping && !d.acq_stop.load()) {
      // Impacts detected before the stop request still waiting for their decay window.
      const bool pending = impacts_at_stop > d.stats.events;
      if (!pending || Clock::now() >= stop_deadline) {
        d.acq_stop.store(true);
        interrupt_source(*d.source);
      }
    }
    if (g_reload.exchange(false)) d.reload();
    if (g_latch_reset.exchange(false)) {
      d.processor->trend().reset_latch();
      spdlog::info("alarm latch reset");
    }

    // Processed in place in the ring (the producer never writes into unconsumed items), at most
    // kMaxChunk samples at a time so that signals, the tacho and the watchdog are served in between.
    const auto regions = d.ring->read_regions();
    const std::span<const float> chunk = regions.first.first(std::min(regions.first.size(), kMaxChunk));
    if (!chunk.empty()) {
      d.processor->process(chunk, regions.first_stream_index, events);
      d.ring->consume(chunk.size());
      if (d.producer_waiting.load() &&
          d.ring->usable_items() - d.ring->fill_items() >= d.producer_resume_items.load())
        d.space.notify_one();
      d.stats.samples += chunk.size();
      d.emit(events);
      events.clear();
      if (const std::uint64_t gaps = d.processor->gaps_seen(); gaps > d.stats.gaps) {
        // Samples lost upstream (ALSA xrun or device loss, ring overrun): the stream index jumped.
        d.stats.gaps = gaps;
        d.warn_limited("gap", fmt::format("gap in the input before sample {} ({} gaps so far, {} overrun samples)",
                                          regions.first_stream_index, gaps, d.ring->overrun_items()));
      }
    } else if (d.acq_done.load(std::memory_order_acquire)) {
      if (d.ring->read_regions().size() == 0) break;  // input ended (or stop) and everything is processed
    } else {
      // Nothing to process: wait for the next block (1 ms at most, so signals, the tacho and the
      // watchdog are still served when the input stalls).
      std::unique_lock<std::mutex> lock(d.wake_mutex);
      d.wake.wait_for(lock, std::chrono::milliseconds(1), [&d] {
        return d.ring->fill_items() > 0 || d.acq_done.load(std::memory_order_acquire);
      });
    }

    d.poll_tacho();
    if (d.net) d.net->poll(d.counters());
    const auto now = Clock::now();
    // Watchdog: ping only while samples keep arriving, so a stalled input gets the service restarted.
    if (d.notifier.watchdog_enabled() && now - last_ping >= d.notifier.watchdog_interval() / 3) {
      const std::uint64_t acquired = d.acq_samples.load(std::memory_order_relaxed);
      if (acquired > samples_at_last_ping) {
        d.notifier.watchdog();
        samples_at_last_ping = acquired;
        last_ping = now;
      } else if (now - last_ping >= d.notifier.watchdog_interval() / 3) {
        d.warn_limited("stall", "no samples from the source: withholding the watchdog ping");
      }
    }
    if (now - last_status >= std::chrono::duration<double>(d.cfg.logging.status_interval_s)) {
      d.stats.overruns = d.ring->overrun_items();
      d.notifier.status(d.status_text());
      spdlog::info("status: {}", d.status_text());
      last_status = now;
      // The first minute of the stream without an impact: say which band is watched (issue 19).
      if (!hinted_survey && d.processor->samples_seen() >= static_cast<std::uint64_t>(60.0 * d.fs)) {
        hinted_survey = true;
        if (d.processor->impacts_detected() == 0)
          spdlog::warn("no impacts in the first minute in the band watched, {}-{} Hz (pipeline.detector), f_expected_hz {}; "
                       "if this rig's impacts ring elsewhere, `ridgewatchd --survey 60 --write-config OUT.yaml` finds "
                       "their band and proposes a configuration",
                       d.cfg.pipeline.detector.band_lo_hz, d.cfg.pipeline.detector.band_hi_hz,
                       d.cfg.pipeline.analyzer.f_expected_hz);
      }
    }
  }

  d.acq_stop.store(true);
  interrupt_source(*d.source);
  if (d.acquisition.joinable()) d.acquisition.join();
  d.processor->flush(events);
  d.emit(events);
  events.clear();
  d.stats.overruns = d.ring->overrun_items();
  d.stats.gaps = d.processor->gaps_seen();
  d.stats.spikes = d.processor->spikes_seen();
  d.events_out->sync();
  if (d.csv_out) d.csv_out->sync();
  if (d.net) {
    d.net->poll(d.counters(), true);
    if (d.options.before_network_stop) d.options.before_network_stop(d.net->http_port());
    d.net->stop(std::chrono::seconds(3));  // what the broker has not acknowledged by then stays spooled
  }
  spdlog::info("stopped: {}", d.status_text());
  if (d.captures)
    spdlog::info("captures: {} written, {} removed to keep output.capture limits, {} failed; {} files ({} bytes) in {}",
                 d.stats.captures_written, d.stats.captures_removed, d.stats.captures_failed, d.captures->files(),
                 d.captures->bytes(), d.captures->config().dir);
  if (d.latency_count > 0)
    spdlog::info("event latency after the decay window: mean {:.2f} ms, max {:.2f} ms over {} events",
                 d.stats.latency_mean_ms, d.stats.latency_max_ms, d.latency_count);
  if (!d.acq_error.empty()) {
    spdlog::error("source failed: {}", d.acq_error);
    ++d.stats.source_errors;
    return app::kExitBadInput;
  }
  return app::kExitOk;
}

void TachoMeter::poll(drivers::TachoInput& tacho, DaemonStats& stats) {
  edges_.clear();
  tacho.wait_edges(std::chrono::nanoseconds(0), edges_);
  for (const auto& edge : edges_) {
    if (!edge.rising) continue;
    ++stats.tacho_pulses;
    if (last_pulse_ns_ > 0 && edge.timestamp_ns > last_pulse_ns_)
      stats.shaft_hz = 1e9 / static_cast<double>(edge.timestamp_ns - last_pulse_ns_);
    last_pulse_ns_ = edge.timestamp_ns;
  }
}

GpioLines open_gpio(const app::GpioConfig& config) {
  GpioLines lines;
  auto line = [&](int offset) {
    drivers::GpioLineConfig c;
    c.chip = config.chip;
    c.offset = static_cast<unsigned>(offset);
    c.active_low = config.active_low;
    return c;
  };
  if (config.alert_line >= 0) lines.alert = std::make_unique<drivers::GpiodRelayOutput>(line(config.alert_line));
  if (config.danger_line >= 0) lines.danger = std::make_unique<drivers::GpiodRelayOutput>(line(config.danger_line));
  if (config.tacho_line >= 0)
    lines.tacho = std::make_unique<drivers::GpiodTachoInput>(line(config.tacho_line), drivers::TachoEdges::rising);
  return lines;
}

}  // namespace ridgewatch::daemon
