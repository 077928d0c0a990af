#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {

std::vector<double> read_all(SampleSource& source) {
  std::vector<double> samples;
  if (const auto& frames = source.info().frames) samples.reserve(static_cast<std::size_t>(*frames));
  std::vector<double> block(65536);
  for (;;) {
    const std::size_t n = source.read(block);
    if (n == 0) break;
    samples.insert(samples.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(n));
  }
  return samples;
}

}  // namespace ridgewatch::drivers
