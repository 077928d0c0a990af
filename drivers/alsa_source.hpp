// Live capture from an ALSA PCM as a SampleSource: interleaved S16_LE / S32_LE / FLOAT_LE frames, one
// channel delivered, integer PCM scaled to full scale 1.0 (S16: /32768, S32: /2^31), float unscaled.
//
// Errors at construction (bad device name, unsupported rate/format/channels, bad config) are
// InputError naming the device: "alsa hw:1,0: cannot open capture PCM: No such device". After that,
// read() never throws for device trouble; it recovers and counts:
//   * xrun (-EPIPE overrun, -ESTRPIPE suspend, -EBADFD stream not running): snd_pcm_recover /
//     snd_pcm_prepare, counted in AlsaCounters::xruns. The frames lost are estimated from the PCM status
//     at the xrun: frames still in the ALSA buffer (discarded by prepare) + time since the xrun x rate.
//   * device loss (-ENODEV, -EIO, any error recovery cannot fix): the PCM is closed and reopened with
//     exponential backoff (reopen_min_ms, doubled per failed attempt up to reopen_max_ms; the first attempt
//     is immediate). Counted in device_losses / reopen_attempts / reopen_failures; the message of the last
//     failure is in last_error(). The frames lost are estimated as the steady-clock time from the loss
//     to the successful reopen x rate. read() blocks while reconnecting; request_stop() (any thread)
//     makes it return 0 promptly (end of stream), which is the only way read() returns 0.
//
// GAPS. Every loss becomes a gap the consumer must see as a jump in sample indices. After each read(),
// take_gap_frames() returns the frames lost immediately before the first sample that read() returned
// (0: the samples continue the previous read seamlessly) and resets it. read() never lets a gap fall
// inside its output: if an error occurs after some frames were read, those are returned first and the
// (sticky) error is handled on the next call. read_block() returns both values at once. An acquisition
// thread forwards the count to SpscRingBuffer::skip() before writing the samples.
//
// TEST SEAM. AlsaSource opens either `device` in the global ALSA configuration, or `device` inside an
// AlsaLocalConfig (a configuration parsed from text with snd_config_load and opened with
// snd_pcm_open_lconf; the global configuration is not touched). Tests define a `type file` PCM there.
// AlsaSeams can replace the opener (to fail on purpose, or to keep the snd_pcm_t* and sabotage it) and
// the backoff sleep (to record delays instead of waiting).
//
// libasound's `file` plugin with `slave.pcm { type null }` and `infile` (what the tests use) has no
// pacing (reads return at once) and no end of file: past the end of `infile` snd_pcm_readi still
// reports the full frame count but leaves the rest of the caller's buffer unwritten. AlsaSource therefore
// zero-fills its raw buffer before every snd_pcm_readi, so such reads yield silence (0.0) rather than
// stale data; tests read exactly the file's length.
#pragma once

#include <alsa/asoundlib.h>

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "drivers/sample_source.hpp"

namespace ridgewatch::drivers {

enum class AlsaSampleFormat { s16_le, s32_le, float_le };

/// "S16_LE", "S32_LE", "FLOAT_LE"; parse throws std::invalid_argument naming the accepted values.
const char* to_string(AlsaSampleFormat format);
AlsaSampleFormat parse_alsa_sample_format(const std::string& text);

struct AlsaSourceConfig {
  std::string device = "default";  ///< ALSA PCM name, e.g. "hw:CARD=USB,DEV=0" or "plughw:1,0"
  unsigned rate_hz = 51200;        ///< must be supported exactly (no silent resampling), 1000..5000000
  unsigned channels = 1;           ///< channels of the capture stream, >= 1
  unsigned channel = 0;            ///< 0-based channel delivered, < channels
  /// Non-empty: a derived channel, sum_c gains[c] x_c over all `channels` (one gain per channel, 0 for
  /// a channel not used) in place of `channel`; the result has no full scale (drivers/combined_source.hpp).
  std::vector<double> gains;
  AlsaSampleFormat format = AlsaSampleFormat::s32_le;
  unsigned period_frames = 1024;   ///< requested period (ALSA picks the nearest), >= 16
  unsigned buffer_frames = 8192;   ///< requested ALSA buffer (nearest), >= 2 * period_frames
  std::chrono::milliseconds reopen_min_ms{100};    ///< first backoff delay after a failed reopen, > 0
  std::chrono::milliseconds reopen_max_ms{10000};  ///< backoff cap, >= reopen_min_ms
};

/// Throws std::invalid_argument naming the field ("channel: must be < channels (got 2, channels 2)").
void validate(const AlsaSourceConfig& config);

/// An ALSA configuration parsed from text, used instead of the global one (owns the snd_config_t).
class AlsaLocalConfig {
 public:
  /// Throws InputError ("alsa config: parse error ...: Invalid argument") when the text does not parse.
  static std::shared_ptr<const AlsaLocalConfig> from_string(const std::string& text);
  ~AlsaLocalConfig();
  AlsaLocalConfig(const AlsaLocalConfig&) = delete;
  AlsaLocalConfig& operator=(const AlsaLocalConfig&) = delete;
  snd_config_t* get() const { return config_; }

 private:
  explicit AlsaLocalConfig(snd_config_t* config) : config_(config) {}
  snd_config_t* config_;
};

/// Exponential backoff for reconnect attempts: delays min, 2 min, 4 min, ... capped at max.
class ReconnectBackoff {
 public:
  /// Throws std::invalid_argument unless 0 < min <= max.
  ReconnectBackoff(std::chrono::milliseconds min_ms, std::chrono::milliseconds max_ms);
  std::chrono::milliseconds next_delay();  ///< the delay before the next attempt; doubles each call
  void reset();                            ///< after a success: start again at min
  unsigned failures() const { return failures_; }

 private:
  std::chrono::milliseconds min_ms_, max_ms_, next_ms_;
  unsigned failures_ = 0;
};

/// Counters, readable from any thread (status lines, logs).
struct AlsaCounters {
  std::uint64_t frames_read = 0;           ///< frames delivered by read()
  std::uint64_t xruns = 0;                 ///< recovered overruns / suspends / not-running states
  std::uint64_t xrun_frames_lost = 0;      ///< estimate, see header comment
  std::uint64_t device_losses = 0;         ///< errors that needed a close and reopen
  std::uint64_t device_loss_frames_lost = 0;  ///< estimate: outage time x rate
  std::uint64_t reopen_attempts = 0;
  std::uint64_t reopen_failures = 0;
  std::uint64_t gap_frames = 0;            ///< all frames reported through take_gap_frames / read_block
};

struct AlsaSeams {
  /// Opens the capture PCM named `device` (as snd_pcm_open: 0 or a negative errno). Default:
  /// snd_pcm_open_lconf with the local config if one was given, else snd_pcm_open.
  std::function<int(snd_pcm_t** pcm, const std::string& device)> open;
  /// Waits between reconnect attempts. Default: sleeps in slices of at most 50 ms, returning early
  /// when request_stop() was called.
  std::function<void(std::chrono::milliseconds delay)> sleep;
};

class AlsaSource : public SampleSource {
 public:
  struct ReadResult {
    std::size_t count = 0;             ///< samples written to out (0 only after request_stop())
    std::uint64_t gap_frames_before = 0;  ///< frames lost right before out[0]
  };

  /// Opens and configures the PCM now; throws InputError naming the device on failure and
  /// std::invalid_argument for a bad config.
  explicit AlsaSource(AlsaSourceConfig config, std::shared_ptr<const AlsaLocalConfig> local_config = nullptr,
                      AlsaSeams seams = {});
  ~AlsaSource() override;
  AlsaSource(const AlsaSource&) = delete;
  AlsaSource& operator=(const AlsaSource&) = delete;

  const SourceInfo& info() const override { return info_; }
  /// Blocks until at least one frame is available (or reconnecting, see header); returns up to one
  /// period of samples. The gap before them: take_gap_frames().
  std::size_t read(std::span<double> out) override;
  ReadResult read_block(std::span<double> out);
  /// Every channel, interleaved (frame i, channel c at interleaved[i * channels + c]), with the same
  /// blocking, recovery and gap rules as read_block; count = frames (at most one period and
  /// interleaved.size() / channels). For several streams from one device (ridgewatchd `streams:`).
  ReadResult read_frames(std::span<double> interleaved);
  /// Frames lost right before the first sample of the last read() (plus any earlier gaps not taken).
  std::uint64_t take_gap_frames();

  /// Any thread: makes a blocked or future read() return 0.
  void request_stop() { stop_.store(true, std::memory_order_relaxed); }

  AlsaCounters counters() const;
  std::string last_error() const;
  /// Period and buffer sizes ALSA actually granted, frames.
  std::size_t period_frames() const { return period_frames_; }
  std::size_t buffer_frames() const { return buffer_frames_; }

 private:
  void open_and_configure();  // throws InputError
  void close_pcm();
  void handle_error(long err);
  bool reconnect();  // false when stopped
  std::size_t read_period(std::size_t frames);  // up to `frames` into raw_, recovering; 0 when stopped
  ReadResult finish_read(std::size_t count);    // attaches and counts the pending gap
  void set_last_error(std::string message);
  std::string device_prefix() const;

  AlsaSourceConfig config_;
  std::shared_ptr<const AlsaLocalConfig> local_config_;
  AlsaSeams seams_;
  SourceInfo info_;
  snd_pcm_t* pcm_ = nullptr;
  std::size_t period_frames_ = 0;
  std::size_t buffer_frames_ = 0;
  std::size_t bytes_per_sample_ = 0;
  std::vector<unsigned char> raw_;  // one period of interleaved frames
  std::vector<double> mix_;         // one period of one channel (gains, read_frames), sized with raw_
  ReconnectBackoff backoff_;
  std::uint64_t pending_gap_frames_ = 0;  // lost before the next delivered sample
  std::uint64_t taken_gap_frames_ = 0;    // gap before the last read's samples, for take_gap_frames
  bool lost_ = false;
  std::chrono::steady_clock::time_point lost_since_;
  std::atomic<bool> stop_{false};

  struct AtomicCounters {
    std::atomic<std::uint64_t> frames_read{0}, xruns{0}, xrun_frames_lost{0}, device_losses{0},
        device_loss_frames_lost{0}, reopen_attempts{0}, reopen_failures{0}, gap_frames{0};
  } counters_;
  mutable std::mutex error_mutex_;
  std::string last_error_;
};

/// `ridgewatchd --list-devices`: every ALSA card's capture PCMs ("hw:CARD,DEV" and the name to put
/// in source.alsa.device) with the rates, sample formats (of S16_LE, S32_LE, FLOAT_LE, the ones the
/// daemon reads) and channel counts the hardware accepts; the names of configured PCMs (e.g. "default",
/// "plughw"). A device that is busy is listed as such. Never throws.
std::string describe_alsa_capture_devices();

/// Routes alsa-lib's own error printing (e.g. "ALSA lib confmisc.c:...: cannot find card") away from
/// standard error: every failure is reported by the caller with the device name instead. Idempotent.
void silence_alsa_lib_errors();

}  // namespace ridgewatch::drivers
