// Opening the configured sample source for the daemon, and reading a source's gap report.
#pragma once

#include <cstdint>

#include "drivers/sample_source.hpp"

namespace ridgewatch::daemon {

/// Frames the source lost just before the samples of its last read() (ALSA xrun or device loss);
/// 0 for sources that cannot lose data (replayed files).
std::uint64_t take_source_gap(drivers::SampleSource& source);

/// Asks a blocking source (ALSA) to return from read() promptly; no-op for others.
void interrupt_source(drivers::SampleSource& source);

}  // namespace ridgewatch::daemon
