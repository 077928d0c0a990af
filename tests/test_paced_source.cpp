// PacedSource: pacing at N x real time and as fast as possible (loose wall-clock bounds: the machine is
// shared, so only gross errors such as "no sleeping at all" or "sleeping per sample" are caught),
// seamless looping through the factory, and the error paths.
#include "drivers/paced_source.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "drivers/sample_source.hpp"

namespace rd = ridgewatch::drivers;

namespace {

/// In-memory source: sample i has value first_value + i. Reads are capped at max_read to exercise
/// the decorator's refilling.
class RampSource : public rd::SampleSource {
 public:
  RampSource(double rate_hz, std::size_t frames, std::size_t max_read = 1000) : frames_(frames), max_read_(max_read) {
    info_.name = "ramp";
    info_.sample_rate_hz = rate_hz;
    info_.frames = frames;
  }
  const rd::SourceInfo& info() const override { return info_; }
  std::size_t read(std::span<double> out) override {
    std::size_t n = 0;
    while (n < out.size() && n < max_read_ && position_ < frames_) out[n++] = static_cast<double>(position_++);
    return n;
  }

 private:
  rd::SourceInfo info_;
  std::size_t frames_;
  std::size_t max_read_;
  std::size_t position_ = 0;
};

double seconds_to_read_all(rd::PacedSource& source, std::size_t block) {
  std::vector<double> buf(block);
  const auto t0 = std::chrono::steady_clock::now();
  while (source.read(buf) > 0) {
  }
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

TEST(PacedSource, FourTimesRealTime) {
  // 0.4 s of audio at 8 kHz, replayed at 4x: expected 0.1 s. Bounds 0.5x..5x expected (shared machine):
  // the lower bound catches a decorator that does not sleep or ignores the rate; the upper bound catches
  // gross over-sleeping. A wrong speed factor within the bounds is caught by SpeedFactorScalesTheTime.
  rd::PacedSource source([] { return std::make_unique<RampSource>(8000.0, 3200); }, {.speed = 4.0, .loop = false});
  const double elapsed_s = seconds_to_read_all(source, 256);
  const double expected_s = 0.4 / 4.0;
  EXPECT_GE(elapsed_s, 0.5 * expected_s);
  EXPECT_LE(elapsed_s, 5.0 * expected_s);
  EXPECT_EQ(source.samples_delivered(), 3200u);
}

TEST(PacedSource, SpeedFactorScalesTheTime) {
  // Same 0.2 s of audio at 2x and 8x: expected 0.1 s and 0.025 s. The 2x replay must take clearly
  // longer than the 8x one (ratio 4 expected; require > 1.5 to stay robust to scheduling noise of a
  // few ms on the shared machine).
  rd::PacedSource slow([] { return std::make_unique<RampSource>(8000.0, 1600); }, {.speed = 2.0});
  rd::PacedSource fast([] { return std::make_unique<RampSource>(8000.0, 1600); }, {.speed = 8.0});
  const double slow_s = seconds_to_read_all(slow, 160);
  const double fast_s = seconds_to_read_all(fast, 160);
  EXPECT_GE(slow_s, 0.5 * 0.1);
  EXPECT_LE(slow_s, 5.0 * 0.1);
  EXPECT_GT(slow_s, 1.5 * fast_s);
}

TEST(PacedSource, AsFastAsPossibleDoesNotSleep) {
  // 100 s of audio at 1 kHz with speed 0: reading 10^5 samples from memory takes well under a
  // millisecond; 1 s allows for a heavily loaded machine and still fails any real pacing (100 s).
  rd::PacedSource source([] { return std::make_unique<RampSource>(1000.0, 100000); }, {.speed = 0.0});
  EXPECT_LT(seconds_to_read_all(source, 4096), 1.0);
  EXPECT_EQ(source.samples_delivered(), 100000u);
  ASSERT_TRUE(source.info().frames.has_value());
  EXPECT_EQ(*source.info().frames, 100000u);
}

TEST(PacedSource, LoopingIsSeamlessInSampleIndices) {
  int opened = 0;
  rd::PacedSource source(
      [&] {
        ++opened;
        return std::make_unique<RampSource>(1000.0, 100, 37);
      },
      {.speed = 0.0, .loop = true});
  EXPECT_FALSE(source.info().frames.has_value()) << "a looping stream is endless";
  std::vector<double> block(64);  // 64 does not divide 100: blocks straddle the loop boundary
  std::vector<double> all;
  for (int i = 0; i < 6; ++i) {
    ASSERT_EQ(source.read(block), block.size()) << "a looping read must fill the whole block";
    all.insert(all.end(), block.begin(), block.end());
  }
  ASSERT_EQ(all.size(), 384u);
  for (std::size_t k = 0; k < all.size(); ++k) ASSERT_EQ(all[k], static_cast<double>(k % 100)) << "index " << k;
  EXPECT_EQ(source.samples_delivered(), 384u);
  EXPECT_EQ(source.loops_completed(), 3u);
  EXPECT_EQ(opened, 4);
}

// read_float goes through the inner source's read_float (here the default double-buffer path of
// SampleSource): the same seamless stream, straddling loop boundaries and short inner reads.
TEST(PacedSource, ReadFloatLoopsSeamlesslyLikeRead) {
  rd::PacedSource source([] { return std::make_unique<RampSource>(1000.0, 100, 37); }, {.speed = 0.0, .loop = true});
  std::vector<float> block(64);
  std::vector<float> all;
  for (int i = 0; i < 6; ++i) {
    ASSERT_EQ(source.read_float(block), block.size());
    all.insert(all.end(), block.begin(), block.end());
  }
  for (std::size_t k = 0; k < all.size(); ++k) ASSERT_EQ(all[k], static_cast<float>(k % 100)) << "index " << k;
  EXPECT_EQ(source.samples_delivered(), 384u);
  EXPECT_EQ(source.loops_completed(), 3u);
}

TEST(PacedSource, LoopingAnEmptySourceEnds) {
  rd::PacedSource source([] { return std::make_unique<RampSource>(1000.0, 0); }, {.speed = 0.0, .loop = true});
  std::vector<double> block(16);
  EXPECT_EQ(source.read(block), 0u);
}

TEST(PacedSource, LoopRejectsASourceThatChanged) {
  double rate_hz = 1000.0;
  rd::PacedSource source([&] { return std::make_unique<RampSource>(rate_hz, 10); }, {.speed = 0.0, .loop = true});
  rate_hz = 2000.0;
  std::vector<double> block(16);
  // The first pass's 10 samples come first; the error when reopening follows on the next call.
  ASSERT_EQ(source.read(block), 10u);
  try {
    source.read(block);
    FAIL() << "expected InputError";
  } catch (const rd::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("ramp: changed while looping"), std::string::npos) << e.what();
  }
}

TEST(PacedSource, RejectsBadSpeedAndFactory) {
  auto factory = [] { return std::make_unique<RampSource>(1000.0, 10); };
  EXPECT_THROW(rd::PacedSource(factory, {.speed = -1.0}), std::invalid_argument);
  EXPECT_THROW(rd::PacedSource(factory, {.speed = std::numeric_limits<double>::infinity()}), std::invalid_argument);
  EXPECT_THROW(rd::PacedSource(factory, {.speed = std::numeric_limits<double>::quiet_NaN()}), std::invalid_argument);
  EXPECT_THROW(rd::PacedSource(rd::PacedSource::Factory{}, {}), std::invalid_argument);
  EXPECT_THROW(rd::PacedSource([] { return std::unique_ptr<rd::SampleSource>(); }, {}), std::invalid_argument);
}

TEST(PacedSource, ReplayFileErrorsPropagate) {
  try {
    rd::open_paced_replay("/nonexistent/x.wav", {}, {});
    FAIL() << "expected InputError";
  } catch (const rd::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/x.wav"), std::string::npos) << e.what();
  }
}

}  // namespace

// An inner source that fails part-way through a read (a NaN sample in a replayed file: the reader
// delivers the good samples before it and throws on its next call). The decorator refills a large
// block with several inner reads; the good samples read before the failure must reach the caller,
// and the error must come on the following read(), not be swallowed or lose those samples.
TEST(PacedSource, ErrorAfterSomeSamplesDeliversThemFirst) {
  class FailingSource : public RampSource {
   public:
    FailingSource() : RampSource(8000.0, 1000000, 100) {}
    std::size_t read(std::span<double> out) override {
      if (calls_++ == 3) throw std::runtime_error("ramp: sample 300 is NaN");
      return RampSource::read(out);
    }

   private:
    int calls_ = 0;
  };
  rd::PacedSource source([] { return std::make_unique<FailingSource>(); }, {.speed = 0.0, .loop = false});
  std::vector<double> buf(1000);
  ASSERT_EQ(source.read(buf), 300u);  // three inner reads of 100, then the failure
  for (std::size_t i = 0; i < 300; ++i) ASSERT_EQ(buf[i], static_cast<double>(i));
  EXPECT_THROW(
      {
        try {
          source.read(buf);
        } catch (const std::runtime_error& e) {
          EXPECT_STREQ(e.what(), "ramp: sample 300 is NaN");
          throw;
        }
      },
      std::runtime_error);
}

// Looping: the file disappears between passes (the factory throws on reopening). The samples of the
// last pass read in the same call must still be delivered, and the error must follow on the next call.
TEST(PacedSource, ReopenFailureWhileLoopingDeliversTheSamplesReadFirst) {
  int opened = 0;
  rd::PacedSource source(
      [&opened]() -> std::unique_ptr<rd::SampleSource> {
        if (opened++ > 0) throw std::runtime_error("ramp: file does not exist");
        return std::make_unique<RampSource>(1000.0, 250);
      },
      {.speed = 0.0, .loop = true});
  std::vector<double> buf(1000);
  ASSERT_EQ(source.read(buf), 250u);  // the whole first pass, then the reopen fails
  EXPECT_EQ(buf[249], 249.0);
  EXPECT_THROW(source.read(buf), std::runtime_error);
}
