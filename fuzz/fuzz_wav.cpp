// Fuzz target: audio replay through libsndfile (drivers/replay_file.hpp open_replay + reading to the
// end), as `ridgewatch analyze` and ridgewatchd do. Byte 0 chooses the channel. Only InputError is an
// expected outcome; samples delivered must be finite and at most the declared frame count.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "drivers/replay_file.hpp"
#include "fuzz/temp_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::string path = ridgewatch::fuzz::write_input(data + 1, size - 1, ".wav");
  ridgewatch::drivers::ReplayOptions options;
  options.channel = data[0] & 0x3;
  try {
    auto source = ridgewatch::drivers::open_replay(path, options);
    const auto& info = source->info();
    if (!(info.sample_rate_hz >= ridgewatch::drivers::kMinReplayRateHz) || info.channel >= info.channels) std::abort();
    std::vector<double> block(1000);
    std::uint64_t total = 0;
    for (;;) {
      const std::size_t n = source->read(block);
      if (n == 0) break;
      for (std::size_t i = 0; i < n; ++i)
        if (!std::isfinite(block[i])) std::abort();
      total += n;
      if (info.frames && total > *info.frames) std::abort();
    }
  } catch (const ridgewatch::drivers::InputError&) {
  }
  return 0;
}
