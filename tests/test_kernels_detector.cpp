// The impact detector's kernels (core/dsp/kernels/: fir_steps, clipped_sum, spike_residual, ring_sum,
// iq_lowpass, phasor_rotate) against their scalar references: bit-identical outputs on random inputs
// of every size the detector uses and the edge sizes around them (remainders of the vectors of four,
// ring wrap-around), with NaN, infinities, signed zeros and huge values among the inputs where the
// kernel must handle them like its reference.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

#include "core/dsp/kernels/clipped_sum.hpp"
#include "core/dsp/kernels/fir_steps.hpp"
#include "core/dsp/kernels/iq_lowpass.hpp"
#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/phasor_rotate.hpp"
#include "core/dsp/kernels/ring_sum.hpp"
#include "core/dsp/kernels/spike_residual.hpp"

namespace ridgewatch::dsp::kernels {
namespace {

// Bit patterns: "equal" must not hide -0 vs +0 or NaN payload differences.
std::uint32_t bits(float v) { return std::bit_cast<std::uint32_t>(v); }
std::uint64_t bits(double v) { return std::bit_cast<std::uint64_t>(v); }

std::vector<float> random_floats(std::size_t n, std::mt19937& rng, float scale = 1.0f) {
  std::normal_distribution<float> g(0.0f, scale);
  std::vector<float> v(n);
  for (float& x : v) x = g(rng);
  return v;
}

// Runs body with the kernels' baseline (SSE2) forms, then with the CPU's choice (the AVX2 forms where
// the CPU has AVX2, isa.hpp), and restores the CPU's choice.
template <typename Body>
void for_each_isa(Body body) {
  for (const bool baseline : {true, false}) {
    SCOPED_TRACE(baseline ? "baseline forms" : "forms chosen for this CPU");
    limit_kernels_to_baseline(baseline);
    body();
  }
  limit_kernels_to_baseline(false);
}

TEST(KernelsDetector, FirStepsMatchesReference) {
  for_each_isa([] {
    std::mt19937 rng(1);
    // n_taps 4..32 covers the register-held taps (<= 24) and the plain loop; steps 1..16 and counts
    // across the groups of four windows and their remainder.
    for (std::size_t n_taps = 4; n_taps <= 32; n_taps += 4) {
      for (std::size_t step : {1u, 3u, 10u, 16u}) {
        for (std::size_t count : {0u, 1u, 3u, 4u, 5u, 16u}) {
          const auto x = random_floats(step * count + n_taps + 4, rng);
          const auto g_re = random_floats(n_taps, rng), g_im = random_floats(n_taps, rng);
          std::vector<float> re(count + 4, 7.0f), im(count + 4, 7.0f), re_g(count + 4, 7.0f), im_g(count + 4, 7.0f);
          fir_steps(x.data(), step, count, g_re.data(), g_im.data(), n_taps, re.data(), im.data());
          fir_steps_generic(x.data(), step, count, g_re.data(), g_im.data(), n_taps, re_g.data(), im_g.data());
          for (std::size_t j = 0; j < count + 4; ++j) {
            ASSERT_EQ(bits(re[j]), bits(re_g[j])) << "taps " << n_taps << " step " << step << " count " << count << " j " << j;
            ASSERT_EQ(bits(im[j]), bits(im_g[j])) << "taps " << n_taps << " step " << step << " count " << count << " j " << j;
          }
        }
      }
    }
  });
}

TEST(KernelsDetector, ClippedSumMatchesReference) {
  std::mt19937 rng(2);
  for (std::size_t n = 0; n <= 41; ++n) {
    for (int trial = 0; trial < 20; ++trial) {
      auto r = random_floats(n, rng);
      if (n > 3 && trial % 5 == 1) r[n / 2] = -0.0f;
      if (n > 3 && trial % 5 == 2) r[n - 1] = std::numeric_limits<float>::quiet_NaN();
      if (n > 3 && trial % 5 == 3) r[1] = -std::numeric_limits<float>::infinity();
      const float clip = 0.5f + static_cast<float>(trial) * 0.1f, above = 1.0f + static_cast<float>(trial % 4);
      double s = 0.0, s_g = 0.0;
      const bool a = clipped_sum_any_above(r.data(), n, clip, above, s);
      const bool a_g = clipped_sum_any_above_generic(r.data(), n, clip, above, s_g);
      ASSERT_EQ(a, a_g) << "n " << n << " trial " << trial;
      ASSERT_EQ(bits(s), bits(s_g)) << "n " << n << " trial " << trial;
    }
  }
}

TEST(KernelsDetector, SpikeResidualBlocksMatchReference) {
  for_each_isa([] {
    std::mt19937 rng(3);
    // len % 4 == 0 with several blocks (the detector's 20-sample blocks at 51.2 kHz), and single blocks
    // of any length (10 at 25.6 kHz, 5 and 7 for other rates).
    struct Case { std::size_t len, count; };
    for (const Case c : {Case{20, 4}, Case{20, 1}, Case{8, 8}, Case{4, 3}, Case{10, 1}, Case{5, 1}, Case{7, 1},
                         Case{3, 1}, Case{1, 1}, Case{12, 2}}) {
      for (int trial = 0; trial < 10; ++trial) {
        const std::size_t n = c.len * c.count + 16;
        auto x = random_floats(n + 4, rng);
        if (trial == 3) x[2 + c.len / 2 + 2] = 50.0f;  // a spike: one large residual
        if (trial == 4) x[4] = std::numeric_limits<float>::quiet_NaN();
        const auto r0 = random_floats(n + 4, rng);  // r[0], r[1] must be kept, the rest overwritten
        std::vector<float> r = r0, r_g = r0;
        std::vector<float> sums(c.count), tops(c.count), sums_g(c.count), tops_g(c.count);
        const float clip = 1.5f;
        // x + 2: the kernels read two samples before their first.
        spike_residual_blocks(x.data() + 2, r.data(), c.len, c.count, clip, sums.data(), tops.data());
        spike_residual_blocks_generic(x.data() + 2, r_g.data(), c.len, c.count, clip, sums_g.data(), tops_g.data());
        for (std::size_t i = 0; i < r.size(); ++i)
          ASSERT_EQ(bits(r[i]), bits(r_g[i])) << "len " << c.len << " count " << c.count << " i " << i;
        EXPECT_EQ(bits(r[0]), bits(r0[0]));
        EXPECT_EQ(bits(r[1]), bits(r0[1]));
        for (std::size_t k = 0; k < c.count; ++k) {
          ASSERT_EQ(bits(sums[k]), bits(sums_g[k])) << "len " << c.len << " count " << c.count << " block " << k;
          ASSERT_EQ(bits(tops[k]), bits(tops_g[k])) << "len " << c.len << " count " << c.count << " block " << k;
        }
      }
    }
  });
}

TEST(KernelsDetector, SpikeResidualReferenceIsTheInterpolationResidual) {
  // Independent check of the reference's formula: for a cubic x[n] = n^3 / 64 (exact in float) the
  // 4-neighbour cubic interpolation is exact, so every residual is 0 up to float rounding of the
  // terms (|x| <= 8: rounding <= 1e-5); a single sample raised by 6 leaves a residual of 6 there,
  // -4 at its neighbours and +1 two away.
  std::vector<float> x(40);
  for (std::size_t n = 0; n < x.size(); ++n) x[n] = static_cast<float>(std::pow(static_cast<double>(n) / 4.0, 3));
  std::vector<float> r(40, 0.0f);
  float sums[1], tops[1];
  spike_residual_blocks_generic(x.data() + 2, r.data(), 20, 1, 1e9f, sums, tops);
  EXPECT_LT(tops[0], 1e-5f);
  std::vector<float> y(40, 0.0f);
  y[12] = 6.0f;
  spike_residual_blocks_generic(y.data() + 2, r.data(), 20, 1, 1e9f, sums, tops);
  EXPECT_FLOAT_EQ(r[10], 6.0f);
  EXPECT_FLOAT_EQ(r[9], -4.0f);
  EXPECT_FLOAT_EQ(r[11], -4.0f);
  EXPECT_FLOAT_EQ(r[8], 1.0f);
  EXPECT_FLOAT_EQ(r[12], 1.0f);
}

TEST(KernelsDetector, RingSumMatchesReference) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.0, 1e-3);
  std::vector<double> ring(64);
  for (double& v : ring) v = u(rng);
  const std::uint64_t mask = ring.size() - 1;
  for (std::uint64_t lo = 0; lo < 130; lo += 7) {
    for (std::uint64_t len = 0; len <= 64; ++len) {
      const double a = ring_sum(ring.data(), mask, lo, lo + len), b = ring_sum_generic(ring.data(), mask, lo, lo + len);
      ASSERT_EQ(bits(a), bits(b)) << "lo " << lo << " len " << len;
    }
  }
  // Independent check: integers are summed exactly in any order.
  std::vector<double> ints(16);
  for (std::size_t i = 0; i < ints.size(); ++i) ints[i] = static_cast<double>(i + 1);
  EXPECT_EQ(ring_sum(ints.data(), 15, 10, 10 + 16), 136.0);  // wraps: all 16 entries, 1 + ... + 16
}

TEST(KernelsDetector, IqLowPassMatchesReference) {
  // A bilinear-transform low-pass stage (numerator (1, 2, 1) b0, as the detector designs it) and an
  // input with steps, noise and a burst.
  auto stage = [](double f, double q, double fs) {
    const double w0 = 2.0 * std::numbers::pi * f / fs, c = std::cos(w0), alpha = std::sin(w0) / (2.0 * q);
    const double a0 = 1.0 + alpha;
    BiquadCoefs b;
    b.b0 = (1.0 - c) / 2.0 / a0;
    b.b1 = (1.0 - c) / a0;
    b.b2 = b.b0;
    b.a1 = -2.0 * c / a0;
    b.a2 = (1.0 - alpha) / a0;
    return b;
  };
  for (double fs : {5120.0, 5688.9, 800.0}) {
    const BiquadCoefs c1 = stage(125.0, 0.5412, fs), c2 = stage(125.0, 1.3066, fs);
    ASSERT_EQ(c1.b1, 2.0 * c1.b0);  // the kernel's precondition
    const IqLowPass4Coefs c(c1, c2);
    IqLowPass4State s, s_g;
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0.0, 1.0);
    for (int n = 0; n < 5000; ++n) {
      const simd::f64x2 z = {g(rng) + (n > 100 ? 3.0 : 0.0), n % 700 < 20 ? 1e3 * g(rng) : g(rng)};
      const simd::f64x2 y = iq_lowpass4_step(c, s, z), y_g = iq_lowpass4_step_generic(c1, c2, s_g, z);
      ASSERT_EQ(bits(y[0]), bits(y_g[0])) << "fs " << fs << " n " << n;
      ASSERT_EQ(bits(y[1]), bits(y_g[1])) << "fs " << fs << " n " << n;
    }
    // Independent check of the design and the recursion: unit DC gain (Butterworth low-pass), so a
    // constant input settles to itself (to 1e-9: 5000 samples are > 30 time constants of the slowest
    // pole pair at these rates).
    IqLowPass4State d;
    simd::f64x2 y{0.0, 0.0};
    for (int n = 0; n < 5000; ++n) y = iq_lowpass4_step(c, d, simd::f64x2{1.0, -2.0});
    EXPECT_NEAR(y[0], 1.0, 1e-9);
    EXPECT_NEAR(y[1], -2.0, 1e-9);
  }
}

TEST(KernelsDetector, PhasorRotateMatchesReference) {
  std::mt19937 rng(6);
  for (std::size_t n : {1u, 3u, 4u, 13u, 16u}) {
    const std::size_t pad = (n + 3) / 4 * 4;
    const auto fr = random_floats(pad, rng), fi = random_floats(pad, rng);
    const auto tr = random_floats(pad, rng), ti = random_floats(pad, rng);
    std::vector<float> zr(pad), zi(pad), zr_g(pad), zi_g(pad);
    phasor_rotate(fr.data(), fi.data(), tr.data(), ti.data(), 0.6f, -0.8f, n, zr.data(), zi.data());
    phasor_rotate_generic(fr.data(), fi.data(), tr.data(), ti.data(), 0.6f, -0.8f, n, zr_g.data(), zi_g.data());
    for (std::size_t j = 0; j < n; ++j) {
      ASSERT_EQ(bits(zr[j]), bits(zr_g[j])) << "n " << n << " j " << j;
      ASSERT_EQ(bits(zi[j]), bits(zi_g[j])) << "n " << n << " j " << j;
    }
  }
  // Independent check: rotating 1 by (base i) x (table 1) gives i.
  const float one = 1.0f, zero = 0.0f;
  float zr = 0, zi = 0;
  phasor_rotate_generic(&one, &zero, &one, &zero, 0.0f, 1.0f, 1, &zr, &zi);
  EXPECT_EQ(zr, 0.0f);
  EXPECT_EQ(zi, 1.0f);
}

}  // namespace
}  // namespace ridgewatch::dsp::kernels
