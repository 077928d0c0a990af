// Replay pacing: a SampleSource decorator that delivers another source's samples no faster than a
// live device would (real time, N times real time, or as fast as possible), optionally looping.
//
// Pacing model: the clock (std::chrono::steady_clock) starts at the first read(). A block whose last
// sample has stream index k (0-based, counted over all loops) is returned no earlier than
//     start + (k + 1) / (sample_rate_hz * speed),
// i.e. like a sound card that hands over a period once its last sample has been captured. The decorator
// sleeps with sleep_until on that absolute deadline, so sleep overshoot does not accumulate: a late
// block is followed by earlier ones until the schedule is caught up (no drift over long replays).
//
// Looping: at the end of the inner source the factory is called again (reopen = rewind) and reading
// continues in the same read() call, so the stream is seamless: sample indices keep counting, a block
// may straddle the loop boundary, and info().frames is empty (the stream is endless). A reopened source
// must have the same sample rate, channel count and channel (else InputError naming the source). A
// source that yields no samples in a whole pass ends the stream (read() returns 0) instead of spinning.
#pragma once

#include <exception>
#include <condition_variable>
#include <mutex>

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>

#include "drivers/replay_file.hpp"
#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {

struct PacedSourceConfig {
  /// Replay speed relative to real time: 1.0 = real time, N > 0 = N times faster (0.5 = half speed),
  /// 0 = as fast as possible (no sleeping). Finite and >= 0.
  double speed = 1.0;
  bool loop = false;  ///< reopen the source through the factory at its end, forever
};

class PacedSource : public SampleSource {
 public:
  using Factory = std::function<std::unique_ptr<SampleSource>()>;

  /// Calls `factory` once now (its exceptions propagate). Throws std::invalid_argument for a bad speed
  /// ("speed: must be finite and >= 0 (got -1)") or an empty factory / null source.
  PacedSource(Factory factory, PacedSourceConfig config);

  const SourceInfo& info() const override { return info_; }
  /// Fills `out` as far as the source allows (across loop boundaries), then sleeps until the block is due.
  std::size_t read(std::span<double> out) override;
  /// The same in single precision, through the inner source's read_float (no double round trip).
  std::size_t read_float(std::span<float> out) override;

  /// From any thread: a read() waiting for its block's due time returns at once (with the block),
  /// and later reads no longer wait. For prompt shutdown of a slow or stalled replay.
  void request_stop();

  std::uint64_t samples_delivered() const { return samples_delivered_; }
  /// Times the source was reopened at its end.
  std::uint64_t loops_completed() const { return loops_completed_; }

 private:
  Factory factory_;
  PacedSourceConfig config_;
  std::unique_ptr<SampleSource> inner_;
  SourceInfo info_;
  bool started_ = false;
  std::chrono::steady_clock::time_point start_;
  std::uint64_t samples_delivered_ = 0;
  std::uint64_t loops_completed_ = 0;
  std::uint64_t samples_this_pass_ = 0;
  /// Reads from the inner source (reopening it to loop) until `out` is full or the stream ends;
  /// `filled` counts the samples stored so far, also when it throws.
  template <typename T>
  void fill(std::span<T> out, std::size_t& filled);
  template <typename T>
  std::size_t paced_read(std::span<T> out);
  bool ended_ = false;
  /// An error of the inner source after some samples of the same read(): those samples are delivered
  /// first and the error is rethrown by the next read(), so no good sample is lost.
  std::exception_ptr pending_error_;
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stop_requested_ = false;
};

/// Convenience: a paced (optionally looping) replay of a file, reopened with open_replay() per pass.
std::unique_ptr<PacedSource> open_paced_replay(const std::string& path, const ReplayOptions& options,
                                               PacedSourceConfig config);

}  // namespace ridgewatch::drivers
