#include "drivers/wav_writer.hpp"

#include <sndfile.h>

#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

namespace ridgewatch::drivers {

void write_wav(const std::string& path, std::span<const double> samples_interleaved, double sample_rate_hz,
               std::size_t channels) {
  constexpr double kMaxRateHz = static_cast<double>(std::numeric_limits<int>::max());
  if (!(sample_rate_hz >= 1.0 && sample_rate_hz <= kMaxRateHz) || sample_rate_hz != std::round(sample_rate_hz)) {
    throw std::invalid_argument("write_wav " + path + ": sample rate must be a whole number of Hz >= 1, got " +
                                std::to_string(sample_rate_hz));
  }
  if (channels == 0 || channels > static_cast<std::size_t>(std::numeric_limits<int>::max())) {
    throw std::invalid_argument("write_wav " + path + ": channel count must be >= 1");
  }
  if (samples_interleaved.size() % channels != 0) {
    throw std::invalid_argument("write_wav " + path + ": " + std::to_string(samples_interleaved.size()) +
                                " samples are not a whole number of " + std::to_string(channels) + "-channel frames");
  }

  SF_INFO info{};
  info.samplerate = static_cast<int>(sample_rate_hz);
  info.channels = static_cast<int>(channels);
  info.format = SF_FORMAT_WAV | SF_FORMAT_FLOAT;
  std::unique_ptr<SNDFILE, int (*)(SNDFILE*)> file(sf_open(path.c_str(), SFM_WRITE, &info), &sf_close);
  if (!file) throw std::runtime_error("write_wav " + path + ": cannot create (libsndfile: " + sf_strerror(nullptr) + ")");
  // No PEAK chunk: libsndfile stamps it with the wall-clock time, so the same samples would give
  // different bytes on every run (simulated replay data must be reproducible bit for bit).
  sf_command(file.get(), SFC_SET_ADD_PEAK_CHUNK, nullptr, SF_FALSE);

  const auto frames = static_cast<sf_count_t>(samples_interleaved.size() / channels);
  const sf_count_t written = sf_writef_double(file.get(), samples_interleaved.data(), frames);
  if (written != frames) {
    throw std::runtime_error("write_wav " + path + ": wrote " + std::to_string(written) + " of " +
                             std::to_string(frames) + " frames (libsndfile: " + sf_strerror(file.get()) + ")");
  }
  // sf_close finalises the header (data length); a failure there leaves a broken file.
  if (sf_close(file.release()) != 0) {
    throw std::runtime_error("write_wav " + path + ": closing failed (header may be incomplete)");
  }
}

}  // namespace ridgewatch::drivers
