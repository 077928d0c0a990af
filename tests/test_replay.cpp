// Replay driver: every supported file layout reads back exactly what was written, and every kind of
// bad input ends in an InputError that names the file and the problem. Fixtures are generated at test
// time in a private temporary directory (libsndfile for audio, ofstream for text, raw bytes for
// broken files), so the expected values are known exactly.
#include <gtest/gtest.h>
#include <sndfile.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "drivers/replay_file.hpp"
#include "drivers/sample_source.hpp"
#include "drivers/wav_writer.hpp"

namespace rd = ridgewatch::drivers;
namespace fs = std::filesystem;

namespace {

/// Writes frames through libsndfile's int or double API in any format. Ints are 32-bit full scale,
/// so an N-bit file stores the top N bits (passing `v << (32 - N)` stores exactly v); doubles are
/// rounded/scaled to the format as a recorder would.
template <typename T>
void write_audio(const std::string& path, int format, int rate_hz, int channels, const std::vector<T>& interleaved) {
  SF_INFO info{};
  info.samplerate = rate_hz;
  info.channels = channels;
  info.format = format;
  SNDFILE* file = sf_open(path.c_str(), SFM_WRITE, &info);
  ASSERT_NE(file, nullptr) << path << ": " << sf_strerror(nullptr);
  const auto frames = static_cast<sf_count_t>(interleaved.size()) / channels;
  if constexpr (std::is_same_v<T, int>) EXPECT_EQ(sf_writef_int(file, interleaved.data(), frames), frames);
  else EXPECT_EQ(sf_writef_double(file, interleaved.data(), frames), frames);
  ASSERT_EQ(sf_close(file), 0);
}

void write_int_pcm(const std::string& path, int format, int rate_hz, int channels, const std::vector<int>& interleaved) {
  write_audio(path, format, rate_hz, channels, interleaved);
}
void write_double_audio(const std::string& path, int format, int rate_hz, int channels,
                        const std::vector<double>& interleaved) {
  write_audio(path, format, rate_hz, channels, interleaved);
}

void write_text(const std::string& path, const std::string& content) {
  std::ofstream out(path, std::ios::binary);
  out << content;
  ASSERT_TRUE(out.good()) << path;
}

std::vector<char> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(const std::string& path, const std::vector<char>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << path;
}

/// Runs `action`, which must throw InputError whose message contains every one of `needles`.
void expect_input_error(const std::function<void()>& action, const std::vector<std::string>& needles) {
  try {
    action();
    ADD_FAILURE() << "expected InputError, nothing was thrown";
  } catch (const rd::InputError& error) {
    const std::string message = error.what();
    for (const auto& needle : needles) {
      EXPECT_NE(message.find(needle), std::string::npos) << "message \"" << message << "\" lacks \"" << needle << "\"";
    }
  } catch (const std::exception& error) {
    ADD_FAILURE() << "expected InputError, got another exception: " << error.what();
  }
}

std::vector<double> read_file(const std::string& path, rd::ReplayOptions options = {}) {
  auto source = rd::open_replay(path, options);
  return rd::read_all(*source);
}

class ReplayTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* test = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("ridgewatch-replay-" + std::to_string(::getpid()) + "-" + test->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  /// A valid 16-bit mono 1 kHz WAV of `frames` frames with a ramp pattern; returns its path.
  std::string valid_wav16(const std::string& name, int frames = 1000) {
    std::vector<int> ints(static_cast<std::size_t>(frames));
    for (int i = 0; i < frames; ++i) ints[static_cast<std::size_t>(i)] = ((i * 37) % 2000 - 1000) << 16;
    const std::string p = path(name);
    write_int_pcm(p, SF_FORMAT_WAV | SF_FORMAT_PCM_16, 1000, 1, ints);
    return p;
  }

  fs::path dir_;
};

// ---------------------------------------------------------------------------------------------
// Good audio files: exact values.
// Integer PCM is read with libsndfile's normalisation 1 / 2^(N-1), so an integer v stored in an
// N-bit file must come back as exactly v / 2^(N-1) (exact in double for N <= 32). The tests write
// the integers directly, so they can demand exact equality instead of a quantisation tolerance.
// ---------------------------------------------------------------------------------------------

/// Integer test values spanning the full range of an N-bit word, including both extremes.
std::vector<int> full_range_values(int bits) {
  const long long max = (1LL << (bits - 1)) - 1;
  const long long min = -(1LL << (bits - 1));
  std::vector<int> values = {static_cast<int>(min), static_cast<int>(max), 0, 1, -1};
  for (int i = 0; i < 500; ++i) {
    // Deterministic spread over the whole range.
    const double phase = std::sin(0.37 * i + 0.1 * i * i);
    values.push_back(static_cast<int>(std::llround(phase * static_cast<double>(max))));
  }
  return values;
}

void check_exact_pcm(const std::string& file, int format, int bits) {
  const std::vector<int> values = full_range_values(bits);
  std::vector<int> stored(values.size());
  for (std::size_t i = 0; i < values.size(); ++i) {
    stored[i] = static_cast<int>(static_cast<std::uint32_t>(values[i]) << (32 - bits));
  }
  write_int_pcm(file, format, 48000, 1, stored);

  auto source = rd::open_replay(file, {});
  EXPECT_EQ(source->info().name, file);
  EXPECT_DOUBLE_EQ(source->info().sample_rate_hz, 48000.0);
  EXPECT_EQ(source->info().channels, 1U);
  ASSERT_TRUE(source->info().frames.has_value());
  EXPECT_EQ(*source->info().frames, values.size());
  const std::vector<double> samples = rd::read_all(*source);
  ASSERT_EQ(samples.size(), values.size());
  const double scale = std::ldexp(1.0, -(bits - 1));
  for (std::size_t i = 0; i < values.size(); ++i) {
    ASSERT_EQ(samples[i], values[i] * scale) << "sample " << i << " (" << bits << "-bit)";
  }
  EXPECT_EQ(samples[0], -1.0);  // negative full scale is exactly -1
}

TEST_F(ReplayTest, Wav16BitIntegersReadExactly) { check_exact_pcm(path("a16.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_16, 16); }
TEST_F(ReplayTest, Wav24BitIntegersReadExactly) { check_exact_pcm(path("a24.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_24, 24); }
TEST_F(ReplayTest, Wav32BitIntegersReadExactly) { check_exact_pcm(path("a32.wav"), SF_FORMAT_WAV | SF_FORMAT_PCM_32, 32); }
TEST_F(ReplayTest, Flac16BitReadsExactly) { check_exact_pcm(path("a16.flac"), SF_FORMAT_FLAC | SF_FORMAT_PCM_16, 16); }
TEST_F(ReplayTest, Flac24BitReadsExactly) { check_exact_pcm(path("a24.flac"), SF_FORMAT_FLAC | SF_FORMAT_PCM_24, 24); }

TEST_F(ReplayTest, Wav16BitFromDoublesWithinQuantisation) {
  // An analogue signal written through libsndfile's double API: it stores round(x * 32767) and reads
  // back / 32768, so the error is at most half a step plus the scale mismatch |x| / 32768:
  // <= 1.5 * 2^-15 for |x| <= 1.
  const std::string file = path("sine16.wav");
  std::vector<double> sine(2560);
  for (std::size_t i = 0; i < sine.size(); ++i) sine[i] = 0.9 * std::sin(2.0 * std::numbers::pi * 854.0 * static_cast<double>(i) / 25600.0);
  write_double_audio(file, SF_FORMAT_WAV | SF_FORMAT_PCM_16, 25600, 1, sine);

  const auto samples = read_file(file);
  ASSERT_EQ(samples.size(), sine.size());
  const double step = std::ldexp(1.0, -15);
  double max_error = 0.0;
  for (std::size_t i = 0; i < sine.size(); ++i) max_error = std::max(max_error, std::abs(samples[i] - sine[i]));
  EXPECT_LE(max_error, 1.5 * step);
  EXPECT_GT(max_error, 0.0);  // it really went through 16-bit quantisation
}

TEST_F(ReplayTest, FloatWavFromWriterRoundTripsUnscaled) {
  // write_wav stores float32: relative rounding error <= 2^-24. Values beyond full scale stay.
  const std::string file = path("float.wav");
  std::vector<double> x(3000);
  for (std::size_t i = 0; i < x.size(); ++i) x[i] = 1.5 * std::cos(0.01 * static_cast<double>(i)) + 1e-6;
  rd::write_wav(file, x, 51200.0);

  auto source = rd::open_replay(file, {});
  EXPECT_DOUBLE_EQ(source->info().sample_rate_hz, 51200.0);
  const auto samples = rd::read_all(*source);
  ASSERT_EQ(samples.size(), x.size());
  for (std::size_t i = 0; i < x.size(); ++i) {
    ASSERT_NEAR(samples[i], x[i], std::abs(x[i]) * std::ldexp(1.0, -24)) << "sample " << i;
  }
  EXPECT_GT(samples[0], 1.4);  // not clipped to 1.0
}

TEST_F(ReplayTest, MultichannelDeliversTheChosenChannelAcrossBlocks) {
  // 3 channels, more frames than one internal block (4096), channel c carries c * 0.25 + i * 1e-5.
  const std::size_t frames = 10000;
  const std::size_t channels = 3;
  std::vector<double> interleaved(frames * channels);
  for (std::size_t i = 0; i < frames; ++i) {
    for (std::size_t c = 0; c < channels; ++c) {
      interleaved[i * channels + c] = 0.25 * static_cast<double>(c) + 1e-5 * static_cast<double>(i) - 0.3;
    }
  }
  const std::string file = path("three.wav");
  rd::write_wav(file, interleaved, 10000.0, channels);

  for (std::size_t c = 0; c < channels; ++c) {
    auto source = rd::open_replay(file, {.channel = c, .csv_rate_hz = std::nullopt});
    EXPECT_EQ(source->info().channels, channels);
    EXPECT_EQ(source->info().channel, c);
    // Odd-sized reads exercise block boundaries inside read().
    std::vector<double> got;
    std::vector<double> block(777);
    for (std::size_t n; (n = source->read(block)) > 0;) got.insert(got.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(n));
    ASSERT_EQ(got.size(), frames);
    for (std::size_t i = 0; i < frames; ++i) {
      const double expected = interleaved[i * channels + c];
      ASSERT_NEAR(got[i], expected, std::abs(expected) * std::ldexp(1.0, -24)) << "channel " << c << " frame " << i;
    }
    EXPECT_EQ(source->read(block), 0U);  // stays at end of stream
  }
}

TEST_F(ReplayTest, Multichannel16BitIntegerChannelChoice) {
  std::vector<int> interleaved;
  for (int i = 0; i < 300; ++i) {
    interleaved.push_back(i << 16);         // channel 0: i / 32768
    interleaved.push_back((-i - 1) << 16);  // channel 1: -(i + 1) / 32768
  }
  const std::string file = path("stereo16.wav");
  write_int_pcm(file, SF_FORMAT_WAV | SF_FORMAT_PCM_16, 44100, 2, interleaved);
  const auto right = read_file(file, {.channel = 1, .csv_rate_hz = std::nullopt});
  ASSERT_EQ(right.size(), 300U);
  for (int i = 0; i < 300; ++i) ASSERT_EQ(right[static_cast<std::size_t>(i)], -(i + 1) / 32768.0);
}

TEST_F(ReplayTest, NaNInAnUnselectedChannelDoesNotMatter) {
  std::vector<double> interleaved = {0.1, 0.2, std::numeric_limits<double>::quiet_NaN(), 0.4, 0.5, 0.6};
  const std::string file = path("nan-left.wav");
  rd::write_wav(file, interleaved, 1000.0, 2);
  const auto right = read_file(file, {.channel = 1, .csv_rate_hz = std::nullopt});
  ASSERT_EQ(right.size(), 3U);
  EXPECT_NEAR(right[1], 0.4, 1e-7);
  expect_input_error([&] { read_file(file, {}); }, {file, "sample 1 is NaN"});
}

// ---------------------------------------------------------------------------------------------
// Good CSV files.
// ---------------------------------------------------------------------------------------------

TEST_F(ReplayTest, CsvOneColumnUsesTheGivenRate) {
  const std::string file = path("values.csv");
  write_text(file, "0.5\n-0.25\n1e-3\n+2\n");
  auto source = rd::open_replay(file, {.channel = 0, .csv_rate_hz = 25600.0});
  EXPECT_DOUBLE_EQ(source->info().sample_rate_hz, 25600.0);
  EXPECT_EQ(source->info().frames, std::optional<std::uint64_t>(4));
  EXPECT_EQ(rd::read_all(*source), (std::vector<double>{0.5, -0.25, 1e-3, 2.0}));
}

TEST_F(ReplayTest, CsvTimeAndValueWithHeaderLines) {
  const std::string file = path("scope.csv");
  std::string text = "Instrument: scope XYZ\r\ntime_s,accel_g\r\n\r\n";
  std::vector<double> expected;
  for (int i = 0; i < 200; ++i) {
    const double v = std::sin(0.1 * i);
    expected.push_back(std::stod(std::to_string(v)));  // what the text holds (6 decimals)
    text += std::to_string(0.5 + i * 0.0005) + "," + std::to_string(v) + "\r\n";
  }
  write_text(file, text);
  auto source = rd::open_replay(file, {});
  EXPECT_NEAR(source->info().sample_rate_hz, 2000.0, 1e-6);
  EXPECT_EQ(rd::read_all(*source), expected);
}

TEST_F(ReplayTest, CsvDecimalCommaWithSemicolon) {
  const std::string file = path("excel.csv");
  write_text(file, "Zeit [s];Wert\n0,000;0,125\n0,001;1,5\n0,002;-2,25\n0,003;1e-2\n");
  auto source = rd::open_replay(file, {});
  EXPECT_NEAR(source->info().sample_rate_hz, 1000.0, 1e-9);
  EXPECT_EQ(rd::read_all(*source), (std::vector<double>{0.125, 1.5, -2.25, 0.01}));
}

TEST_F(ReplayTest, CsvDecimalCommaWithTabsAndSecondValueColumn) {
  const std::string file = path("daq.txt");
  write_text(file, "t\tch0\tch1\n0,0000\t1,0\t-0,5\n0,0001\t2,0\t-0,75\n0,0002\t3,0\t-1,0\n");
  auto source = rd::open_replay(file, {.channel = 1, .csv_rate_hz = std::nullopt});
  EXPECT_NEAR(source->info().sample_rate_hz, 10000.0, 1e-6);
  EXPECT_EQ(source->info().channels, 2U);
  EXPECT_EQ(rd::read_all(*source), (std::vector<double>{-0.5, -0.75, -1.0}));
}

TEST_F(ReplayTest, CsvWhitespaceSeparatedWithComments) {
  const std::string file = path("plain.txt");
  write_text(file, "# exported by rig-logger\n  0.00   10\n  0.01   20\n# pause marker\n  0.02   30\n");
  auto source = rd::open_replay(file, {});
  EXPECT_NEAR(source->info().sample_rate_hz, 100.0, 1e-9);
  EXPECT_EQ(rd::read_all(*source), (std::vector<double>{10.0, 20.0, 30.0}));
}

TEST_F(ReplayTest, CsvCoarselyPrintedTimeStampsAreAccepted) {
  // 44.1 kHz stamps printed with 6 decimals: single steps are 22 or 23 us (4 % apart) because of
  // rounding, not jitter. The rate comes from the whole span, so it is accurate to ~1e-6 / 0.01 s.
  const std::string file = path("fine.csv");
  std::string text;
  const int n = 441;
  for (int i = 0; i < n; ++i) {
    char line[64];
    std::snprintf(line, sizeof line, "%.6f,%d\n", i / 44100.0, i);
    text += line;
  }
  write_text(file, text);
  auto source = rd::open_replay(file, {});
  EXPECT_NEAR(source->info().sample_rate_hz, 44100.0, 44100.0 * 1e-4);
  EXPECT_EQ(rd::read_all(*source).size(), static_cast<std::size_t>(n));
}

TEST_F(ReplayTest, CsvGivenRateMustAgreeWithTimeColumn) {
  const std::string file = path("tv.csv");
  write_text(file, "0,1\n0.001,2\n0.002,3\n");
  EXPECT_NO_THROW(read_file(file, {.channel = 0, .csv_rate_hz = 1000.0}));
  expect_input_error([&] { read_file(file, {.channel = 0, .csv_rate_hz = 2000.0}); }, {file, "disagrees", "1000"});
}

// ---------------------------------------------------------------------------------------------
// The real recording (optional: ../shared is absent in a user's fresh clone).
// ---------------------------------------------------------------------------------------------

TEST(ReplayRealData, PlateHit16BitMono) {
  const std::string file = std::string(RIDGEWATCH_SHARED_DIR) + "/real-data/plate-hits/hit-2.wav";
  if (!fs::exists(file)) GTEST_SKIP() << file << " not present";
  auto source = rd::open_replay(file, {});
  EXPECT_DOUBLE_EQ(source->info().sample_rate_hz, 44100.0);
  EXPECT_EQ(source->info().channels, 1U);
  EXPECT_EQ(source->info().frames, std::optional<std::uint64_t>(17093));  // 34186 data bytes / 2
  const auto samples = rd::read_all(*source);
  ASSERT_EQ(samples.size(), 17093U);
  double peak = 0.0;
  for (const double x : samples) {
    ASSERT_TRUE(std::isfinite(x));
    ASSERT_GE(x, -1.0);
    ASSERT_LE(x, 1.0);
    // 16-bit PCM: every value is a whole number of quantisation steps 2^-15.
    ASSERT_EQ(x * 32768.0, std::round(x * 32768.0));
    peak = std::max(peak, std::abs(x));
  }
  EXPECT_GT(peak, 0.01);  // there is a hit in it, not silence
}

// ---------------------------------------------------------------------------------------------
// Bad input: type InputError, message names the file and the problem.
// ---------------------------------------------------------------------------------------------

TEST_F(ReplayTest, MissingFile) {
  const std::string file = path("nope.wav");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "does not exist"});
}

TEST_F(ReplayTest, DirectoryInsteadOfFile) {
  expect_input_error([&] { rd::open_replay(dir_.string(), {}); }, {dir_.string(), "directory"});
}

TEST_F(ReplayTest, EmptyFile) {
  const std::string wav = path("empty.wav");
  const std::string csv = path("empty.csv");
  write_text(wav, "");
  write_text(csv, "");
  expect_input_error([&] { rd::open_replay(wav, {}); }, {wav, "empty"});
  expect_input_error([&] { rd::open_replay(csv, {.channel = 0, .csv_rate_hz = 1000.0}); }, {csv, "empty"});
}

TEST_F(ReplayTest, WavWithZeroFrames) {
  const std::string file = path("zero-frames.wav");
  write_int_pcm(file, SF_FORMAT_WAV | SF_FORMAT_PCM_16, 1000, 1, {});
  ASSERT_GT(fs::file_size(file), 0U);  // a proper header, just no samples
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "empty (0 samples)"});
}

TEST_F(ReplayTest, TruncatedWavIsReportedNotSilentlyShortened) {
  // libsndfile itself opens this file and reports 500 frames (it trims the data chunk to what is
  // present and only notes "should be" in its log); the driver must say the file is truncated.
  const std::string full = valid_wav16("full.wav", 1000);
  auto bytes = read_bytes(full);
  ASSERT_EQ(bytes.size(), 44U + 2000U);
  bytes.resize(44 + 1001);  // 500.5 frames left
  const std::string file = path("cut.wav");
  write_bytes(file, bytes);
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "truncated", "declares 1000 frames", "only 500 frames"});
}

TEST_F(ReplayTest, WavWithHeaderOnlyIsTruncated) {
  auto bytes = read_bytes(valid_wav16("full.wav", 1000));
  bytes.resize(44);
  const std::string file = path("header-only.wav");
  write_bytes(file, bytes);
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "truncated", "only 0 frames"});
}

TEST_F(ReplayTest, TruncatedFlacFailsWhileReading) {
  // FLAC carries the frame count in its header; libsndfile opens a cut file fine and the decoder
  // fails ("lost sync") when it reaches the cut. That surfaces in read().
  std::vector<int> ints(20000);
  for (std::size_t i = 0; i < ints.size(); ++i) ints[i] = static_cast<int>(std::lround(3e8 * std::sin(0.05 * static_cast<double>(i))));
  const std::string full = path("full.flac");
  write_int_pcm(full, SF_FORMAT_FLAC | SF_FORMAT_PCM_16, 8000, 1, ints);
  auto bytes = read_bytes(full);
  bytes.resize(bytes.size() / 2);
  const std::string file = path("cut.flac");
  write_bytes(file, bytes);

  auto source = rd::open_replay(file, {});
  EXPECT_EQ(source->info().frames, std::optional<std::uint64_t>(20000));
  expect_input_error([&] { rd::read_all(*source); }, {file, "truncated", "of 20000 frames"});
}

TEST_F(ReplayTest, GarbageBytes) {
  std::vector<char> garbage(4000);
  std::uint32_t state = 12345;
  for (auto& b : garbage) {
    state = state * 1664525U + 1013904223U;
    b = static_cast<char>(state >> 24);
  }
  const std::string file = path("garbage.wav");
  write_bytes(file, garbage);
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "not an audio file", "libsndfile"});
}

TEST_F(ReplayTest, TextWithAudioExtensionGetsAHint) {
  const std::string file = path("samples.dat");
  write_text(file, "0.1\n0.2\n0.3\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "not an audio file", ".csv"});
}

TEST_F(ReplayTest, NaNAndInfSamplesAreNamedByIndex) {
  std::vector<double> x(6000, 0.25);
  const std::string nan_file = path("nan.wav");
  x[1234] = std::numeric_limits<double>::quiet_NaN();
  rd::write_wav(nan_file, x, 8000.0);
  expect_input_error([&] { read_file(nan_file); }, {nan_file, "sample 1234 is NaN", "t = 0.15425 s"});

  // Beyond the first internal block (4096), so the index must carry across blocks.
  const std::string inf_file = path("inf.wav");
  x[1234] = 0.25;
  x[5000] = std::numeric_limits<double>::infinity();
  rd::write_wav(inf_file, x, 8000.0);
  expect_input_error([&] { read_file(inf_file); }, {inf_file, "sample 5000 is +Inf"});

  const std::string minus_inf_file = path("minus-inf.wav");
  x[5000] = -std::numeric_limits<double>::infinity();
  rd::write_wav(minus_inf_file, x, 8000.0);
  expect_input_error([&] { read_file(minus_inf_file); }, {minus_inf_file, "sample 5000 is -Inf"});
}

/// Reads a source to its end through read_float in blocks of `block` samples.
std::vector<float> read_all_float(rd::SampleSource& source, std::size_t block = 1000) {
  std::vector<float> all, buf(block);
  for (;;) {
    const std::size_t n = source.read_float(buf);
    if (n == 0) break;
    all.insert(all.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
  }
  return all;
}

// read_float (libsndfile's float decoder, or the double path for 64-bit files) must give exactly the
// values of read() rounded to float: the daemon and `ridgewatch analyze` read with it, the pipeline
// was validated on the rounded doubles. Exact equality is the right check: both are one correctly
// rounded conversion of the same stored value (integers scaled by a power of two, or float/double).
TEST_F(ReplayTest, ReadFloatEqualsRoundedDoublesForEveryFormat) {
  const int n = 9000;  // more than two of the driver's 4096-frame blocks
  std::vector<int> ints(static_cast<std::size_t>(2 * n));
  std::vector<double> reals(static_cast<std::size_t>(2 * n));
  for (int i = 0; i < 2 * n; ++i) {
    // All 32 bits busy (the low bits matter for PCM_32, whose values do not fit a float exactly).
    const auto u = static_cast<std::uint32_t>(i) * 2654435761U;
    ints[static_cast<std::size_t>(i)] = static_cast<int>(u);
    reals[static_cast<std::size_t>(i)] = 0.9 * std::sin(0.0123 * i) + 1e-9 * (i % 7);
  }
  const std::vector<std::pair<std::string, int>> formats = {
      {"pcm16.wav", SF_FORMAT_WAV | SF_FORMAT_PCM_16}, {"pcm24.wav", SF_FORMAT_WAV | SF_FORMAT_PCM_24},
      {"pcm32.wav", SF_FORMAT_WAV | SF_FORMAT_PCM_32}, {"float.wav", SF_FORMAT_WAV | SF_FORMAT_FLOAT},
      {"double.wav", SF_FORMAT_WAV | SF_FORMAT_DOUBLE}, {"flac24.flac", SF_FORMAT_FLAC | SF_FORMAT_PCM_24}};
  for (const auto& [name, format] : formats) {
    for (int channels : {1, 2}) {
      SCOPED_TRACE(name + " channels " + std::to_string(channels));
      const std::string file = path(std::to_string(channels) + name);
      const int sub = format & SF_FORMAT_SUBMASK;
      if (sub == SF_FORMAT_FLOAT || sub == SF_FORMAT_DOUBLE) {
        write_double_audio(file, format, 8000, channels, std::vector<double>(reals.begin(), reals.begin() + n * channels));
      } else {
        write_int_pcm(file, format, 8000, channels, std::vector<int>(ints.begin(), ints.begin() + n * channels));
      }
      rd::ReplayOptions options;
      options.channel = static_cast<std::size_t>(channels - 1);
      const std::vector<double> d = read_file(file, options);
      auto source = rd::open_replay(file, options);
      const std::vector<float> f = read_all_float(*source, 777);
      ASSERT_EQ(f.size(), d.size());
      ASSERT_EQ(d.size(), static_cast<std::size_t>(n));
      std::size_t differ = 0;
      for (std::size_t i = 0; i < d.size(); ++i) differ += f[i] != static_cast<float>(d[i]);
      EXPECT_EQ(differ, 0U);
    }
  }
}

TEST_F(ReplayTest, ReadFloatDeliversTheSamplesBeforeABadOneThenNamesIt) {
  std::vector<double> x(6000, 0.25);
  x[5000] = std::numeric_limits<double>::quiet_NaN();
  const std::string file = path("nan.wav");
  rd::write_wav(file, x, 8000.0);
  auto source = rd::open_replay(file, {});
  std::vector<float> buf(4500);
  EXPECT_EQ(source->read_float(buf), 4500U);
  EXPECT_EQ(source->read_float(buf), 500U);  // the good samples before the NaN
  expect_input_error([&] { source->read_float(buf); }, {file, "sample 5000 is NaN"});
}

TEST_F(ReplayTest, ReadFloatRejectsADoubleBeyondTheFloatRange) {
  // Finite in a 64-bit file, but +Inf once rounded to float: an error, never an Inf in the pipeline.
  std::vector<double> x(3000, 0.5);
  x[2100] = 1e300;
  const std::string file = path("huge.wav");
  write_double_audio(file, SF_FORMAT_WAV | SF_FORMAT_DOUBLE, 8000, 1, x);
  EXPECT_EQ(read_file(file).size(), 3000U);  // read() delivers it as it is
  auto source = rd::open_replay(file, {});
  std::vector<float> buf(2000);
  EXPECT_EQ(source->read_float(buf), 2000U);
  EXPECT_EQ(source->read_float(buf), 100U);
  expect_input_error([&] { source->read_float(buf); }, {file, "sample 2100", "single-precision range"});
  // The stream ends there: later calls report the same error instead of going on after a hole.
  expect_input_error([&] { source->read_float(buf); }, {file, "sample 2100", "single-precision range"});
}

/// Overwrites the sample-rate field (bytes 24..27, little endian) of a canonical 44-byte-header WAV.
void patch_wav_rate(std::vector<char>& bytes, std::uint32_t rate_hz) {
  ASSERT_EQ(std::string(bytes.data() + 12, 4), "fmt ");
  for (int i = 0; i < 4; ++i) bytes[static_cast<std::size_t>(24 + i)] = static_cast<char>((rate_hz >> (8 * i)) & 0xFFU);
}

TEST_F(ReplayTest, ZeroSampleRate) {
  // libsndfile refuses to write a 0 Hz file (and refuses to open one with "SF_INFO struct
  // incomplete"), so patch the header of a valid file.
  auto bytes = read_bytes(valid_wav16("ok.wav"));
  patch_wav_rate(bytes, 0);
  const std::string file = path("rate0.wav");
  write_bytes(file, bytes);
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "sample rate 0 Hz is outside [100, 5000000] Hz"});
}

TEST_F(ReplayTest, AbsurdSampleRates) {
  auto bytes = read_bytes(valid_wav16("ok.wav"));
  patch_wav_rate(bytes, 268435456);
  const std::string high = path("rate-huge.wav");
  write_bytes(high, bytes);
  expect_input_error([&] { rd::open_replay(high, {}); }, {high, "sample rate 268435456 Hz", "outside"});

  const std::string low = path("rate50.wav");
  write_int_pcm(low, SF_FORMAT_WAV | SF_FORMAT_PCM_16, 50, 1, std::vector<int>(100, 0));
  expect_input_error([&] { rd::open_replay(low, {}); }, {low, "sample rate 50 Hz", "outside"});

  const std::string csv = path("slow.csv");
  write_text(csv, "1\n2\n3\n");
  expect_input_error([&] { rd::open_replay(csv, {.channel = 0, .csv_rate_hz = 10.0}); }, {csv, "sample rate 10 Hz", "outside"});
}

TEST_F(ReplayTest, ChannelOutOfRange) {
  const std::string file = path("stereo.wav");
  rd::write_wav(file, std::vector<double>(200, 0.1), 1000.0, 2);
  expect_input_error([&] { rd::open_replay(file, {.channel = 3, .csv_rate_hz = std::nullopt}); },
                     {file, "channel 3 out of range (file has 2 channels)"});
  const std::string csv = path("tv.csv");
  write_text(csv, "0,1\n0.001,2\n");
  expect_input_error([&] { rd::open_replay(csv, {.channel = 1, .csv_rate_hz = std::nullopt}); }, {csv, "channel 1 out of range"});
}

TEST_F(ReplayTest, CsvOneColumnWithoutRate) {
  const std::string file = path("values.csv");
  write_text(file, "0.1\n0.2\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "--rate HZ"});
}

TEST_F(ReplayTest, CsvMissingValueNamesTheLine) {
  const std::string file = path("gap.csv");
  std::string text = "time,value\n";
  for (int i = 0; i < 15; ++i) text += std::to_string(i * 0.001) + "," + std::to_string(i) + "\n";
  text += "0.015,\n";  // line 17
  write_text(file, text);
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "line 17: missing value"});

  const std::string short_line = path("short.csv");
  write_text(short_line, "0;1\n0,001;2\n0,002\n");
  expect_input_error([&] { rd::open_replay(short_line, {}); }, {short_line, "line 3: missing value"});
}

TEST_F(ReplayTest, CsvJunkNamesTheLineAndText) {
  const std::string file = path("junk.csv");
  write_text(file, "0.1\n0.2\nabc\n0.4\n");
  expect_input_error([&] { rd::open_replay(file, {.channel = 0, .csv_rate_hz = 1000.0}); },
                     {file, "line 3: 'abc' is not a number"});
  const std::string extra = path("extra.csv");
  write_text(extra, "0,1\n0.001,2,3\n");
  expect_input_error([&] { rd::open_replay(extra, {}); }, {extra, "line 2: too many values"});
}

TEST_F(ReplayTest, CsvNonFiniteValue) {
  const std::string file = path("nan.csv");
  write_text(file, "0,1\n0.001,nan\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "line 2", "not finite"});
}

TEST_F(ReplayTest, CsvHeaderOnly) {
  const std::string file = path("header.csv");
  write_text(file, "time;value\nunit s;unit g\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "empty (0 samples"});
}

TEST_F(ReplayTest, CsvNonUniformTime) {
  const std::string file = path("jitter.csv");
  // Steps of 1 ms, then one of 1.5 ms arriving on line 6 (stamps resolve 0.1 ms, so it is real).
  write_text(file, "t,v\n0.0000,1\n0.0010,2\n0.0020,3\n0.0030,4\n0.0045,5\n0.0055,6\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "line 6: non-uniform time step"});
}

TEST_F(ReplayTest, CsvMissingSampleIsNotExcusedByCoarseRounding) {
  // Stamps printed with exactly the step's resolution: a skipped sample is a 100 % deviation.
  const std::string file = path("skip.csv");
  write_text(file, "0.001,1\n0.002,2\n0.003,3\n0.005,5\n0.006,6\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "line 4: non-uniform"});
}

TEST_F(ReplayTest, CsvTimeMustIncrease) {
  const std::string file = path("backwards.csv");
  write_text(file, "0.000,1\n0.001,2\n0.001,3\n");
  expect_input_error([&] { rd::open_replay(file, {}); }, {file, "line 3", "must increase"});
}

// ---------------------------------------------------------------------------------------------
// write_wav argument and I/O errors.
// ---------------------------------------------------------------------------------------------

TEST_F(ReplayTest, WriteWavRejectsBadArguments) {
  const std::vector<double> x(10, 0.0);
  EXPECT_THROW(rd::write_wav(path("a.wav"), x, 1000.5), std::invalid_argument);
  EXPECT_THROW(rd::write_wav(path("a.wav"), x, 0.0), std::invalid_argument);
  EXPECT_THROW(rd::write_wav(path("a.wav"), x, 1000.0, 3), std::invalid_argument);  // 10 % 3 != 0
  EXPECT_THROW(rd::write_wav(path("a.wav"), x, 1000.0, 0), std::invalid_argument);
  try {
    rd::write_wav(path("no-such-dir/a.wav"), x, 1000.0);
    ADD_FAILURE() << "expected std::runtime_error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("no-such-dir/a.wav"), std::string::npos) << error.what();
  }
}

}  // namespace
