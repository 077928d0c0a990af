// Opening the configured sample source for the daemon, and reading a source's gap report.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "app/config_yaml.hpp"

#include "drivers/sample_source.hpp"

namespace ridgewatch::daemon {

/// The file of streams[i] (its own path, or source.replay.path).
std::string stream_path(const app::RidgewatchConfig& config, std::size_t i);

/// Replay of streams[i]: its file, its channel or combination (radii from its rig), paced and looped
/// as source.replay says. UsageError naming `config_name: streams[i].channel` (or `.combine...`) for
/// a channel the file lacks; InputError for the file itself.
std::unique_ptr<drivers::SampleSource> open_stream_replay(const app::RidgewatchConfig& config, std::size_t i,
                                                          const std::string& config_name);

/// Frames the source lost just before the samples of its last read() (ALSA xrun or device loss);
/// 0 for sources that cannot lose data (replayed files).
std::uint64_t take_source_gap(drivers::SampleSource& source);

/// Asks a blocking source (ALSA) to return from read() promptly; no-op for others.
void interrupt_source(drivers::SampleSource& source);

}  // namespace ridgewatch::daemon
