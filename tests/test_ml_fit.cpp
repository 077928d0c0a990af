// SpectralModeFitter internals against slow references: the DFT bins its fits use (Goertzel recursions,
// several bins per pass) against a one-bin-at-a-time evaluation of the same arithmetic (exactly) and a
// direct DFT in long double (to the recursion's round-off); fits by the fast kernels (model terms in
// SSE2 pairs, compile-time-size normal equations, reused mode states) against fits by the plain
// reference kernels (exactly); a steady line fitted as an undamped second component. The fits'
// accuracy is tested in test_damping.cpp.
#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <cstring>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "core/dsp/ml_fit.hpp"
#include "core/dsp/synthetic.hpp"

using namespace ridgewatch::dsp;

namespace {

using cd = std::complex<double>;

// The fitter's twiddle table entry e^{-2 pi i m / N}, computed as the fitter computes it.
cd twiddle(std::size_t m, std::size_t n) {
  return std::polar(1.0, -2.0 * std::numbers::pi * static_cast<double>(m % n) / static_cast<double>(n));
}

// The polyphase Goertzel value of bin k (ml_fit.cpp: 8 phases, zero-padded last row, read-out and
// combination in the same operations and order), one bin and one phase at a time in scalars.
cd reference_bin(const std::vector<double>& x, std::size_t k) {
  constexpr std::size_t kPhases = 8;
  const std::size_t n = x.size();
  const std::size_t m_count = (n + kPhases - 1) / kPhases;
  const double coef = 2.0 * twiddle(k * kPhases, n).real();
  double s1[kPhases], s2[kPhases];
  for (std::size_t j = 0; j < kPhases; ++j) {
    double a = 0.0, b = 0.0;  // s[m-1], s[m-2]
    for (std::size_t m = 0; m < m_count; ++m) {
      const std::size_t i = kPhases * m + j;
      const double xv = i < n ? x[i] : 0.0;
      const double s0 = (xv - b) + coef * a;
      b = a;
      a = s0;
    }
    s1[j] = a;
    s2[j] = b;
  }
  const cd e = twiddle(k * kPhases, n);
  const cd rot = twiddle(((k * kPhases) % n) * (m_count - 1), n);
  cd acc(0.0, 0.0);
  for (std::size_t j = 0; j < kPhases; ++j) acc += (s1[j] - e * s2[j]) * twiddle(k * j, n);
  acc *= rot;
  return acc;
}

bool same_bits(cd a, cd b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// Every reported number of two fits, bit for bit.
void expect_same_fit(const MlFitResult& a, const MlFitResult& b, const std::string& what) {
  EXPECT_TRUE(same_bits(a.noise_sd, b.noise_sd)) << what << ": noise_sd " << a.noise_sd << " vs " << b.noise_sd;
  EXPECT_EQ(a.converged, b.converged) << what;
  EXPECT_EQ(a.bins, b.bins) << what;
  ASSERT_EQ(a.modes.size(), b.modes.size()) << what;
  for (std::size_t j = 0; j < a.modes.size(); ++j) {
    const DampingEstimate& x = a.modes[j];
    const DampingEstimate& y = b.modes[j];
    EXPECT_EQ(x.status, y.status) << what << " mode " << j;
    const double xs[] = {x.f_hz, x.zeta, x.f_sd_hz, x.zeta_sd, x.zeta_ci95_lo, x.zeta_ci95_hi, x.amplitude};
    const double ys[] = {y.f_hz, y.zeta, y.f_sd_hz, y.zeta_sd, y.zeta_ci95_lo, y.zeta_ci95_hi, y.amplitude};
    for (std::size_t i = 0; i < std::size(xs); ++i)
      EXPECT_TRUE(same_bits(xs[i], ys[i])) << what << " mode " << j << " field " << i << ": " << xs[i] << " vs " << ys[i];
  }
}

}  // namespace

// Segment lengths with and without a partial last row of 8 samples and with an odd and an even number
// of full rows (the recursion runs its steps in pairs), every bin count up to 9 (bins run two per pass
// plus a single one for odd counts), at several band positions.
TEST(MlFitBins, GoertzelBinsEqualOneBinReference) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (const std::size_t n : {64u, 72u, 75u, 100u, 883u, 1766u}) {
    std::vector<double> x(n);
    for (std::size_t i = 0; i < n; ++i)
      x[i] = std::exp(-3.0 * static_cast<double>(i) / static_cast<double>(n)) *
                 std::sin(0.7 * static_cast<double>(i)) +
             0.1 * n01(rng);
    SpectralModeFitter fitter(n, 25600.0, 1);  // max_bins 1: no FFT plan, every band by Goertzel
    for (std::size_t count = 1; count <= 9; ++count) {
      for (const std::size_t k_lo : {std::size_t{1}, std::size_t{5}, (n - 1) / 2 - count + 1}) {
        std::vector<cd> bins(count);
        fitter.dft_bins(x, k_lo, bins);
        for (std::size_t i = 0; i < count; ++i) {
          const cd want = reference_bin(x, k_lo + i);
          EXPECT_TRUE(same_bits(bins[i], want))
              << "n " << n << " count " << count << " k " << k_lo + i << ": " << bins[i] << " vs " << want;
        }
      }
    }
  }
}

// The same bins against a direct DFT in long double: the recursion's round-off (~M^2 eps / sin(t),
// M = N / 8) stays far below 1e-11 of sum |x|.
TEST(MlFitBins, GoertzelBinsMatchDirectDft) {
  const std::size_t n = 883;
  std::vector<double> x(n);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n01(0.0, 1.0);
  double l1 = 0.0;
  for (double& v : x) {
    v = n01(rng);
    l1 += std::abs(v);
  }
  SpectralModeFitter fitter(n, 25600.0, 1);
  const std::size_t k_lo = 25, count = 7;
  std::vector<cd> bins(count);
  fitter.dft_bins(x, k_lo, bins);
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t k = k_lo + i;
    long double re = 0, im = 0;
    for (std::size_t m = 0; m < n; ++m) {
      const long double t = -2.0L * std::numbers::pi_v<long double> * static_cast<long double>((k * m) % n) /
                            static_cast<long double>(n);
      re += x[m] * std::cos(t);
      im += x[m] * std::sin(t);
    }
    EXPECT_LT(std::abs(bins[i] - cd(static_cast<double>(re), static_cast<double>(im))), 1e-11 * l1) << k;
  }
}

TEST(MlFitBins, RejectsBinsOutsideTheHalfSpectrum) {
  SpectralModeFitter fitter(100, 1000.0, 1);
  std::vector<double> x(100, 0.0), wrong(99, 0.0);
  std::vector<cd> bins(3);
  EXPECT_THROW(fitter.dft_bins(wrong, 1, bins), std::invalid_argument);
  EXPECT_THROW(fitter.dft_bins(x, 0, bins), std::invalid_argument);
  EXPECT_THROW(fitter.dft_bins(x, 48, bins), std::invalid_argument);  // 50 > 49
  EXPECT_NO_THROW(fitter.dft_bins(x, 47, bins));
}

// Fits by the fast kernels equal fits by the reference kernels (SpectralModeFitter::use_reference_kernels)
// bit for bit: the pipeline's one mode with one and two residual terms (6 and 8 parameters: the
// compile-time-size paths), none (4), two modes (12: run-time size), and three modes on many bins (16:
// the general MINPACK path, FFT bins), each on noisy segments from several seeds and misplaced starts.
TEST(MlFitKernels, FastKernelsEqualReferenceKernels) {
  struct Case {
    std::size_t n;
    double fs;
    std::vector<DampedComponent> truth;
    std::vector<ModeGuess> guesses;
    double f_lo, f_hi;
    int residual_terms;
  };
  const std::vector<Case> cases = {
      {883, 25600.0, {{1.0, 860.0, 0.024, 0.3}, {0.5, 1500.0, 0.01, 1.0}}, {{851.0, 0.02}}, 757.0, 963.0, 1},
      {883, 25600.0, {{1.0, 860.0, 0.024, 0.3}, {0.5, 1500.0, 0.01, 1.0}}, {{866.0, 0.03}}, 722.0, 998.0, 2},
      {883, 25600.0, {{1.0, 860.0, 0.024, 0.3}}, {{855.0, 0.02}}, 757.0, 963.0, 0},
      {1766, 25600.0, {{1.0, 800.0, 0.02, 0.3}, {0.7, 1000.0, 0.015, 2.0}}, {{795.0, 0.025}, {1004.0, 0.012}},
       650.0, 1150.0, 2},
      {4000, 10000.0, {{1.0, 250.0, 0.02, 0.0}, {0.8, 500.0, 0.045, 1.0}, {0.5, 1250.0, 0.005, 2.0}},
       {{248.0, 0.025}, {505.0, 0.04}, {1251.0, 0.006}}, 100.0, 1500.0, 2},
  };
  for (std::size_t c = 0; c < cases.size(); ++c) {
    const Case& cs = cases[c];
    SpectralModeFitter fast(cs.n, cs.fs);
    SpectralModeFitter reference(cs.n, cs.fs);
    reference.use_reference_kernels(true);
    MlFitOptions o;
    o.f_lo_hz = cs.f_lo;
    o.f_hi_hz = cs.f_hi;
    o.residual_terms = cs.residual_terms;
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
      auto x = damped_sum(cs.truth, cs.fs, cs.n);
      add_white_noise(x, 10.0 + 5.0 * static_cast<double>(seed), seed);
      const MlFitResult a = fast.fit(x, cs.guesses, o);
      const MlFitResult b = reference.fit(x, cs.guesses, o);
      ASSERT_FALSE(a.modes.empty());
      EXPECT_EQ(a.modes[0].status, EstimateStatus::ok) << "case " << c << " seed " << seed;
      expect_same_fit(a, b, "case " + std::to_string(c) + " seed " + std::to_string(seed));
    }
  }
}

// A steady line fitted as a second component (the impact analyzer's line component): its damping runs
// towards zero, where the RSS no longer depends on it. The fit still reports the decaying mode with an
// interval (the line's ln zeta held out of the covariance) and the line's own interval as null. A
// decay at 860 Hz (zeta 0.024) plus a line at 790 Hz (10 % of its amplitude) and 1 % noise, 1000
// samples at 25.6 kHz; 20 noise seeds.
TEST(MlFitLine, UndampedComponentLeavesTheModeItsInterval) {
  constexpr double fs = 25600.0, f = 860.0, zeta = 0.024, f_line = 790.0;
  constexpr std::size_t n = 1000;
  SpectralModeFitter fitter(n, fs);
  const double omega = 2.0 * std::numbers::pi * f;
  const double sigma = zeta * omega / std::sqrt(1.0 - zeta * zeta);
  std::size_t covered = 0, line_held = 0;
  for (unsigned seed = 1; seed <= 20; ++seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, 0.01);
    std::vector<double> x(n);
    for (std::size_t i = 0; i < n; ++i) {
      const double t = static_cast<double>(i) / fs;
      x[i] = std::exp(-sigma * t) * std::cos(omega * t) + 0.1 * std::cos(2.0 * std::numbers::pi * f_line * t + 0.4) +
             noise(rng);
    }
    const ModeGuess guesses[2] = {{f, 0.02}, {f_line + 10.0, 1e-4}};
    MlFitOptions o;
    o.f_lo_hz = 700.0;
    o.f_hi_hz = 1000.0;
    o.residual_terms = 2;
    const MlFitResult r = fitter.fit(x, guesses, o);
    ASSERT_EQ(r.modes.size(), 2u);
    const DampingEstimate& m = r.modes[0];
    ASSERT_EQ(m.status, EstimateStatus::ok) << "seed " << seed;
    ASSERT_TRUE(std::isfinite(m.zeta_ci95_lo) && std::isfinite(m.zeta_ci95_hi)) << "seed " << seed;
    // The interval is an interval: +-2 sd around zeta, narrow (< +-10 %) at this SNR.
    EXPECT_LT(m.zeta_ci95_hi / m.zeta_ci95_lo, 1.2) << "seed " << seed;
    covered += m.zeta_ci95_lo <= zeta && zeta <= m.zeta_ci95_hi;
    EXPECT_NEAR(r.modes[1].f_hz, f_line, 1.0) << "seed " << seed;
    if (r.modes[1].status == EstimateStatus::fit_failed) {
      ++line_held;
      EXPECT_TRUE(std::isnan(r.modes[1].zeta_ci95_lo)) << "seed " << seed;
    }
  }
  // 95 % intervals: at least 16 of 20 cover the truth (binomial: P(<= 15 | 0.95) = 1.6 %).
  EXPECT_GE(covered, 16u);
  // The line's damping ran off towards zero in most seeds (the case this tests).
  EXPECT_GE(line_held, 10u);
}

// P(|T| <= t) for Student's t with nu (integer) degrees of freedom in closed form (Abramowitz & Stegun
// 26.7.3 / 26.7.4, theta = atan(t / sqrt(nu))), computed here independently of the table and series in
// student_t95.
namespace {
double student_two_sided(double t, int nu) {
  const double th = std::atan(t / std::sqrt(static_cast<double>(nu))), c2 = std::cos(th) * std::cos(th);
  double term = 1.0, sum = 1.0;
  if (nu % 2 == 0) {
    for (int k = 2; k <= nu - 2; k += 2) sum += term *= c2 * (k - 1) / k;
    return std::sin(th) * sum;
  }
  if (nu == 1) return 2.0 * th / std::numbers::pi;
  for (int k = 3; k <= nu - 2; k += 2) sum += term *= c2 * (k - 1) / k;
  return 2.0 / std::numbers::pi * (th + std::sin(th) * std::cos(th) * sum);
}
}  // namespace

// The interval's quantile is t_{0.975, dof}: P(|T| <= student_t95(dof)) = 0.95. Tolerance 5e-5: the
// table's 4 decimals move the probability by at most ~3e-5 (density <= 0.07 at the quantile for
// nu >= 2, 0.5e-4 rounding; nu = 1: density 0.004), the series above 30 is closer than that.
TEST(MlFitInterval, StudentQuantileIsTheNinetyFivePercentOne) {
  for (int nu : {1, 2, 3, 5, 6, 7, 10, 29, 30, 31, 40, 60, 100, 250, 1000})
    EXPECT_NEAR(student_two_sided(student_t95(nu), nu), 0.95, 5e-5) << "dof " << nu;
  EXPECT_GT(student_t95(6), 2.4);  // 6 residual degrees of freedom: 25 % wider than 1.96
  EXPECT_TRUE(std::isnan(student_t95(0)));
}
