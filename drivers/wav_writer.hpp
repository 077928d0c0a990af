// Writes 32-bit float WAV files: simulator output, test fixtures, captured windows. Float keeps the
// full dynamic range of simulated signals (no clipping at full scale, no quantisation below 2^-24
// relative), and the replay driver reads it back unchanged.
#pragma once

#include <cstddef>
#include <span>
#include <string>

namespace ridgewatch::drivers {

/// Writes `samples_interleaved` (frame-major: s[frame * channels + channel]) to `path` as a WAV file
/// with 32-bit IEEE float samples, overwriting any existing file. Values are stored as given (no
/// scaling or clipping; NaN/Inf are stored too, which fixtures for bad input rely on).
///   sample_rate_hz: a whole number of hertz in [1, 2^31 - 1] (WAV stores an integer rate).
///   channels:       >= 1; samples_interleaved.size() must be a multiple of it.
/// Throws std::invalid_argument for bad arguments and std::runtime_error naming the path when the
/// file cannot be created or written completely.
void write_wav(const std::string& path, std::span<const double> samples_interleaved, double sample_rate_hz,
               std::size_t channels = 1);

}  // namespace ridgewatch::drivers
