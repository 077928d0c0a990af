// Exactness of the dsp kernels (core/dsp/kernels/): each fast form against its plain scalar
// reference (<name>_generic), bit for bit, and each reference against the kernel's definition written
// out independently here. Bit-identical is the right bound: the fast forms do the same operations in
// the same order per output (half_rate_121) or compute counts, maxima and minima, which are exact
// (pivot_counts).
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <complex>
#include <numbers>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "core/dsp/kernels/goertzel.hpp"
#include "core/dsp/kernels/half_rate_121.hpp"
#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/pivot_counts.hpp"

using namespace ridgewatch::dsp::kernels;

namespace {

std::uint64_t bits(double v) { return std::bit_cast<std::uint64_t>(v); }
std::uint32_t bits(float v) { return std::bit_cast<std::uint32_t>(v); }

// Samples of varied magnitude and sign: normal values scaled by powers of two from 2^-30 to 2^30 (so
// the sums round differently), exact zeros of both signs and a few values repeated.
template <typename T>
std::vector<T> varied_samples(std::size_t n, std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_int_distribution<int> exponent(-30, 30), kind(0, 15);
  std::vector<T> x(n);
  for (std::size_t i = 0; i < n; ++i) {
    const int k = kind(rng);
    if (k == 0) x[i] = T{0};
    else if (k == 1) x[i] = -T{0};
    else if (k == 2 && i > 0) x[i] = -x[i - 1];
    else x[i] = static_cast<T>(std::ldexp(normal(rng), exponent(rng)));
  }
  return x;
}

// Runs the fast and the reference kernel on x for outputs [m0, m1), with and without the float copy,
// and checks every output and the returned maximum bit for bit; then the reference against the
// definition y[m] = ((x[2m-1] + x[2m+1]) + 2 x[2m]) / 4 in double (the same value as the kernel's
// 0.25 (a + c) + 0.5 b: scaling by a power of two is exact) and max |x| over [2 m0, 2 m1).
template <typename In>
void check_half_rate(const std::vector<In>& x, std::size_t m0, std::size_t m1) {
  const std::size_t m_out = m1 + 1;
  std::vector<double> y_fast(m_out, -1.0), y_ref(m_out, -1.0);
  std::vector<float> yf_fast(m_out, -1.0f), yf_ref(m_out, -1.0f);
  const double p_fast = half_rate_121(x.data(), y_fast.data(), yf_fast.data(), m0, m1);
  const double p_ref = half_rate_121_generic(x.data(), y_ref.data(), yf_ref.data(), m0, m1);
  ASSERT_EQ(bits(p_fast), bits(p_ref)) << "n=" << x.size() << " m0=" << m0 << " m1=" << m1;
  for (std::size_t m = 0; m < m_out; ++m) {
    ASSERT_EQ(bits(y_fast[m]), bits(y_ref[m])) << "n=" << x.size() << " m0=" << m0 << " m=" << m;
    ASSERT_EQ(bits(yf_fast[m]), bits(yf_ref[m])) << "n=" << x.size() << " m0=" << m0 << " m=" << m;
  }
  std::vector<double> y_only(m_out, -1.0);  // without the float copy
  ASSERT_EQ(bits(half_rate_121(x.data(), y_only.data(), nullptr, m0, m1)), bits(p_ref));
  ASSERT_EQ(y_only, y_ref);

  double peak = 0.0;
  for (std::size_t k = 2 * m0; k < 2 * m1; ++k) peak = std::max(peak, std::abs(static_cast<double>(x[k])));
  ASSERT_EQ(p_ref, peak);
  for (std::size_t m = 0; m < m_out; ++m) {
    if (m < m0 || m >= m1) {  // outside the range: untouched
      ASSERT_EQ(y_ref[m], -1.0);
      ASSERT_EQ(yf_ref[m], -1.0f);
      continue;
    }
    const double a = static_cast<double>(x[2 * m - 1]), b = static_cast<double>(x[2 * m]),
                 c = static_cast<double>(x[2 * m + 1]);
    ASSERT_EQ(bits(y_ref[m]), bits(((a + c) + 2.0 * b) / 4.0)) << "m=" << m;
    ASSERT_EQ(bits(yf_ref[m]), bits(static_cast<float>(y_ref[m]))) << "m=" << m;
  }
}

// Interior ranges of every length 0..40 (the vector loop's remainders 0-3 and the first steps) from
// offsets 1..5 (element-aligned but not vector-aligned loads), and the impact analyzer's window
// (1894 samples: outputs [1, 947)), for float and double input.
TEST(KernelHalfRate121, FastEqualsGenericBitForBit) {
  std::mt19937_64 rng(21);
  for (int trial = 0; trial < 4; ++trial) {
    const auto xf = varied_samples<float>(1894, rng);
    const auto xd = varied_samples<double>(1894, rng);
    for (std::size_t m0 = 1; m0 <= 5; ++m0)
      for (std::size_t len = 0; len <= 40; ++len) {
        check_half_rate(xf, m0, m0 + len);
        check_half_rate(xd, m0, m0 + len);
      }
    check_half_rate(xf, 1, 947);
    check_half_rate(xd, 1, 947);
  }
}

// The maximum is found in every lane and in the remainder: a single large sample (either sign) at
// each position of a 64-sample window; a NaN sample does not count as the largest.
TEST(KernelHalfRate121, PeakAtEveryPositionAndNanIgnored) {
  std::mt19937_64 rng(22);
  const auto base = varied_samples<float>(64, rng);
  for (std::size_t m1 : {29u, 30u, 31u}) {  // remainders 0, 1, 2 after the four-output steps
    for (std::size_t i = 2; i < 2 * m1; ++i) {
      std::vector<float> x = base;
      for (float& v : x) v = std::clamp(v, -1.0f, 1.0f);
      x[i] = i % 2 == 0 ? 1e3f : -1e3f;
      const std::vector<double> xd(x.begin(), x.end());
      std::vector<double> y(m1 + 1);
      EXPECT_EQ(half_rate_121(x.data(), y.data(), nullptr, 1, m1), 1e3) << "i=" << i;
      EXPECT_EQ(half_rate_121(xd.data(), y.data(), nullptr, 1, m1), 1e3) << "i=" << i;
      EXPECT_EQ(half_rate_121_generic(x.data(), y.data(), nullptr, 1, m1), 1e3) << "i=" << i;
      // The large sample replaced by NaN: the maximum is that of the others.
      x[i] = std::numeric_limits<float>::quiet_NaN();
      std::vector<float> rest(x.begin() + 2, x.begin() + static_cast<std::ptrdiff_t>(2 * m1));
      rest.erase(rest.begin() + static_cast<std::ptrdiff_t>(i - 2));
      float expected = 0.0f;
      for (float v : rest) expected = std::max(expected, std::abs(v));
      const std::vector<double> xdn(x.begin(), x.end());
      EXPECT_EQ(half_rate_121(x.data(), y.data(), nullptr, 1, m1), static_cast<double>(expected)) << "i=" << i;
      EXPECT_EQ(half_rate_121(xdn.data(), y.data(), nullptr, 1, m1), static_cast<double>(expected)) << "i=" << i;
      EXPECT_EQ(half_rate_121_generic(x.data(), y.data(), nullptr, 1, m1), static_cast<double>(expected)) << "i=" << i;
    }
  }
}

// Counts and neighbours by their definition, written independently of the kernel.
PivotCounts counts_by_definition(const std::vector<double>& v, double pivot) {
  PivotCounts c;
  c.below = static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [&](double x) { return x < pivot; }));
  c.at_or_below = static_cast<std::size_t>(std::count_if(v.begin(), v.end(), [&](double x) { return x <= pivot; }));
  c.below_max = 0.0;
  c.above_min = std::numeric_limits<double>::infinity();
  for (double x : v) {
    if (x < pivot) c.below_max = std::max(c.below_max, x);
    if (x > pivot) c.above_min = std::min(c.above_min, x);
  }
  return c;
}

// Every length 0..70 (the pair loop's remainders and the single tail value) and 200; rows of random
// powers, of small integers (ties: several values equal to the pivot and to its neighbours) and of
// zeros; pivots taken from the row (as select_kth_nonnegative does), below, between and above all of
// its values.
TEST(KernelPivotCounts, FastEqualsGenericBitForBit) {
  std::mt19937_64 rng(23);
  std::exponential_distribution<double> expo(1.0);
  std::uniform_int_distribution<int> small(0, 3);
  std::vector<std::size_t> lengths;
  for (std::size_t n = 0; n <= 70; ++n) lengths.push_back(n);
  lengths.push_back(200);
  std::size_t checked = 0;
  for (std::size_t n : lengths) {
    for (int family = 0; family < 3; ++family) {
      std::vector<double> v(n);
      for (double& x : v) x = family == 0 ? expo(rng) : family == 1 ? static_cast<double>(small(rng)) : 0.0;
      std::vector<double> pivots = {0.0, 0.5, 1.5, 1e300, std::numeric_limits<double>::infinity()};
      for (std::size_t i = 0; i < n; i += 1 + n / 8) pivots.push_back(v[i]);
      for (double pivot : pivots) {
        const PivotCounts fast = pivot_counts(v.data(), n, pivot);
        const PivotCounts ref = pivot_counts_generic(v.data(), n, pivot);
        const PivotCounts def = counts_by_definition(v, pivot);
        ASSERT_EQ(fast.below, ref.below) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(fast.at_or_below, ref.at_or_below) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(bits(fast.below_max), bits(ref.below_max)) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(bits(fast.above_min), bits(ref.above_min)) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(ref.below, def.below) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(ref.at_or_below, def.at_or_below) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(bits(ref.below_max), bits(def.below_max)) << "n=" << n << " pivot=" << pivot;
        ASSERT_EQ(bits(ref.above_min), bits(def.above_min)) << "n=" << n << " pivot=" << pivot;
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000u);
}

// The neighbours in each lane and in the tail: a row of 2.0 with one 1.0 (the largest below a pivot
// of 2) and one 3.0 (the smallest above it) moved through every position.
TEST(KernelPivotCounts, NeighboursFoundAtEveryPosition) {
  for (std::size_t n : {9u, 10u, 11u, 12u}) {
    for (std::size_t i = 0; i < n; ++i) {
      std::vector<double> v(n, 2.0);
      v[i] = 1.0;
      v[n - 1 - i == i ? (i + 1) % n : n - 1 - i] = 3.0;
      const PivotCounts c = pivot_counts(v.data(), n, 2.0);
      EXPECT_EQ(c.below, 1u) << "n=" << n << " i=" << i;
      EXPECT_EQ(c.at_or_below, n - 1) << "n=" << n << " i=" << i;
      EXPECT_EQ(c.below_max, 1.0) << "n=" << n << " i=" << i;
      EXPECT_EQ(c.above_min, 3.0) << "n=" << n << " i=" << i;
    }
  }
}

}  // namespace

// The Goertzel recursions: the fast form (baseline and, where the CPU has AVX2, the AVX2 form) against
// the reference bit for bit, for 1 and 2 bins, with and without a tail row, over row counts around the
// two-step loop's remainder and the ML fit's segments (1766 samples: 220 full rows and a tail); then
// the reference against the recursion's definition: with c = 2 cos t, s[M-1] - e^{-i t} s[M-2] =
// sum_m x[P m + j] e^{i t (M-1-m)} for each phase j (Goertzel), within 1e-9 of sum |x| (the
// recursion's round-off grows like M^2 eps / sin t: ~1e-11 at M = 221, sin t >= 0.3 here).
TEST(KernelGoertzel, FastEqualsGenericBitForBit) {
  constexpr std::size_t P = kGoertzelPhases;
  std::mt19937_64 rng(23);
  const double ts[2] = {0.8, 2.1};
  const double coef[2] = {2.0 * std::cos(ts[0]), 2.0 * std::cos(ts[1])};
  for (std::size_t m_full : {0u, 1u, 2u, 3u, 4u, 7u, 220u}) {
    for (const bool with_tail : {false, true}) {
      if (m_full == 0 && !with_tail) continue;
      const auto x = varied_samples<double>(P * m_full + P, rng);
      const double* tail = with_tail ? x.data() + P * m_full : nullptr;
      for (std::size_t bins : {1u, 2u}) {
        std::vector<double> ref(2 * P * bins, -1.0);
        goertzel_recursions_generic(x.data(), m_full, tail, coef, bins, ref.data());
        for (const bool baseline : {true, false}) {
          limit_kernels_to_baseline(baseline);
          std::vector<double> fast(2 * P * bins, -1.0);
          goertzel_recursions(x.data(), m_full, tail, coef, bins, fast.data());
          for (std::size_t i = 0; i < fast.size(); ++i)
            ASSERT_EQ(bits(fast[i]), bits(ref[i])) << "m_full=" << m_full << " tail=" << with_tail
                                                   << " bins=" << bins << " baseline=" << baseline << " i=" << i;
        }
        limit_kernels_to_baseline(false);
        const std::size_t rows = m_full + (with_tail ? 1 : 0);
        for (std::size_t b = 0; b < bins; ++b) {
          for (std::size_t j = 0; j < P; ++j) {
            std::complex<double> direct(0.0, 0.0);
            double scale = 0.0;
            for (std::size_t m = 0; m < rows; ++m) {
              const double v = x[P * m + j];
              direct += v * std::polar(1.0, ts[b] * static_cast<double>(rows - 1 - m));
              scale += std::abs(v);
            }
            const std::complex<double> read =
                ref[2 * P * b + j] - std::polar(1.0, -ts[b]) * ref[2 * P * b + P + j];
            EXPECT_LE(std::abs(read - direct), 1e-9 * scale + 1e-300)
                << "m_full=" << m_full << " tail=" << with_tail << " bin " << b << " phase " << j;
          }
        }
      }
    }
  }
}
