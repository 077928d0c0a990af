// The one interface every sample producer implements: replayed files now, live ALSA capture and the
// simulated rig later. The pipeline only ever sees this interface, so replay exercises the live path.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace ridgewatch::drivers {

/// Bad input data (missing, unreadable, malformed or physically absurd file). The message names the
/// source and what is wrong. Command-line tools map it to exit code 3.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct SourceInfo {
  std::string name;                     ///< file path or device name, used in messages and events
  double sample_rate_hz = 0.0;          ///< > 0
  std::size_t channels = 1;             ///< channels in the underlying stream
  std::size_t channel = 0;              ///< the channel this source delivers (0-based)
  std::optional<std::uint64_t> frames;  ///< total frames when known (files), empty for live streams
  /// Full scale of the delivered samples when the format has one: 1.0 for integer PCM (scaled so),
  /// empty for float formats and CSV text (physical units, no converter limit). The pipeline's
  /// clipping check takes its default level from it (cli: resolve_format_defaults()).
  std::optional<double> full_scale;
};

class SampleSource {
 public:
  virtual ~SampleSource() = default;
  virtual const SourceInfo& info() const = 0;
  /// Reads up to out.size() samples of the selected channel into `out` (physical units of the file:
  /// full scale = 1.0 for integer PCM). Returns the number written; 0 means end of stream.
  /// Throws InputError when the data turn out to be bad (NaN/Inf samples, truncated file).
  virtual std::size_t read(std::span<double> out) = 0;
  /// The same stream as read(), rounded to single precision (the pipeline's input format), with the
  /// same end-of-stream and error behaviour. Sources that decode to float directly override it and
  /// skip the double round trip (libsndfile decodes float and up to 32-bit integer PCM straight to
  /// float, with the same values as rounding its double output). The default reads through a double
  /// buffer and rejects a sample beyond the float range (InputError naming its index, after the
  /// samples before it were delivered, like a NaN). A caller uses one of the two for the whole stream.
  virtual std::size_t read_float(std::span<float> out);

 private:
  std::vector<double> float_scratch_;  ///< the default read_float's double block (sized on first use)
  std::uint64_t float_delivered_ = 0;  ///< samples delivered by the default read_float
  std::string float_pending_error_;    ///< an out-of-range sample found after good ones of one call
};

/// Reads a source to its end.
std::vector<double> read_all(SampleSource& source);

}  // namespace ridgewatch::drivers
