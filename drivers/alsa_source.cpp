#include "drivers/alsa_source.hpp"

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <utility>

namespace ridgewatch::drivers {

static_assert(std::endian::native == std::endian::little, "the *_LE sample conversion assumes a little-endian host");

const char* to_string(AlsaSampleFormat format) {
  switch (format) {
    case AlsaSampleFormat::s16_le: return "S16_LE";
    case AlsaSampleFormat::s32_le: return "S32_LE";
    case AlsaSampleFormat::float_le: return "FLOAT_LE";
  }
  return "?";
}

AlsaSampleFormat parse_alsa_sample_format(const std::string& text) {
  if (text == "S16_LE") return AlsaSampleFormat::s16_le;
  if (text == "S32_LE") return AlsaSampleFormat::s32_le;
  if (text == "FLOAT_LE") return AlsaSampleFormat::float_le;
  throw std::invalid_argument("format: must be S16_LE, S32_LE or FLOAT_LE (got \"" + text + "\")");
}

namespace {

snd_pcm_format_t alsa_format(AlsaSampleFormat format) {
  switch (format) {
    case AlsaSampleFormat::s16_le: return SND_PCM_FORMAT_S16_LE;
    case AlsaSampleFormat::s32_le: return SND_PCM_FORMAT_S32_LE;
    case AlsaSampleFormat::float_le: return SND_PCM_FORMAT_FLOAT_LE;
  }
  return SND_PCM_FORMAT_UNKNOWN;
}

std::size_t bytes_per_sample(AlsaSampleFormat format) { return format == AlsaSampleFormat::s16_le ? 2 : 4; }

/// Converts sample `channel` of `frames` interleaved frames to doubles at full scale 1.0.
void convert(const unsigned char* raw, std::size_t frames, std::size_t channels, std::size_t channel,
             AlsaSampleFormat format, double* out) {
  const std::size_t bytes = bytes_per_sample(format);
  const std::size_t stride = bytes * channels;
  const unsigned char* p = raw + bytes * channel;
  for (std::size_t i = 0; i < frames; ++i, p += stride) {
    switch (format) {
      case AlsaSampleFormat::s16_le: {
        std::int16_t v;
        std::memcpy(&v, p, sizeof v);
        out[i] = static_cast<double>(v) / 32768.0;
        break;
      }
      case AlsaSampleFormat::s32_le: {
        std::int32_t v;
        std::memcpy(&v, p, sizeof v);
        out[i] = static_cast<double>(v) / 2147483648.0;
        break;
      }
      case AlsaSampleFormat::float_le: {
        float v;
        std::memcpy(&v, p, sizeof v);
        out[i] = static_cast<double>(v);
        break;
      }
    }
  }
}

}  // namespace

void validate(const AlsaSourceConfig& c) {
  auto fail = [](const std::string& message) { throw std::invalid_argument(message); };
  if (c.device.empty()) fail("device: must not be empty");
  if (c.rate_hz < 1000 || c.rate_hz > 5000000)
    fail("rate_hz: must be in 1000..5000000 (got " + std::to_string(c.rate_hz) + ")");
  if (c.channels < 1) fail("channels: must be >= 1");
  if (!c.gains.empty() && c.gains.size() != c.channels)
    fail("gains: need one per channel (got " + std::to_string(c.gains.size()) + ", channels " +
         std::to_string(c.channels) + ")");
  if (c.channel >= c.channels)
    fail("channel: must be < channels (got " + std::to_string(c.channel) + ", channels " +
         std::to_string(c.channels) + ")");
  if (c.period_frames < 16) fail("period_frames: must be >= 16 (got " + std::to_string(c.period_frames) + ")");
  if (c.buffer_frames < 2 * c.period_frames)
    fail("buffer_frames: must be >= 2 * period_frames (got " + std::to_string(c.buffer_frames) + ")");
  if (c.reopen_min_ms.count() <= 0) fail("reopen_min_ms: must be > 0");
  if (c.reopen_max_ms < c.reopen_min_ms) fail("reopen_max_ms: must be >= reopen_min_ms");
}

// ---- AlsaLocalConfig ----

std::shared_ptr<const AlsaLocalConfig> AlsaLocalConfig::from_string(const std::string& text) {
  snd_config_t* top = nullptr;
  int err = snd_config_top(&top);
  if (err < 0) throw InputError(std::string("alsa config: cannot create: ") + snd_strerror(err));
  snd_input_t* input = nullptr;
  err = snd_input_buffer_open(&input, text.data(), static_cast<ssize_t>(text.size()));
  if (err < 0) {
    snd_config_delete(top);
    throw InputError(std::string("alsa config: cannot read text: ") + snd_strerror(err));
  }
  err = snd_config_load(top, input);
  snd_input_close(input);
  if (err < 0) {
    snd_config_delete(top);
    throw InputError(std::string("alsa config: parse error: ") + snd_strerror(err));
  }
  return std::shared_ptr<const AlsaLocalConfig>(new AlsaLocalConfig(top));
}

AlsaLocalConfig::~AlsaLocalConfig() { snd_config_delete(config_); }

// ---- ReconnectBackoff ----

ReconnectBackoff::ReconnectBackoff(std::chrono::milliseconds min_ms, std::chrono::milliseconds max_ms)
    : min_ms_(min_ms), max_ms_(max_ms), next_ms_(min_ms) {
  if (min_ms.count() <= 0 || max_ms < min_ms)
    throw std::invalid_argument("reconnect backoff: need 0 < min <= max (got " + std::to_string(min_ms.count()) +
                                " ms, " + std::to_string(max_ms.count()) + " ms)");
}

std::chrono::milliseconds ReconnectBackoff::next_delay() {
  const auto delay = next_ms_;
  ++failures_;
  next_ms_ = next_ms_ >= max_ms_ / 2 ? max_ms_ : next_ms_ * 2;
  return delay;
}

void ReconnectBackoff::reset() {
  next_ms_ = min_ms_;
  failures_ = 0;
}

// ---- AlsaSource ----

AlsaSource::AlsaSource(AlsaSourceConfig config, std::shared_ptr<const AlsaLocalConfig> local_config, AlsaSeams seams)
    : config_(std::move(config)),
      local_config_(std::move(local_config)),
      seams_(std::move(seams)),
      backoff_((validate(config_), config_.reopen_min_ms), config_.reopen_max_ms) {
  if (!seams_.open) {
    seams_.open = [this](snd_pcm_t** pcm, const std::string& device) {
      if (local_config_)
        return snd_pcm_open_lconf(pcm, device.c_str(), SND_PCM_STREAM_CAPTURE, 0, local_config_->get());
      return snd_pcm_open(pcm, device.c_str(), SND_PCM_STREAM_CAPTURE, 0);
    };
  }
  if (!seams_.sleep) {
    seams_.sleep = [this](std::chrono::milliseconds delay) {
      const auto until = std::chrono::steady_clock::now() + delay;
      while (!stop_.load(std::memory_order_relaxed) && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(
            std::chrono::milliseconds(50), until - std::chrono::steady_clock::now()));
    };
  }
  info_.name = "alsa " + config_.device;
  info_.sample_rate_hz = config_.rate_hz;
  info_.channels = config_.channels;
  info_.channel = config_.channel;
  if (config_.format != AlsaSampleFormat::float_le && config_.gains.empty()) info_.full_scale = 1.0;  // integer: +-1.0
  bytes_per_sample_ = bytes_per_sample(config_.format);
  open_and_configure();
}

AlsaSource::~AlsaSource() { close_pcm(); }

std::string AlsaSource::device_prefix() const { return "alsa " + config_.device + ": "; }

void AlsaSource::close_pcm() {
  if (pcm_ != nullptr) {
    snd_pcm_close(pcm_);
    pcm_ = nullptr;
  }
}

void AlsaSource::open_and_configure() {
  close_pcm();
  snd_pcm_t* pcm = nullptr;
  int err = seams_.open(&pcm, config_.device);
  if (err < 0 || pcm == nullptr)
    throw InputError(device_prefix() + "cannot open capture PCM: " + snd_strerror(err < 0 ? err : -ENODEV));
  pcm_ = pcm;
  auto check = [&](int result, const std::string& what) {
    if (result < 0) {
      close_pcm();
      throw InputError(device_prefix() + what + ": " + snd_strerror(result));
    }
  };
  snd_pcm_hw_params_t* hw = nullptr;
  snd_pcm_hw_params_alloca(&hw);
  check(snd_pcm_hw_params_any(pcm_, hw), "cannot read hardware parameters");
  check(snd_pcm_hw_params_set_access(pcm_, hw, SND_PCM_ACCESS_RW_INTERLEAVED), "interleaved access not supported");
  check(snd_pcm_hw_params_set_format(pcm_, hw, alsa_format(config_.format)),
        std::string("sample format ") + to_string(config_.format) + " not supported");
  check(snd_pcm_hw_params_set_channels(pcm_, hw, config_.channels),
        std::to_string(config_.channels) + " channels not supported");
  check(snd_pcm_hw_params_set_rate_resample(pcm_, hw, 0), "cannot disable resampling");
  check(snd_pcm_hw_params_set_rate(pcm_, hw, config_.rate_hz, 0),
        "sample rate " + std::to_string(config_.rate_hz) + " Hz not supported");
  snd_pcm_uframes_t period = config_.period_frames;
  check(snd_pcm_hw_params_set_period_size_near(pcm_, hw, &period, nullptr),
        "period of " + std::to_string(config_.period_frames) + " frames not supported");
  snd_pcm_uframes_t buffer = std::max<snd_pcm_uframes_t>(config_.buffer_frames, 2 * period);
  check(snd_pcm_hw_params_set_buffer_size_near(pcm_, hw, &buffer),
        "buffer of " + std::to_string(config_.buffer_frames) + " frames not supported");
  check(snd_pcm_hw_params(pcm_, hw), "cannot apply hardware parameters");
  check(snd_pcm_prepare(pcm_), "cannot prepare");
  period_frames_ = period;
  buffer_frames_ = buffer;
  // Allocated once per (re)open, never per read.
  raw_.assign(period_frames_ * config_.channels * bytes_per_sample_, 0);
  mix_.assign(period_frames_, 0.0);
}

void AlsaSource::handle_error(long err) {
  const int code = static_cast<int>(err);
  if (code == -EAGAIN || code == -EINTR) return;  // nothing lost, just try again
  if (code == -EPIPE || code == -ESTRPIPE || code == -EBADFD) {
    // Estimate what is lost: frames still in the ALSA buffer (prepare discards them) plus the time the
    // stream has been stopped since the xrun, at the nominal rate.
    std::uint64_t lost = 0;
    snd_pcm_status_t* status = nullptr;
    snd_pcm_status_alloca(&status);
    if (snd_pcm_status(pcm_, status) == 0 && snd_pcm_status_get_state(status) == SND_PCM_STATE_XRUN) {
      snd_htimestamp_t since{}, now{};
      snd_pcm_status_get_trigger_htstamp(status, &since);
      snd_pcm_status_get_htstamp(status, &now);
      const double stopped_s = static_cast<double>(now.tv_sec - since.tv_sec) +
                               1e-9 * static_cast<double>(now.tv_nsec - since.tv_nsec);
      lost = static_cast<std::uint64_t>(snd_pcm_status_get_avail(status));
      if (stopped_s > 0.0) lost += static_cast<std::uint64_t>(std::llround(stopped_s * config_.rate_hz));
    }
    int result = code == -EBADFD ? snd_pcm_prepare(pcm_) : snd_pcm_recover(pcm_, code, 1);
    if (result == 0) {
      counters_.xruns.fetch_add(1, std::memory_order_relaxed);
      counters_.xrun_frames_lost.fetch_add(lost, std::memory_order_relaxed);
      pending_gap_frames_ += lost;
      set_last_error(device_prefix() + "xrun (" + snd_strerror(code) + "), recovered; about " + std::to_string(lost) +
                     " frames lost");
      return;
    }
    set_last_error(device_prefix() + "xrun recovery failed: " + snd_strerror(result));
  } else {
    set_last_error(device_prefix() + "read failed: " + snd_strerror(code));
  }
  // Device loss (or an xrun that cannot be recovered): close now, reopen in reconnect().
  counters_.device_losses.fetch_add(1, std::memory_order_relaxed);
  close_pcm();
  lost_ = true;
  lost_since_ = std::chrono::steady_clock::now();
}

bool AlsaSource::reconnect() {
  while (!stop_.load(std::memory_order_relaxed)) {
    counters_.reopen_attempts.fetch_add(1, std::memory_order_relaxed);
    try {
      open_and_configure();
      const double outage_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - lost_since_).count();
      const auto lost = static_cast<std::uint64_t>(std::llround(outage_s * config_.rate_hz));
      counters_.device_loss_frames_lost.fetch_add(lost, std::memory_order_relaxed);
      pending_gap_frames_ += lost;
      lost_ = false;
      backoff_.reset();
      return true;
    } catch (const InputError& e) {
      counters_.reopen_failures.fetch_add(1, std::memory_order_relaxed);
      set_last_error(e.what());
    }
    seams_.sleep(backoff_.next_delay());
  }
  return false;
}

std::size_t AlsaSource::read_period(std::size_t frames) {
  for (;;) {
    if (stop_.load(std::memory_order_relaxed)) return 0;
    if (lost_ && !reconnect()) return 0;
    // The file plugin leaves the buffer unwritten past the end of its input file: zero it first.
    std::fill(raw_.begin(), raw_.end(), static_cast<unsigned char>(0));
    const snd_pcm_sframes_t n = snd_pcm_readi(pcm_, raw_.data(), static_cast<snd_pcm_uframes_t>(std::min(frames, period_frames_)));
    if (n > 0) return static_cast<std::size_t>(n);
    if (n < 0) handle_error(n);
  }
}

AlsaSource::ReadResult AlsaSource::finish_read(std::size_t count) {
  ReadResult result;
  result.count = count;
  result.gap_frames_before = pending_gap_frames_;
  pending_gap_frames_ = 0;
  counters_.frames_read.fetch_add(result.count, std::memory_order_relaxed);
  counters_.gap_frames.fetch_add(result.gap_frames_before, std::memory_order_relaxed);
  return result;
}

AlsaSource::ReadResult AlsaSource::read_block(std::span<double> out) {
  const std::size_t n = out.empty() ? 0 : read_period(out.size());
  if (n == 0) return finish_read(0);
  if (config_.gains.empty()) {
    convert(raw_.data(), n, config_.channels, config_.channel, config_.format, out.data());
  } else {
    // Derived channel: the weighted sum of the channels, in double precision.
    std::fill(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n), 0.0);
    for (std::size_t c = 0; c < config_.channels; ++c) {
      const double g = config_.gains[c];
      if (g == 0.0) continue;
      convert(raw_.data(), n, config_.channels, c, config_.format, mix_.data());
      for (std::size_t i = 0; i < n; ++i) out[i] += g * mix_[i];
    }
  }
  return finish_read(n);
}

AlsaSource::ReadResult AlsaSource::read_frames(std::span<double> interleaved) {
  const std::size_t channels = config_.channels;
  const std::size_t n = interleaved.size() < channels ? 0 : read_period(interleaved.size() / channels);
  for (std::size_t c = 0; c < channels && n > 0; ++c) {
    convert(raw_.data(), n, channels, c, config_.format, mix_.data());
    for (std::size_t i = 0; i < n; ++i) interleaved[i * channels + c] = mix_[i];
  }
  return finish_read(n);
}

std::size_t AlsaSource::read(std::span<double> out) {
  const ReadResult result = read_block(out);
  taken_gap_frames_ += result.gap_frames_before;
  return result.count;
}

std::uint64_t AlsaSource::take_gap_frames() { return std::exchange(taken_gap_frames_, 0); }

AlsaCounters AlsaSource::counters() const {
  AlsaCounters c;
  c.frames_read = counters_.frames_read.load(std::memory_order_relaxed);
  c.xruns = counters_.xruns.load(std::memory_order_relaxed);
  c.xrun_frames_lost = counters_.xrun_frames_lost.load(std::memory_order_relaxed);
  c.device_losses = counters_.device_losses.load(std::memory_order_relaxed);
  c.device_loss_frames_lost = counters_.device_loss_frames_lost.load(std::memory_order_relaxed);
  c.reopen_attempts = counters_.reopen_attempts.load(std::memory_order_relaxed);
  c.reopen_failures = counters_.reopen_failures.load(std::memory_order_relaxed);
  c.gap_frames = counters_.gap_frames.load(std::memory_order_relaxed);
  return c;
}

std::string AlsaSource::last_error() const {
  std::lock_guard lock(error_mutex_);
  return last_error_;
}

void AlsaSource::set_last_error(std::string message) {
  std::lock_guard lock(error_mutex_);
  last_error_ = std::move(message);
}

}  // namespace ridgewatch::drivers

namespace ridgewatch::drivers {

namespace {
extern "C" void silent_alsa_error(const char*, int, const char*, int, const char*, ...) {}
}  // namespace

void silence_alsa_lib_errors() { snd_lib_error_set_handler(silent_alsa_error); }

std::string describe_alsa_capture_devices() {
  silence_alsa_lib_errors();
  std::ostringstream o;
  int card = -1;
  int cards = 0;
  while (snd_card_next(&card) == 0 && card >= 0) {
    ++cards;
    const std::string ctl_name = "hw:" + std::to_string(card);
    snd_ctl_t* ctl = nullptr;
    if (snd_ctl_open(&ctl, ctl_name.c_str(), 0) < 0) {
      o << "card " << card << ": cannot open its control device\n";
      continue;
    }
    snd_ctl_card_info_t* info = nullptr;
    snd_ctl_card_info_alloca(&info);
    std::string card_id = std::to_string(card);
    if (snd_ctl_card_info(ctl, info) == 0) {
      card_id = snd_ctl_card_info_get_id(info);
      o << "card " << card << " (" << card_id << "): " << snd_ctl_card_info_get_name(info) << "\n";
    }
    int dev = -1;
    bool any = false;
    while (snd_ctl_pcm_next_device(ctl, &dev) == 0 && dev >= 0) {
      snd_pcm_info_t* pinfo = nullptr;
      snd_pcm_info_alloca(&pinfo);
      snd_pcm_info_set_device(pinfo, static_cast<unsigned>(dev));
      snd_pcm_info_set_subdevice(pinfo, 0);
      snd_pcm_info_set_stream(pinfo, SND_PCM_STREAM_CAPTURE);
      if (snd_ctl_pcm_info(ctl, pinfo) < 0) continue;  // playback only
      any = true;
      const std::string hw = "hw:CARD=" + card_id + ",DEV=" + std::to_string(dev);
      o << "  capture device " << dev << ": " << snd_pcm_info_get_name(pinfo) << "\n"
        << "    source.alsa.device: \"" << hw << "\"  (or \"plug" << hw << "\" for rate/format conversion)\n";
      snd_pcm_t* pcm = nullptr;
      if (const int err = snd_pcm_open(&pcm, hw.c_str(), SND_PCM_STREAM_CAPTURE, SND_PCM_NONBLOCK); err < 0) {
        o << "    cannot open: " << snd_strerror(err) << (err == -EBUSY ? " (in use by another program)" : "") << "\n";
        continue;
      }
      snd_pcm_hw_params_t* hw_params = nullptr;
      snd_pcm_hw_params_alloca(&hw_params);
      if (snd_pcm_hw_params_any(pcm, hw_params) >= 0) {
        unsigned rmin = 0, rmax = 0, cmin = 0, cmax = 0;
        int dir = 0;
        snd_pcm_hw_params_get_rate_min(hw_params, &rmin, &dir);
        snd_pcm_hw_params_get_rate_max(hw_params, &rmax, &dir);
        snd_pcm_hw_params_get_channels_min(hw_params, &cmin);
        snd_pcm_hw_params_get_channels_max(hw_params, &cmax);
        o << "    rates " << rmin << "-" << rmax << " Hz (51200 Hz "
          << (snd_pcm_hw_params_test_rate(pcm, hw_params, 51200, 0) == 0 ? "accepted" : "not accepted") << ")";
        o << "; channels " << cmin << "-" << cmax << "; formats";
        bool fmt_any = false;
        for (const auto& [f, name] : {std::pair{SND_PCM_FORMAT_S16_LE, "S16_LE"}, std::pair{SND_PCM_FORMAT_S32_LE, "S32_LE"},
                                      std::pair{SND_PCM_FORMAT_FLOAT_LE, "FLOAT_LE"}})
          if (snd_pcm_hw_params_test_format(pcm, hw_params, f) == 0) {
            o << " " << name;
            fmt_any = true;
          }
        if (!fmt_any) o << " none the daemon reads (use plughw)";
        o << "\n";
      }
      snd_pcm_close(pcm);
    }
    if (!any) o << "  no capture devices\n";
    snd_ctl_close(ctl);
  }
  if (cards == 0) o << "no ALSA sound cards (is the USB/PCI interface connected? `arecord -l` lists the same)\n";
  // Named PCMs from the ALSA configuration (asoundrc): "default", "dsnoop", plugin definitions.
  void** hints = nullptr;
  if (snd_device_name_hint(-1, "pcm", &hints) == 0) {
    o << "configured PCM names with capture:";
    int n = 0;
    for (void** h = hints; *h != nullptr; ++h) {
      char* name = snd_device_name_get_hint(*h, "NAME");
      char* io = snd_device_name_get_hint(*h, "IOID");
      if (name != nullptr && (io == nullptr || std::string(io) == "Input")) {
        o << (n++ % 4 == 0 ? "\n  " : "  ") << name;
      }
      std::free(name);
      std::free(io);
    }
    o << (n == 0 ? " none\n" : "\n");
    snd_device_name_free_hint(hints);
  }
  return o.str();
}

}  // namespace ridgewatch::drivers
