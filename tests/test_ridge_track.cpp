// The impact analyzer's ridge step (core/pipeline/ridge_track.hpp) on hand-made power grids: where
// the ridge starts, its frequency, and when it is lost or ends (the free response stopped).
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <complex>
#include <cstdint>
#include <random>
#include <vector>

#include "core/dsp/kernels/isa.hpp"
#include "core/pipeline/ridge_track.hpp"

namespace {

using namespace ridgewatch::pipeline;

constexpr std::size_t kRows = 9, kCols = 80;
constexpr double kEta0 = 7.0;

struct Grid {
  std::vector<double> rows_hz, gain;
  std::vector<std::uint8_t> near;
  std::vector<std::complex<float>> w;  // rows x cols
  std::vector<double> power, median, scratch;
  Grid() : w(kRows * kCols), power(kRows * kCols), median(kRows), scratch(2 * kCols) {
    for (std::size_t r = 0; r < kRows; ++r) rows_hz.push_back(860.0 * std::exp((static_cast<double>(r) - 4.0) / (3.0 * kEta0)));
    gain.assign(kRows, 1.0);
    for (std::size_t r = 0; r < kRows; ++r)
      for (std::size_t q = 0; q < kRows; ++q)
        near.push_back(std::abs(std::log(rows_hz[r] / rows_hz[q])) <= 1.0 / kEta0 ? 1 : 0);
  }
  // |W|^2 = p at (r, c) (a real W).
  void set(std::size_t r, std::size_t c, double p) { w[r * kCols + c] = std::complex<float>(static_cast<float>(std::sqrt(p)), 0.0f); }
  RidgeTrack track(std::size_t onset_col, std::size_t last_col, RidgeStart* start_out = nullptr) {
    const RidgeStart s = find_ridge(w, kRows, kCols, onset_col, last_col, power, median, scratch);
    if (start_out) *start_out = s;
    RidgeFollowInputs in;
    in.rows_hz = rows_hz;
    in.row_gain = gain;
    in.near = near;
    in.noise_var = 1e-6;  // 20 dB floor: 1e-4 above the median
    in.width_cols = 2;
    in.last_col = last_col;
    return follow_ridge(RidgeGrid{power, median, kRows, kCols}, s, in);
  }
};

// A decaying mode on row `row` (neighbours at `side` of its power), starting at column c0.
void decay(Grid& g, std::size_t row, std::size_t c0, double side_lo, double side_hi, double per_col = 0.9) {
  for (std::size_t c = c0; c < kCols; ++c) {
    const double p = std::pow(per_col, static_cast<double>(c - c0));
    g.set(row, c, p);
    g.set(row - 1, c, side_lo * p);
    g.set(row + 1, c, side_hi * p);
  }
}

TEST(RidgeTrack, DecayOnAMiddleRowIsFollowedToTheFloor) {
  Grid g;
  decay(g, 4, 10, 0.5, 0.5);
  RidgeStart s;
  const RidgeTrack t = g.track(10, 70, &s);
  EXPECT_EQ(s.row, 4u);
  EXPECT_EQ(s.col, 10u);
  EXPECT_FALSE(t.lost);
  EXPECT_FALSE(t.ended);
  EXPECT_EQ(t.end_col, kCols);
  // Equal energy on both sides: the parabola's vertex is the row itself.
  EXPECT_DOUBLE_EQ(t.f_hz, g.rows_hz[4]);
}

TEST(RidgeTrack, UnequalNeighboursMoveTheFrequencyTowardsTheStrongerOne) {
  Grid g;
  decay(g, 4, 10, 0.3, 0.7);
  const RidgeTrack t = g.track(10, 70);
  EXPECT_GT(t.f_hz, g.rows_hz[4]);
  EXPECT_LT(t.f_hz, std::sqrt(g.rows_hz[4] * g.rows_hz[5]));  // at most half a row step
}

TEST(RidgeTrack, MaximumOnABandEdgeRowIsLost) {
  Grid g;
  for (std::size_t c = 10; c < kCols; ++c) {
    const double p = std::pow(0.9, static_cast<double>(c - 10));
    g.set(kRows - 1, c, p);
    g.set(kRows - 2, c, 0.5 * p);
  }
  const RidgeTrack t = g.track(10, 70);
  EXPECT_EQ(t.row, kRows - 1);
  EXPECT_TRUE(t.lost);
  EXPECT_EQ(t.f_hz, g.rows_hz[kRows - 1]);
}

TEST(RidgeTrack, AnAcceleratingDecayThatDoesNotRecoverEndsTheRidge) {
  Grid g;
  decay(g, 4, 10, 0.5, 0.5, 0.97);
  // From column 40 on the power falls by a factor 10 per column (a stop), well above the floor.
  for (std::size_t c = 40; c < kCols; ++c) {
    const double p = std::pow(0.97, 30.0) * std::pow(0.1, static_cast<double>(c - 39));
    g.set(4, c, p);
    g.set(3, c, 0.5 * p);
    g.set(5, c, 0.5 * p);
  }
  const RidgeTrack t = g.track(10, 70);
  EXPECT_FALSE(t.lost);
  EXPECT_TRUE(t.ended);
  EXPECT_EQ(t.end_col, 40u);
}

}  // namespace

// find_ridge's two forms (the baseline and, where the CPU has AVX2, the AVX2 one: dsp/kernels/isa.hpp)
// give the same start, powers and medians bit for bit: random complex grids of the analyzer's size
// (14 rows) with a decaying ridge, noise, exact ties and rows of one repeated value (the median's
// shortcuts and its partition fallback).
TEST(RidgeTrack, FindRidgeFormsAgreeBitForBit) {
  constexpr std::size_t rows = 14;
  std::mt19937_64 rng(31);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  for (std::size_t cols : {16u, 63u, 79u, 80u}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<std::complex<float>> w(rows * cols);
      for (auto& v : w) v = {noise(rng), noise(rng)};
      const std::size_t r0 = 1 + static_cast<std::size_t>(trial) % (rows - 2);
      for (std::size_t c = 5; c < cols; ++c)
        w[r0 * cols + c] += std::complex<float>(static_cast<float>(30.0 * std::exp(-0.05 * static_cast<double>(c))), 0.0f);
      if (trial % 4 == 1)
        for (std::size_t c = 0; c < cols; ++c) w[(rows - 1) * cols + c] = {0.5f, 0.0f};  // one value repeated
      if (trial % 4 == 2) w[cols / 2] = w[cols / 4];  // a tie at the pivot's rank (row 0)
      std::vector<double> p[2], med[2], scratch(2 * cols);
      RidgeStart st[2];
      for (int form = 0; form < 2; ++form) {
        p[form].assign(rows * cols, -1.0);
        med[form].assign(rows, -1.0);
        ridgewatch::dsp::kernels::limit_kernels_to_baseline(form == 0);
        st[form] = find_ridge(w, rows, cols, 3, cols - 2, p[form], med[form], scratch);
      }
      ridgewatch::dsp::kernels::limit_kernels_to_baseline(false);
      ASSERT_EQ(st[0].row, st[1].row) << "cols " << cols << " trial " << trial;
      ASSERT_EQ(st[0].col, st[1].col) << "cols " << cols << " trial " << trial;
      ASSERT_EQ(std::bit_cast<std::uint64_t>(st[0].power), std::bit_cast<std::uint64_t>(st[1].power));
      for (std::size_t i = 0; i < rows * cols; ++i)
        ASSERT_EQ(std::bit_cast<std::uint64_t>(p[0][i]), std::bit_cast<std::uint64_t>(p[1][i])) << "i " << i;
      for (std::size_t r = 0; r < rows; ++r)
        ASSERT_EQ(std::bit_cast<std::uint64_t>(med[0][r]), std::bit_cast<std::uint64_t>(med[1][r])) << "row " << r;
      EXPECT_EQ(st[1].row, r0) << "the ridge row";  // the test grid's ridge dominates
    }
  }
}
