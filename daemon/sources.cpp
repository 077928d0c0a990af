#include "daemon/sources.hpp"

#include <cmath>
#include <stdexcept>

#include "app/args.hpp"
#include "daemon/daemon.hpp"
#include "drivers/alsa_source.hpp"
#include "drivers/combined_source.hpp"
#include "drivers/paced_source.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::daemon {

namespace {
std::unique_ptr<drivers::SampleSource> open_with_gains(const app::SourceConfig& config, const std::vector<double>& gains) {
  if (config.type == "alsa") {
    const app::AlsaSourceConfig& a = config.alsa;
    drivers::AlsaSourceConfig c;
    c.device = a.device;
    c.rate_hz = static_cast<unsigned>(std::lround(a.rate_hz));
    c.channels = static_cast<unsigned>(a.channels);
    c.channel = static_cast<unsigned>(a.channel);
    c.gains = gains;
    c.format = a.format == "S16_LE"   ? drivers::AlsaSampleFormat::s16_le
               : a.format == "FLOAT_LE" ? drivers::AlsaSampleFormat::float_le
                                        : drivers::AlsaSampleFormat::s32_le;
    c.period_frames = static_cast<unsigned>(a.period_frames);
    c.buffer_frames = static_cast<unsigned>(a.buffer_frames);
    c.reopen_min_ms = std::chrono::milliseconds(std::lround(a.retry_min_s * 1000.0));
    c.reopen_max_ms = std::chrono::milliseconds(std::lround(a.retry_max_s * 1000.0));
    try {
      drivers::validate(c);
    } catch (const std::invalid_argument& e) {
      throw app::UsageError(std::string("source.alsa.") + e.what());
    }
    return std::make_unique<drivers::AlsaSource>(c);
  }
  drivers::ReplayOptions opt;
  opt.channel = config.replay.channel;
  if (config.replay.rate_hz > 0) opt.csv_rate_hz = config.replay.rate_hz;
  drivers::PacedSourceConfig paced;
  paced.speed = config.replay.speed;
  paced.loop = config.replay.loop;
  if (gains.empty()) return drivers::open_paced_replay(config.replay.path, opt, paced);
  const std::string path = config.replay.path;
  const std::vector<std::size_t> channels = config.combine.channels;
  return std::make_unique<drivers::PacedSource>(
      [path, channels, gains, opt] { return drivers::open_combined_replay(path, channels, gains, opt.csv_rate_hz); }, paced);
}
}  // namespace

std::unique_ptr<drivers::SampleSource> open_source(const app::SourceConfig& config) { return open_with_gains(config, {}); }

std::unique_ptr<drivers::SampleSource> open_source(const app::RidgewatchConfig& c, const std::string& config_name) {
  if (c.source.combine.type == "none") return open_with_gains(c.source, {});
  if (c.source.type == "alsa") {
    const std::vector<double> g = app::combine_gains(c, config_name, c.source.alsa.channels);
    std::vector<double> gains(c.source.alsa.channels, 0.0);
    for (std::size_t i = 0; i < g.size(); ++i) gains[c.source.combine.channels[i]] += g[i];
    return open_with_gains(c.source, gains);
  }
  // The file's channel count first, so a channel it lacks is a configuration error naming the key.
  drivers::ReplayOptions probe;
  if (c.source.replay.rate_hz > 0) probe.csv_rate_hz = c.source.replay.rate_hz;
  const std::size_t available = drivers::open_replay(c.source.replay.path, probe)->info().channels;
  return open_with_gains(c.source, app::combine_gains(c, config_name, available));
}

std::string stream_path(const app::RidgewatchConfig& c, std::size_t i) {
  return c.streams.at(i).path.empty() ? c.source.replay.path : c.streams[i].path;
}

std::unique_ptr<drivers::SampleSource> open_stream_replay(const app::RidgewatchConfig& c, std::size_t i,
                                                          const std::string& config_name) {
  const app::StreamConfig& s = c.streams.at(i);
  app::SourceConfig source = c.source;
  source.replay.path = stream_path(c, i);
  source.replay.channel = s.channel;
  source.combine = s.combine;
  // The file's channel count first, so a channel it lacks is a configuration error naming the key.
  drivers::ReplayOptions probe;
  if (c.source.replay.rate_hz > 0) probe.csv_rate_hz = c.source.replay.rate_hz;
  const std::size_t available = drivers::open_replay(source.replay.path, probe)->info().channels;
  app::check_stream_channels(c, config_name, i, available);
  if (s.combine.type == "none") return open_with_gains(source, {});
  return open_with_gains(source, app::combine_gains(s, config_name, "streams[" + std::to_string(i) + "].combine", available));
}

std::uint64_t take_source_gap(drivers::SampleSource& source) {
  if (auto* alsa = dynamic_cast<drivers::AlsaSource*>(&source)) return alsa->take_gap_frames();
  return 0;
}

void interrupt_source(drivers::SampleSource& source) {
  if (auto* alsa = dynamic_cast<drivers::AlsaSource*>(&source)) alsa->request_stop();
  if (auto* paced = dynamic_cast<drivers::PacedSource*>(&source)) paced->request_stop();
}

}  // namespace ridgewatch::daemon
