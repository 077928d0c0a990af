#include "drivers/sample_source.hpp"

#include <cmath>
#include <sstream>

namespace ridgewatch::drivers {

std::size_t SampleSource::read_float(std::span<float> out) {
  // An out-of-range sample ends the stream: the error is reported on every later call (the samples
  // after it were consumed from read() and are not delivered; a silent hole is never made).
  if (!float_pending_error_.empty()) throw InputError(float_pending_error_);
  // One read() per call, as large as the caller's span (the scratch grows to the largest block once):
  // a second read() could throw after samples of the first were converted, and those would be lost.
  if (float_scratch_.size() < out.size()) float_scratch_.resize(out.size());
  const std::size_t n = read(std::span<double>(float_scratch_.data(), out.size()));
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = static_cast<float>(float_scratch_[i]);
    if (std::isfinite(out[i])) continue;
    // read() delivers finite samples only: this one is beyond the single-precision range. The samples
    // before it are delivered now and the error comes with the next call (as read() does).
    const std::uint64_t index = float_delivered_ + i;
    std::ostringstream msg;
    msg << info().name << ": sample " << index << " (" << float_scratch_[i]
        << ") is beyond the single-precision range (|x| > 3.4e38)";
    float_pending_error_ = msg.str();
    if (i == 0) throw InputError(float_pending_error_);
    float_delivered_ += i;
    return i;
  }
  float_delivered_ += n;
  return n;
}

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
