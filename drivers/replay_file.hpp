// Replay of captured files through the SampleSource interface (the same path live capture takes).
//
// Formats, chosen by file name extension:
//   * `.csv`, `.tsv`, `.txt` (any case): text samples, see drivers/csv_reader.hpp for the layout
//     (one value column plus `csv_rate_hz`, or a time column in seconds plus value columns).
//   * anything else: audio through libsndfile (WAV, FLAC, AIFF, ... 16/24/32-bit integer or float,
//     any channel count). Integer PCM is scaled to full scale 1.0 (int16 -32768 -> -1.0) and reports
//     SourceInfo::full_scale = 1.0; float files are delivered unscaled and report no full scale (their
//     values are physical units; nothing in the format says where a converter would clip). A file libsndfile does not recognise is rejected even if it holds text:
//     the message suggests the CSV extension, so a mislabelled file never gets a silent guess.
//
// Every failure is an InputError whose message is "<path>: <problem>", e.g.
//   "data/x.wav: file does not exist", "data/x.wav: channel 3 out of range (file has 2 channels)",
//   "data/x.wav: truncated: header declares 48000 frames but the file holds only 1000",
//   "data/x.wav: sample 1234 is NaN (t = 0.0257 s)", "data/x.csv: line 17: missing value ...".
// Problems visible in the header are reported by open_replay(); problems in the sample data (NaN/Inf,
// decoder errors, fewer frames than the header promised) by SampleSource::read() when reached.
#pragma once

#include <cstddef>
#include <memory>
#include <optional>
#include <string>

#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {

/// Accepted sample rates for replayed files: below 100 Hz or above 5 MHz a file is certainly not a
/// vibration capture (usually a corrupt header or a wrong `--rate`).
inline constexpr double kMinReplayRateHz = 100.0;
inline constexpr double kMaxReplayRateHz = 5.0e6;

struct ReplayOptions {
  std::size_t channel = 0;            ///< 0-based channel to deliver (CSV: value column after the time column)
  std::optional<double> csv_rate_hz;  ///< sample rate for one-column CSV files (required there), Hz
};

/// Opens `path` for replay. Audio files are streamed in blocks (constant memory); CSV files are parsed
/// completely on open. Throws InputError as described above.
std::unique_ptr<SampleSource> open_replay(const std::string& path, const ReplayOptions& options);

}  // namespace ridgewatch::drivers
