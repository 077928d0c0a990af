// AlsaSource against libasound's `file` PCM plugin (defined in a local config, the global ALSA
// configuration is not touched): samples equal the raw file's scaled values for every format, channel
// selection, clear errors, xrun recovery and device loss with backoff through the opener/sleep seam.
#include "drivers/alsa_source.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace rd = ridgewatch::drivers;
namespace fs = std::filesystem;
using std::chrono::milliseconds;

namespace {

class AlsaSourceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ridgewatch-alsa-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  template <typename T>
  std::string write_raw(const std::vector<T>& interleaved) {
    const std::string path = (dir_ / "in.raw").string();
    std::ofstream out(path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(interleaved.data()), static_cast<std::streamsize>(interleaved.size() * sizeof(T)));
    EXPECT_TRUE(out.good());
    return path;
  }

  /// A capture PCM "rwtest" that reads `infile` (no pacing, see alsa_source.hpp).
  static std::shared_ptr<const rd::AlsaLocalConfig> file_pcm(const std::string& infile) {
    return rd::AlsaLocalConfig::from_string("pcm.rwtest { type file slave.pcm { type null } file \"/dev/null\" infile \"" +
                                            infile + "\" format \"raw\" }");
  }

  static rd::AlsaSourceConfig config(rd::AlsaSampleFormat format, unsigned channels, unsigned channel) {
    rd::AlsaSourceConfig c;
    c.device = "rwtest";
    c.rate_hz = 48000;
    c.channels = channels;
    c.channel = channel;
    c.format = format;
    c.period_frames = 64;
    c.buffer_frames = 256;
    c.reopen_min_ms = milliseconds(10);
    c.reopen_max_ms = milliseconds(40);
    return c;
  }

  /// Reads exactly n samples (the plugin has no end of file, so never more than the file holds).
  static std::vector<double> read_n(rd::AlsaSource& source, std::size_t n) {
    std::vector<double> out(n);
    std::size_t done = 0;
    while (done < n) {
      const std::size_t got = source.read(std::span(out).subspan(done));
      EXPECT_GT(got, 0u);
      if (got == 0) break;
      done += got;
    }
    return out;
  }

  fs::path dir_;
};

TEST_F(AlsaSourceTest, S16StereoDeliversTheChosenChannelScaled) {
  std::vector<std::int16_t> raw;
  for (int i = 0; i < 300; ++i) {
    raw.push_back(static_cast<std::int16_t>(i * 100 - 15000));
    raw.push_back(static_cast<std::int16_t>(-i * 7));
  }
  raw[1] = -32768;  // full-scale negative -> exactly -1.0
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 2, 1), local);
  EXPECT_EQ(source.info().name, "alsa rwtest");
  EXPECT_EQ(source.info().sample_rate_hz, 48000.0);
  EXPECT_FALSE(source.info().frames.has_value());
  const auto got = read_n(source, 300);
  for (std::size_t i = 0; i < got.size(); ++i) ASSERT_EQ(got[i], raw[2 * i + 1] / 32768.0) << "frame " << i;
  EXPECT_EQ(got[0], -1.0);
  EXPECT_EQ(source.take_gap_frames(), 0u);
  EXPECT_EQ(source.counters().frames_read, 300u);
  EXPECT_EQ(source.counters().xruns, 0u);
}

TEST_F(AlsaSourceTest, S32MonoScaledToFullScale) {
  std::vector<std::int32_t> raw = {0, 1 << 30, -(1 << 30), INT32_MIN, INT32_MAX};
  for (int i = 0; i < 200; ++i) raw.push_back(i * 1000003);
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s32_le, 1, 0), local);
  const auto got = read_n(source, raw.size());
  for (std::size_t i = 0; i < got.size(); ++i) ASSERT_EQ(got[i], raw[i] / 2147483648.0) << "frame " << i;
  EXPECT_EQ(got[1], 0.5);
  EXPECT_EQ(got[3], -1.0);
}

TEST_F(AlsaSourceTest, FloatThreeChannelsLastChannelUnscaled) {
  std::vector<float> raw;
  for (int i = 0; i < 150; ++i) {
    raw.push_back(9.0f);
    raw.push_back(-9.0f);
    raw.push_back(0.001f * static_cast<float>(i) - 0.07f);
  }
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSource source(config(rd::AlsaSampleFormat::float_le, 3, 2), local);
  const auto got = read_n(source, 150);
  for (std::size_t i = 0; i < got.size(); ++i) ASSERT_EQ(got[i], static_cast<double>(raw[3 * i + 2])) << "frame " << i;
}

// source.combine on ALSA: the weighted sum of the channels, per period, with no full scale.
TEST_F(AlsaSourceTest, GainsDeliverTheWeightedSumOfTheChannels) {
  std::vector<std::int16_t> raw;
  for (int i = 0; i < 300; ++i) {
    raw.push_back(static_cast<std::int16_t>(i * 90 - 12000));  // φ̇1
    raw.push_back(static_cast<std::int16_t>(5000 - i * 31));   // φ̇2
    raw.push_back(static_cast<std::int16_t>(30000));           // unused (gain 0)
  }
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSourceConfig c = config(rd::AlsaSampleFormat::s16_le, 3, 0);
  c.gains = {0.03046, 0.08466, 0.0};
  rd::AlsaSource source(c, local);
  EXPECT_FALSE(source.info().full_scale.has_value());
  const auto got = read_n(source, 300);
  for (std::size_t i = 0; i < got.size(); ++i)
    ASSERT_NEAR(got[i], 0.03046 * raw[3 * i] / 32768.0 + 0.08466 * raw[3 * i + 1] / 32768.0, 1e-15) << "frame " << i;
  // One gain per channel or none.
  c.gains = {1.0, 2.0};
  EXPECT_THROW(rd::validate(c), std::invalid_argument);
}

// Several streams from one device (ridgewatchd streams:): every channel of a period, interleaved.
TEST_F(AlsaSourceTest, ReadFramesDeliversEveryChannelInterleaved) {
  std::vector<std::int16_t> raw;
  for (int i = 0; i < 200; ++i)
    for (int c = 0; c < 4; ++c) raw.push_back(static_cast<std::int16_t>(1000 * c - 7 * i));
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 4, 1), local);
  std::vector<double> got;
  std::vector<double> block(4 * 64);
  while (got.size() < raw.size()) {
    const auto r = source.read_frames(std::span<double>(block.data(), std::min(block.size(), raw.size() - got.size())));
    ASSERT_GT(r.count, 0u);
    ASSERT_LE(r.count, 64u);
    EXPECT_EQ(r.gap_frames_before, 0u);
    got.insert(got.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(4 * r.count));
  }
  for (std::size_t i = 0; i < raw.size(); ++i) ASSERT_EQ(got[i], raw[i] / 32768.0) << "sample " << i;
  EXPECT_EQ(source.counters().frames_read, 200u);
}

TEST_F(AlsaSourceTest, ReadsPastTheEndOfTheFileGiveSilence) {
  // The file plugin reports full reads past the end of infile without writing the buffer; the driver
  // zero-fills, so the result is silence, not stale data.
  std::vector<std::int16_t> raw(40, 16384);
  const auto local = file_pcm(write_raw(raw));
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 1, 0), local);
  const auto got = read_n(source, 100);
  for (std::size_t i = 0; i < 40; ++i) ASSERT_EQ(got[i], 0.5);
  for (std::size_t i = 40; i < 100; ++i) ASSERT_EQ(got[i], 0.0) << "frame " << i;
}

TEST_F(AlsaSourceTest, UnknownDeviceIsAClearError) {
  auto c = config(rd::AlsaSampleFormat::s16_le, 1, 0);
  c.device = "ridgewatch_no_such_pcm";
  try {
    rd::AlsaSource source(c);  // global ALSA configuration
    FAIL() << "expected InputError";
  } catch (const rd::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("alsa ridgewatch_no_such_pcm: cannot open capture PCM"), std::string::npos)
        << e.what();
  }
}

TEST_F(AlsaSourceTest, MissingInfileAndBadConfigAreClearErrors) {
  const auto local = file_pcm((dir_ / "missing.raw").string());
  try {
    rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 1, 0), local);
    FAIL() << "expected InputError";
  } catch (const rd::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("alsa rwtest: cannot open capture PCM: No such file"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(rd::AlsaLocalConfig::from_string("pcm.x { type "), rd::InputError);
  auto c = config(rd::AlsaSampleFormat::s16_le, 2, 2);
  EXPECT_THROW(rd::validate(c), std::invalid_argument);
  c.channel = 0;
  c.buffer_frames = c.period_frames;
  EXPECT_THROW(rd::AlsaSource(c, local), std::invalid_argument);
  EXPECT_EQ(rd::parse_alsa_sample_format("S32_LE"), rd::AlsaSampleFormat::s32_le);
  EXPECT_THROW(rd::parse_alsa_sample_format("S24_LE"), std::invalid_argument);
}

TEST_F(AlsaSourceTest, StoppedStreamIsRecoveredAndCountedAsXrun) {
  std::vector<std::int16_t> raw;
  for (int i = 0; i < 400; ++i) raw.push_back(static_cast<std::int16_t>(i));
  const auto local = file_pcm(write_raw(raw));
  snd_pcm_t* opened = nullptr;
  rd::AlsaSeams seams;
  seams.open = [&](snd_pcm_t** pcm, const std::string& device) {
    const int err = snd_pcm_open_lconf(pcm, device.c_str(), SND_PCM_STREAM_CAPTURE, 0, local->get());
    opened = *pcm;
    return err;
  };
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 1, 0), local, seams);
  auto first = read_n(source, 100);
  ASSERT_EQ(snd_pcm_drop(opened), 0);  // stream stopped behind the driver's back: next read -> -EBADFD
  auto second = read_n(source, 100);
  EXPECT_EQ(source.counters().xruns, 1u);
  EXPECT_EQ(source.counters().device_losses, 0u);
  EXPECT_NE(source.last_error().find("alsa rwtest: xrun"), std::string::npos) << source.last_error();
  // The plugin keeps its file position, so the data continue after recovery.
  EXPECT_EQ(second[0], 100 / 32768.0);
  // Not an overrun state: nothing measurably lost, and what is reported is consistent.
  EXPECT_EQ(source.take_gap_frames(), source.counters().xrun_frames_lost);
}

TEST_F(AlsaSourceTest, DeviceLossReopensWithBackoff) {
  std::vector<std::int16_t> raw;
  for (int i = 0; i < 400; ++i) raw.push_back(static_cast<std::int16_t>(i + 1));
  const auto local = file_pcm(write_raw(raw));
  snd_pcm_t* opened = nullptr;
  int opens = 0;
  int failures_to_inject = 0;
  std::vector<milliseconds> slept;
  rd::AlsaSeams seams;
  seams.open = [&](snd_pcm_t** pcm, const std::string& device) {
    ++opens;
    if (failures_to_inject > 0) {
      --failures_to_inject;
      return -ENODEV;
    }
    const int err = snd_pcm_open_lconf(pcm, device.c_str(), SND_PCM_STREAM_CAPTURE, 0, local->get());
    opened = *pcm;
    return err;
  };
  seams.sleep = [&](milliseconds delay) { slept.push_back(delay); };
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 1, 0), local, seams);
  read_n(source, 50);
  // Device gone: hw_free makes readi fail with -EIO and prepare fail too, as after an unplug.
  ASSERT_EQ(snd_pcm_hw_free(opened), 0);
  failures_to_inject = 4;
  const auto after = read_n(source, 10);
  EXPECT_EQ(after[0], 1 / 32768.0) << "reopened PCM starts its file again";
  const auto c = source.counters();
  EXPECT_EQ(c.device_losses, 1u);
  EXPECT_EQ(c.reopen_attempts, 5u);
  EXPECT_EQ(c.reopen_failures, 4u);
  EXPECT_EQ(opens, 6);
  // min 10 ms doubling, capped at 40 ms
  EXPECT_EQ(slept, (std::vector<milliseconds>{milliseconds(10), milliseconds(20), milliseconds(40), milliseconds(40)}));
  EXPECT_NE(source.last_error().find("alsa rwtest: cannot open capture PCM: No such device"), std::string::npos)
      << source.last_error();
  // The outage gap (time based, tiny with the fake sleep) is reported once and counted.
  const auto gap = source.take_gap_frames();
  EXPECT_EQ(gap, c.device_loss_frames_lost);
  EXPECT_EQ(source.take_gap_frames(), 0u);
  // A later loss starts the backoff at the minimum again.
  ASSERT_EQ(snd_pcm_hw_free(opened), 0);
  failures_to_inject = 1;
  slept.clear();
  read_n(source, 10);
  EXPECT_EQ(slept, (std::vector<milliseconds>{milliseconds(10)}));
}

TEST_F(AlsaSourceTest, StopEndsAReconnectLoop) {
  std::vector<std::int16_t> raw(100, 1);
  const auto local = file_pcm(write_raw(raw));
  snd_pcm_t* opened = nullptr;
  bool fail = false;
  rd::AlsaSource* self = nullptr;
  int sleeps = 0;
  rd::AlsaSeams seams;
  seams.open = [&](snd_pcm_t** pcm, const std::string& device) {
    if (fail) return -ENODEV;
    const int err = snd_pcm_open_lconf(pcm, device.c_str(), SND_PCM_STREAM_CAPTURE, 0, local->get());
    opened = *pcm;
    return err;
  };
  seams.sleep = [&](milliseconds) {
    if (++sleeps == 3) self->request_stop();
  };
  rd::AlsaSource source(config(rd::AlsaSampleFormat::s16_le, 1, 0), local, seams);
  self = &source;
  read_n(source, 10);
  ASSERT_EQ(snd_pcm_hw_free(opened), 0);
  fail = true;
  std::vector<double> out(10);
  EXPECT_EQ(source.read(out), 0u);  // device never comes back; stop -> end of stream, no crash
  EXPECT_EQ(source.counters().reopen_failures, 3u);
}

TEST(ReconnectBackoff, DoublesUpToTheCapAndResets) {
  rd::ReconnectBackoff backoff(milliseconds(100), milliseconds(1000));
  std::vector<long> delays;
  for (int i = 0; i < 6; ++i) delays.push_back(static_cast<long>(backoff.next_delay().count()));
  EXPECT_EQ(delays, (std::vector<long>{100, 200, 400, 800, 1000, 1000}));
  EXPECT_EQ(backoff.failures(), 6u);
  backoff.reset();
  EXPECT_EQ(backoff.next_delay(), milliseconds(100));
  EXPECT_THROW(rd::ReconnectBackoff(milliseconds(0), milliseconds(10)), std::invalid_argument);
  EXPECT_THROW(rd::ReconnectBackoff(milliseconds(20), milliseconds(10)), std::invalid_argument);
}

}  // namespace
