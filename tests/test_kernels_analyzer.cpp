// Exactness of the analyzer's and the ML fit's kernels (core/dsp/kernels/) against their plain scalar
// references: every result bit for bit (each kernel performs its reference's operations in the same
// order per lane, so no tolerance is needed; a reordered sum or a fused operation shows as a
// difference here).
#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <cstring>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "core/dsp/kernels/lag_correlation.hpp"
#include "core/dsp/kernels/mode_bin.hpp"
#include "core/dsp/kernels/phase_advance.hpp"
#include "core/dsp/kernels/subtract_and_max.hpp"

namespace {

using namespace ridgewatch::dsp;
using cd = std::complex<double>;

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_bits(cd a, cd b) { return same_bits(a.real(), b.real()) && same_bits(a.imag(), b.imag()); }

TEST(KernelsAnalyzer, SubtractAndMaxMatchesGeneric) {
  std::mt19937 rng(11);
  std::exponential_distribution<double> power(1.0);
  int cases = 0;
  for (std::size_t cols = 1; cols <= 70; ++cols) {
    for (std::size_t c_begin = 0; c_begin < cols; c_begin += 3) {
      for (std::size_t c_end = c_begin + 1; c_end <= cols; c_end += 5) {
        std::vector<double> a(cols);
        for (double& v : a) v = power(rng);
        std::vector<double> b = a;
        const double med = a[cols / 2];
        const double ma = kernels::subtract_and_max(a.data(), cols, med, c_begin, c_end);
        const double mb = kernels::subtract_and_max_generic(b.data(), cols, med, c_begin, c_end);
        ASSERT_TRUE(same_bits(ma, mb)) << cols << " " << c_begin << " " << c_end << ": " << ma << " vs " << mb;
        for (std::size_t c = 0; c < cols; ++c) ASSERT_TRUE(same_bits(a[c], b[c])) << "column " << c;
        ++cases;
      }
    }
  }
  EXPECT_GT(cases, 500);
}

TEST(KernelsAnalyzer, LagCorrelationSumMatchesGeneric) {
  std::mt19937 rng(12);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (std::size_t count = 1; count <= 90; ++count) {
    std::vector<double> z(count), rho(count);
    for (double& v : z) v = normal(rng) * 1e3;
    for (std::size_t k = 0; k < count; ++k) rho[k] = std::exp(-0.01 * static_cast<double>(k * k)) * (k ? 2.0 : 1.0);
    for (std::size_t reach = 0; reach < count; ++reach) {
      const double a = kernels::lag_correlation_sum(z.data(), count, rho.data(), reach);
      const double b = kernels::lag_correlation_sum_generic(z.data(), count, rho.data(), reach);
      ASSERT_TRUE(same_bits(a, b)) << count << " " << reach << ": " << a << " vs " << b;
    }
  }
  // The reference is a plain lag sum (its order aside): a small case by hand.
  const double z[3] = {1.0, 2.0, 3.0}, rho[3] = {1.0, 0.5, 0.25};
  EXPECT_EQ(kernels::lag_correlation_sum_generic(z, 3, rho, 2), 14.0 + 0.5 * 8.0 + 0.25 * 3.0);
}

TEST(KernelsAnalyzer, PhaseAdvancesMatchGeneric) {
  std::mt19937 rng(13);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double advance = 2.0 * std::numbers::pi * 860.0 / 1706.0;  // a decimated row's carrier step
  const cd derotate = std::polar(1.0, -advance);
  for (int trial = 0; trial < 200; ++trial) {
    const std::size_t count = 2 + static_cast<std::size_t>(uni(rng) * 120);
    // A row near the carrier (advances within the series' range), with a few columns far off it (noise)
    // and, in some trials, a NaN.
    std::vector<cd> w(count);
    double phase = uni(rng) * 6.0;
    for (std::size_t i = 0; i < count; ++i) {
      phase += advance + 0.02 * normal(rng);
      w[i] = std::polar(std::exp(-0.01 * static_cast<double>(i)), phase);
      if (uni(rng) < 0.05) w[i] = cd(normal(rng), normal(rng));
    }
    if (trial % 10 == 0) w[count / 2] = cd(std::numeric_limits<double>::quiet_NaN(), 0.0);
    std::vector<double> a(count, 0.0), b(count, 0.0);
    kernels::phase_advances(w.data(), count, derotate, advance, a.data());
    kernels::phase_advances_generic(w.data(), count, derotate, advance, b.data());
    for (std::size_t i = 1; i < count; ++i)
      ASSERT_TRUE(same_bits(a[i], b[i]) || (std::isnan(a[i]) && std::isnan(b[i])))
          << "trial " << trial << " column " << i << ": " << a[i] << " vs " << b[i];
  }
  // phase_angle is arg: within a few ulp of std::arg on the series' range and equal to it off it
  // (4 ulp of 0.12: the series' truncation is below 3e-18, the rest is the division's and Horner's
  // rounding).
  for (double t = -0.125; t <= 0.125; t += 1.0 / 512.0) {
    const cd z(2.0, 2.0 * t);
    EXPECT_NEAR(kernels::phase_angle(z), std::arg(z), 4 * std::numeric_limits<double>::epsilon() * 0.125) << t;
  }
  EXPECT_EQ(kernels::phase_angle(cd(-1.0, 0.5)), std::arg(cd(-1.0, 0.5)));
}

TEST(KernelsAnalyzer, ModeBinMatchesGeneric) {
  std::mt19937 rng(14);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double fs = 25600.0;
  for (int trial = 0; trial < 200; ++trial) {
    const double n = static_cast<double>(200 + static_cast<int>(uni(rng) * 2000));
    const double f = 200.0 + uni(rng) * 2000.0, zeta = std::exp(-9.0 + 7.0 * uni(rng));
    const double omega = 2.0 * std::numbers::pi * f, sigma = zeta * omega / std::sqrt(1.0 - zeta * zeta);
    const cd e(-sigma / fs, omega / fs);
    kernels::ModeBinState m;
    m.z = std::exp(e);
    m.one_minus_zn = 1.0 - std::exp(n * e);
    m.zn1 = std::exp((n - 1.0) * e);
    m.c = cd(uni(rng) - 0.5, uni(rng) - 0.5);
    m.c_dz_df = m.c * m.z * cd(-0.1 * uni(rng), 2.0 * std::numbers::pi) / fs;
    m.c_dz_du = m.c * m.z * cd(-sigma, 0.0) / fs;
    kernels::fill_lanes(m, n);
    for (int b = 0; b < 8; ++b) {
      const double k = std::floor(f / fs * n) - 3.0 + b;
      const cd wk = std::polar(1.0, -2.0 * std::numbers::pi * k / n);
      cd col_a[4], col_b[4];
      const cd va = kernels::mode_bin(m, kernels::both(wk), col_a);
      const cd vb = kernels::mode_bin_generic(m, wk, n, col_b);
      ASSERT_TRUE(same_bits(va, vb)) << "trial " << trial << " bin " << b << ": " << va << " vs " << vb;
      for (int c = 0; c < 4; ++c) ASSERT_TRUE(same_bits(col_a[c], col_b[c])) << "column " << c;
      ASSERT_TRUE(same_bits(kernels::mode_bin(m, kernels::both(wk), nullptr), vb));
    }
  }
}

}  // namespace
