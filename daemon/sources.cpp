#include "daemon/sources.hpp"

#include <cmath>
#include <stdexcept>

#include "cli/args.hpp"
#include "daemon/daemon.hpp"
#include "drivers/alsa_source.hpp"
#include "drivers/paced_source.hpp"
#include "drivers/replay_file.hpp"

namespace ridgewatch::daemon {

std::unique_ptr<drivers::SampleSource> open_source(const cli::SourceConfig& config) {
  if (config.type == "alsa") {
    const cli::AlsaSourceConfig& a = config.alsa;
    drivers::AlsaSourceConfig c;
    c.device = a.device;
    c.rate_hz = static_cast<unsigned>(std::lround(a.rate_hz));
    c.channels = static_cast<unsigned>(a.channels);
    c.channel = static_cast<unsigned>(a.channel);
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
      throw cli::UsageError(std::string("source.alsa.") + e.what());
    }
    return std::make_unique<drivers::AlsaSource>(c);
  }
  drivers::ReplayOptions opt;
  opt.channel = config.replay.channel;
  if (config.replay.rate_hz > 0) opt.csv_rate_hz = config.replay.rate_hz;
  drivers::PacedSourceConfig paced;
  paced.speed = config.replay.speed;
  paced.loop = config.replay.loop;
  return drivers::open_paced_replay(config.replay.path, opt, paced);
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
