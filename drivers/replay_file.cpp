#include "drivers/replay_file.hpp"

#include <sndfile.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <type_traits>
#include <utility>
#include <vector>

#include "drivers/csv_reader.hpp"

namespace ridgewatch::drivers {
namespace {

namespace fs = std::filesystem;

/// Frames decoded per libsndfile call; the de-interleave buffer holds one block of all channels.
constexpr std::size_t kBlockFrames = 4096;

std::string num(double value) {
  std::ostringstream out;
  out << std::setprecision(10) << value;
  return out.str();
}

void check_sample_rate(const std::string& path, double rate_hz) {
  if (!(rate_hz >= kMinReplayRateHz && rate_hz <= kMaxReplayRateHz)) {
    std::ostringstream msg;
    msg << path << ": sample rate " << num(rate_hz) << " Hz is outside [" << kMinReplayRateHz << ", "
        << static_cast<long long>(kMaxReplayRateHz) << "] Hz";
    throw InputError(msg.str());
  }
}

void check_channel(const std::string& path, std::size_t channel, std::size_t channels) {
  if (channel >= channels) {
    throw InputError(path + ": channel " + std::to_string(channel) + " out of range (file has " +
                     std::to_string(channels) + (channels == 1 ? " channel)" : " channels)"));
  }
}

/// Index of the first NaN or infinite sample (samples.size() if none) and the message naming its
/// 0-based index in the stream and its time.
template <typename T>
std::size_t find_non_finite(const std::string& path, std::span<const T> samples, std::uint64_t first_index,
                            double rate_hz, std::string& message) {
  // Fast pass: NaN and Inf are the values whose exponent bits are all set; an OR over the block of
  // that integer test vectorises (measured 0.45 -> ~0.1 ns/sample with the per-sample isfinite branch).
  using Bits = std::conditional_t<sizeof(T) == 4, std::uint32_t, std::uint64_t>;
  constexpr Bits kExponent = static_cast<Bits>(sizeof(T) == 4 ? 0x7F800000ULL : 0x7FF0000000000000ULL);
  Bits any_bad = 0;
  for (const T x : samples) any_bad |= static_cast<Bits>((std::bit_cast<Bits>(x) & kExponent) == kExponent);
  if (any_bad == 0) return samples.size();
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const T x = samples[i];
    if (std::isfinite(x)) continue;
    const std::uint64_t index = first_index + i;
    const char* what = std::isnan(x) ? "NaN" : (x > 0 ? "+Inf" : "-Inf");
    message = path + ": sample " + std::to_string(index) + " is " + what + " (t = " +
              num(static_cast<double>(index) / rate_hz) + " s)";
    return i;
  }
  return samples.size();
}

bool has_text_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".csv" || ext == ".tsv" || ext == ".txt";
}

/// True when the first KiB contains no control bytes other than whitespace (ASCII or UTF-8 text).
bool looks_like_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::array<char, 1024> head{};
  in.read(head.data(), head.size());
  const auto n = static_cast<std::size_t>(in.gcount());
  if (n == 0) return false;
  return std::all_of(head.begin(), head.begin() + static_cast<std::ptrdiff_t>(n), [](char ch) {
    const auto c = static_cast<unsigned char>(ch);
    return c >= 0x20 ? c != 0x7F : (c == '\t' || c == '\n' || c == '\r');
  });
}

/// What a RIFF/WAVE header says, read by hand: libsndfile refuses a 0 Hz rate with the unhelpful
/// "SF_INFO struct incomplete", and silently shortens a truncated data chunk to what is present
/// (it only notes "should be" in its log), so the driver checks these two facts itself.
struct RiffWaveHeader {
  std::optional<std::uint32_t> sample_rate_hz;  ///< from the 'fmt ' chunk
  std::uint16_t channels = 0;
  std::uint16_t block_align_bytes = 0;          ///< bytes per frame
  std::optional<std::uint32_t> declared_data_bytes;  ///< size field of the 'data' chunk
  std::uint64_t present_data_bytes = 0;              ///< bytes actually in the file after the 'data' header
};

std::uint32_t le32(const unsigned char* p) {
  return static_cast<std::uint32_t>(p[0]) | static_cast<std::uint32_t>(p[1]) << 8 |
         static_cast<std::uint32_t>(p[2]) << 16 | static_cast<std::uint32_t>(p[3]) << 24;
}
std::uint16_t le16(const unsigned char* p) { return static_cast<std::uint16_t>(p[0] | p[1] << 8); }

/// Returns nothing unless the file starts like a little-endian RIFF/WAVE file.
std::optional<RiffWaveHeader> inspect_riff_wave(const std::string& path, std::uint64_t file_bytes) {
  std::ifstream in(path, std::ios::binary);
  std::array<unsigned char, 12> riff{};
  if (!in.read(reinterpret_cast<char*>(riff.data()), riff.size())) return std::nullopt;
  if (std::string_view(reinterpret_cast<const char*>(riff.data()), 4) != "RIFF" ||
      std::string_view(reinterpret_cast<const char*>(riff.data()) + 8, 4) != "WAVE") {
    return std::nullopt;
  }
  RiffWaveHeader header;
  std::uint64_t offset = 12;
  for (int chunk = 0; chunk < 1000 && offset + 8 <= file_bytes; ++chunk) {
    std::array<unsigned char, 8> chunk_header{};
    in.seekg(static_cast<std::streamoff>(offset));
    if (!in.read(reinterpret_cast<char*>(chunk_header.data()), chunk_header.size())) break;
    const std::string_view id(reinterpret_cast<const char*>(chunk_header.data()), 4);
    const std::uint32_t size_bytes = le32(chunk_header.data() + 4);
    if (id == "fmt " && size_bytes >= 16) {
      std::array<unsigned char, 16> fmt{};
      if (!in.read(reinterpret_cast<char*>(fmt.data()), fmt.size())) break;
      header.channels = le16(fmt.data() + 2);
      header.sample_rate_hz = le32(fmt.data() + 4);
      header.block_align_bytes = le16(fmt.data() + 12);
    } else if (id == "data") {
      header.declared_data_bytes = size_bytes;
      header.present_data_bytes = file_bytes - (offset + 8);
      break;  // samples follow; nothing after them matters here
    }
    offset += 8 + static_cast<std::uint64_t>(size_bytes) + (size_bytes & 1U);  // chunks are word-aligned
  }
  return header;
}

/// Audio through libsndfile, streamed block by block.
class SndfileSource final : public SampleSource {
 public:
  SndfileSource(SNDFILE* file, SourceInfo info, bool double_data)
      : file_(file, &sf_close), info_(std::move(info)), double_data_(double_data) {}

  const SourceInfo& info() const override { return info_; }

  std::size_t read(std::span<double> out) override { return read_as(out, interleaved_); }
  /// Decoded by libsndfile straight to float (no double round trip), except for 64-bit float files,
  /// whose values beyond the float range the default path reports as such.
  std::size_t read_float(std::span<float> out) override {
    if (double_data_) return SampleSource::read_float(out);
    return read_as(out, interleaved_float_);
  }

 private:
  static sf_count_t readf(SNDFILE* file, double* dest, sf_count_t frames) { return sf_readf_double(file, dest, frames); }
  static sf_count_t readf(SNDFILE* file, float* dest, sf_count_t frames) { return sf_readf_float(file, dest, frames); }

  template <typename T>
  std::size_t read_as(std::span<T> out, std::vector<T>& interleaved) {
    // A bad sample found by an earlier call: the good samples before it were delivered then.
    if (!pending_error_.empty()) throw InputError(pending_error_);
    std::size_t delivered = 0;
    while (delivered < out.size() && !finished_) {
      // Mono decodes straight into the caller's span, in one call (fewer read system calls);
      // multichannel goes through the de-interleave buffer of kBlockFrames frames.
      const std::size_t want = info_.channels == 1 ? out.size() - delivered : std::min(out.size() - delivered, kBlockFrames);
      std::span<T> dest = out.subspan(delivered, want);
      sf_count_t got = 0;
      if (info_.channels == 1) {
        got = readf(file_.get(), dest.data(), static_cast<sf_count_t>(want));
      } else {
        interleaved.resize(kBlockFrames * info_.channels);  // allocates on the first call only
        got = readf(file_.get(), interleaved.data(), static_cast<sf_count_t>(want));
        for (sf_count_t f = 0; f < got; ++f) {
          dest[static_cast<std::size_t>(f)] = interleaved[static_cast<std::size_t>(f) * info_.channels + info_.channel];
        }
      }
      const auto got_frames = static_cast<std::size_t>(std::max<sf_count_t>(got, 0));
      std::string bad;
      const std::size_t good = find_non_finite<T>(info_.name, dest.first(got_frames), frames_read_, info_.sample_rate_hz, bad);
      if (good < got_frames) {
        // Deliver the samples before the bad one (a consumer streaming block by block then sees the
        // same data whatever its block size) and report the error on this call if there are none,
        // else on the next one.
        delivered += good;
        frames_read_ += good;
        finished_ = true;
        if (delivered == 0) throw InputError(bad);
        pending_error_ = bad;
        return delivered;
      }
      frames_read_ += got_frames;
      delivered += got_frames;
      if (got_frames < want) {
        finished_ = true;
        check_complete();
      }
    }
    return delivered;
  }

  /// Called at the end of the stream: a decoder error or fewer frames than the header declared
  /// means the file is damaged, and a shortened analysis would be a silent wrong answer.
  void check_complete() const {
    const std::string position = "after " + std::to_string(frames_read_) +
                                 (info_.frames ? " of " + std::to_string(*info_.frames) : std::string()) + " frames";
    if (sf_error(file_.get()) != SF_ERR_NO_ERROR) {
      throw InputError(info_.name + ": truncated or corrupt: decoding stopped " + position +
                       " (libsndfile: " + sf_strerror(file_.get()) + ")");
    }
    if (info_.frames && frames_read_ < *info_.frames) {
      throw InputError(info_.name + ": truncated: data ended " + position);
    }
  }

  std::unique_ptr<SNDFILE, int (*)(SNDFILE*)> file_;
  SourceInfo info_;
  bool double_data_ = false;               ///< 64-bit float samples (read_float goes through double)
  std::vector<double> interleaved_;        ///< one block of all channels (multichannel files)
  std::vector<float> interleaved_float_;   ///< the same for read_float
  std::uint64_t frames_read_ = 0;
  bool finished_ = false;
  std::string pending_error_;  ///< NaN/Inf found after some good samples of the same call
};

/// Samples already in memory (parsed CSV).
class VectorSource final : public SampleSource {
 public:
  VectorSource(std::vector<double> samples, SourceInfo info) : samples_(std::move(samples)), info_(std::move(info)) {}

  const SourceInfo& info() const override { return info_; }

  std::size_t read(std::span<double> out) override {
    const std::size_t n = std::min(out.size(), samples_.size() - position_);
    std::copy_n(samples_.begin() + static_cast<std::ptrdiff_t>(position_), n, out.begin());
    position_ += n;
    return n;
  }

 private:
  std::vector<double> samples_;
  SourceInfo info_;
  std::size_t position_ = 0;
};

std::unique_ptr<SampleSource> open_csv(const std::string& path, const ReplayOptions& options) {
  CsvSeries series = read_csv_series(path, options.channel, options.csv_rate_hz);
  check_sample_rate(path, series.sample_rate_hz);
  SourceInfo info;
  info.name = path;
  info.sample_rate_hz = series.sample_rate_hz;
  info.channels = series.value_columns;
  info.channel = options.channel;
  info.frames = series.values.size();
  return std::make_unique<VectorSource>(std::move(series.values), std::move(info));
}

std::unique_ptr<SampleSource> open_audio(const std::string& path, std::uint64_t file_bytes,
                                         const ReplayOptions& options) {
  const auto riff = inspect_riff_wave(path, file_bytes);
  if (riff && riff->sample_rate_hz) check_sample_rate(path, static_cast<double>(*riff->sample_rate_hz));
  if (riff && riff->sample_rate_hz && riff->channels == 0) throw InputError(path + ": header declares 0 channels");

  SF_INFO sf_info{};
  SNDFILE* raw = sf_open(path.c_str(), SFM_READ, &sf_info);
  if (raw == nullptr) {
    // sf_strerror(nullptr) reports the last open failure (process-wide in libsndfile).
    std::string msg = path + ": not an audio file (libsndfile: " + sf_strerror(nullptr) + ")";
    if (looks_like_text(path)) msg += "; it looks like text: name CSV data *.csv or *.txt";
    throw InputError(msg);
  }
  std::unique_ptr<SNDFILE, int (*)(SNDFILE*)> file(raw, &sf_close);

  SourceInfo info;
  info.name = path;
  info.sample_rate_hz = static_cast<double>(sf_info.samplerate);
  info.channels = static_cast<std::size_t>(std::max(sf_info.channels, 0));
  info.channel = options.channel;
  if (sf_info.frames >= 0 && sf_info.frames != SF_COUNT_MAX) info.frames = static_cast<std::uint64_t>(sf_info.frames);

  check_sample_rate(path, info.sample_rate_hz);
  if (info.channels == 0) throw InputError(path + ": header declares 0 channels");
  check_channel(path, options.channel, info.channels);

  // libsndfile trims a data chunk that runs past the end of the file to what is present and
  // reports that shorter length as the frame count; the declared size is the honest one. Sizes 0
  // and 0xFFFFFFFF are placeholders of recorders that never finalised the header, not truncation.
  if (riff && riff->declared_data_bytes && riff->block_align_bytes > 0 && *riff->declared_data_bytes != 0 &&
      *riff->declared_data_bytes != 0xFFFFFFFFU && *riff->declared_data_bytes > riff->present_data_bytes) {
    const std::uint64_t declared_frames = *riff->declared_data_bytes / riff->block_align_bytes;
    const std::uint64_t present_frames = riff->present_data_bytes / riff->block_align_bytes;
    throw InputError(path + ": truncated: header declares " + std::to_string(declared_frames) + " frames (" +
                     std::to_string(*riff->declared_data_bytes) + " data bytes) but the file holds only " +
                     std::to_string(present_frames) + " frames (" + std::to_string(riff->present_data_bytes) +
                     " bytes)");
  }
  if (info.frames && *info.frames == 0) throw InputError(path + ": empty (0 samples)");

  const bool double_data = (sf_info.format & SF_FORMAT_SUBMASK) == SF_FORMAT_DOUBLE;
  const bool float_data = double_data || (sf_info.format & SF_FORMAT_SUBMASK) == SF_FORMAT_FLOAT;
  if (!float_data) info.full_scale = 1.0;  // integer PCM (and companded formats) decode to +-1.0
  return std::make_unique<SndfileSource>(file.release(), std::move(info), double_data);
}

}  // namespace

std::unique_ptr<SampleSource> open_replay(const std::string& path, const ReplayOptions& options) {
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) throw InputError(path + ": file does not exist");
  if (fs::is_directory(status)) throw InputError(path + ": is a directory, not a file");
  const std::uintmax_t file_bytes = fs::file_size(path, ec);
  if (ec) throw InputError(path + ": cannot determine the file size (" + ec.message() + ")");
  if (file_bytes == 0) throw InputError(path + ": empty file (0 bytes)");
  {
    std::ifstream probe(path, std::ios::binary);
    if (!probe) throw InputError(path + ": cannot open for reading (permission denied?)");
  }
  if (has_text_extension(path)) return open_csv(path, options);
  return open_audio(path, static_cast<std::uint64_t>(file_bytes), options);
}

}  // namespace ridgewatch::drivers
