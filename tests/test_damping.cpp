// Damping estimators and multi-mode identification against analytic damped sinusoids and the paper's
// Table-1 signal.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "core/dsp/damping.hpp"
#include "core/dsp/ml_fit.hpp"
#include "core/dsp/modes.hpp"
#include "core/dsp/select.hpp"
#include "core/dsp/morlet_cwt.hpp"
#include "core/dsp/synthetic.hpp"

using namespace ridgewatch::dsp;

namespace {

constexpr double kPi = std::numbers::pi;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The identified mode closest in frequency to f_hz (nullptr if none within 5 %).
const IdentifiedMode* match(const ModeSearchResult& r, double f_hz) {
  const IdentifiedMode* best = nullptr;
  for (const auto& m : r.modes)
    if (!best || std::abs(m.ridge_ls.f_hz - f_hz) < std::abs(best->ridge_ls.f_hz - f_hz)) best = &m;
  if (best && std::abs(best->ridge_ls.f_hz / f_hz - 1.0) > 0.05) return nullptr;
  return best;
}

// One CWT row of x at frequency f (default eta0), full rate.
std::vector<std::complex<double>> single_row(const std::vector<double>& x, double fs, double f,
                                             double& time_step_s) {
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.frequencies_hz = {f};
  cfg.max_samples = x.size();
  MorletCwt<double> cwt(cfg);
  cwt.load(x);
  std::vector<std::complex<double>> w(cwt.columns());
  cwt.row(f, w);
  time_step_s = cwt.time_step_s();
  return w;
}

}  // namespace

TEST(DampingRelations, ZetaFromDecayMatchesEquation19) {
  // Eq. (17) for the model (16): delta = sigma T_d = 2 pi sigma / omega_d; Eq. (19) gives zeta.
  for (double zeta : {0.001, 0.02, 0.3, 0.9}) {
    const double omega_d = 2 * kPi * 854.0;
    const double sigma = decay_from_zeta(zeta, omega_d);
    const double delta = 2 * kPi * sigma / omega_d;
    const double eq19 = delta / std::sqrt(4 * kPi * kPi + delta * delta);
    EXPECT_NEAR(zeta_from_decay(sigma, omega_d), zeta, 1e-14);
    EXPECT_NEAR(eq19, zeta, 1e-14);
  }
}

TEST(DampingMethodNames, RoundTrip) {
  for (DampingMethod m : {DampingMethod::two_point, DampingMethod::ridge_ls, DampingMethod::ml}) {
    DampingMethod parsed = DampingMethod::two_point;
    ASSERT_TRUE(parse_damping_method(to_string(m), parsed));
    EXPECT_EQ(parsed, m);
  }
  DampingMethod unused{};
  EXPECT_FALSE(parse_damping_method("least-squares", unused));
}

// Single-mode grid, noise-free: zeta in {0.002, 0.01, 0.024, 0.05} x f in {200, 854, 3000} Hz.
// The issue asks for recovery within 0.1 %; the maximum-likelihood model is exact for sampled
// damped sinusoids, so it must be far better (limited by the optimiser tolerance); the envelope
// methods are exact in the continuum limit but see the Gaussian edge factor and interpolation.
TEST(SingleModeGrid, NoiseFreeRecoveryWithinTenthOfAPercent) {
  const double fs = 25600.0;
  for (double f : {200.0, 854.0, 3000.0}) {
    for (double zeta : {0.002, 0.01, 0.024, 0.05}) {
      // Long enough for the envelope to fall well below its start even at zeta = 0.002, f = 200 Hz.
      const double decay_s = 1.0 / decay_from_zeta(zeta, 2 * kPi * f);
      const auto n = static_cast<std::size_t>(std::min(4.0, std::max(0.25, 3.0 * decay_s)) * fs);
      const auto x = damped_sum({{1.0, f, zeta, 0.3}}, fs, n);
      ModeSearchOptions opt;
      opt.onset_s = 0.0;
      const ModeSearchResult r = identify_modes(x, fs, opt);
      const IdentifiedMode* m = match(r, f);
      ASSERT_NE(m, nullptr) << "f=" << f << " zeta=" << zeta;
      SCOPED_TRACE("f=" + std::to_string(f) + " zeta=" + std::to_string(zeta));
      EXPECT_EQ(m->ml.status, EstimateStatus::ok);
      EXPECT_NEAR(m->ml.zeta / zeta, 1.0, 1e-3);
      EXPECT_NEAR(m->ml.f_hz / f, 1.0, 1e-3);
      EXPECT_NEAR(m->ridge_ls.zeta / zeta, 1.0, 1e-3);
      EXPECT_NEAR(m->ridge_ls.f_hz / f, 1.0, 1e-3);
    }
  }
}

// Reads the frequency from the scale maximum of the paper-normalised transform (|W_paper| = |W| / K,
// K proportional to sqrt(f), Eq. 12), and from the phase slope. The scale maximum is biased by about
// -1/(2 eta0^2) (maximise exp(-(eta0 (1 - f0/f))^2 / 2) / sqrt(f)); the phase slope is not.
TEST(RidgeFrequency, PhaseSlopeRemovesTheScaleMaximumBias) {
  const double fs = 10000.0, f0 = 500.0, eta0 = 7.0;
  const auto x = damped_sum({{1.0, f0, 0.0, 0.0}}, fs, 8000);  // a steady tone
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.eta0 = eta0;
  cfg.frequencies_hz = make_frequency_grid(400, 600, 2001, GridSpacing::linear);  // 0.1 Hz steps
  cfg.max_samples = x.size();
  MorletCwt<double> cwt(cfg);
  cwt.load(x);
  std::vector<std::complex<double>> w(cwt.columns());
  const std::size_t mid = w.size() / 2;
  double best_f = 0, best = -1;
  for (double f : cfg.frequencies_hz) {
    cwt.row(f, w);
    const double paper_modulus = std::abs(w[mid]) / std::sqrt(f);
    if (paper_modulus > best) best = paper_modulus, best_f = f;
  }
  const double bias = best_f / f0 - 1.0;
  EXPECT_NEAR(bias, -1.0 / (2 * eta0 * eta0), 1.5e-3);  // -1.02 %, to within the 0.1 Hz grid + O(eta0^-4)
  EXPECT_LT(bias, -0.008);

  // Phase slope from a row deliberately 3 % off the tone.
  cwt.row(f0 * 1.03, w);
  EnvelopeRow row{w, cwt.time_step_s(), f0 * 1.03, eta0, NAN};
  const EnvelopeWindow win{1000, 7000, 4000, 1e-12, EstimateStatus::ok};
  double sd = NAN;
  const double f_phase = phase_slope_frequency(row, win, sd);
  EXPECT_NEAR(f_phase / f0 - 1.0, 0.0, 1e-9);  // exact in double precision for a pure tone
}

// Envelope normalisation (Eq. 12): the ridge-LS amplitude at the window start equals the true
// envelope A exp(-sigma t) there.
TEST(RidgeLs, AmplitudeEqualsSignalEnvelope) {
  const double fs = 10000.0, f = 700.0, zeta = 0.01, a = 2.5;
  const auto x = damped_sum({{a, f, zeta, 1.0}}, fs, 10000);
  double dt = 0.0;
  const auto w = single_row(x, fs, f, dt);
  const EnvelopeRow row{w, dt, f, 7.0, 1e-20};  // noise-free: tiny noise power
  const EnvelopeWindow win = choose_window(row, EnvelopeOptions{});
  const DampingEstimate e = estimate_ridge_ls(row, win, f);
  ASSERT_EQ(e.status, EstimateStatus::ok);
  const double expected = a * std::exp(-decay_from_zeta(zeta, 2 * kPi * f) * e.window_start_s);
  // The estimator divides out the in-kernel decay gain exp(s^2 sigma^2 / 2) (= 1.0024 here, which the
  // paper's Eq. 12 neglects); what remains is the 3e-5 edge factor and round-off.
  EXPECT_NEAR(e.amplitude / expected, 1.0, 1e-4);
}

// The window ends where the envelope meets the noise, so weaker signals give shorter windows, and a
// signal below the noise is reported as low_snr instead of a number that looks fine.
TEST(RidgeLs, WindowFollowsNoiseFloorAndFlagsLowSnr) {
  const double fs = 10000.0, f = 500.0, zeta = 0.01;
  const auto weak = damped_sum({{0.05, f, zeta, 0.0}}, fs, 10000);
  const auto buried = damped_sum({{0.001, f, zeta, 0.0}}, fs, 10000);
  // The same noise (sd 0.01) under three amplitudes.
  auto run = [&](std::vector<double> x, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> n01(0.0, 0.01);
    for (double& v : x) v += n01(rng);
    double dt = 0.0;
    const auto w = single_row(x, fs, f, dt);
    const EnvelopeRow row{w, dt, f, 7.0, NAN};  // noise power estimated from the row
    const EnvelopeWindow win = choose_window(row, EnvelopeOptions{});
    return std::make_pair(win, estimate_ridge_ls(row, win, f));
  };
  const auto [w_strong, e_strong] = run(damped_sum({{1.0, f, zeta, 0.0}}, fs, 10000), 3);
  const auto [w_weak, e_weak] = run(weak, 3);
  const auto [w_buried, e_buried] = run(buried, 3);
  EXPECT_EQ(e_strong.status, EstimateStatus::ok);
  EXPECT_EQ(e_weak.status, EstimateStatus::ok);
  EXPECT_GT(w_strong.end - w_strong.start, w_weak.end - w_weak.start);
  EXPECT_EQ(e_buried.status, EstimateStatus::low_snr);
  // Statistical tolerances: the ridge-LS interval at these SNRs is ~0.5 % (strong) and ~5 % (weak).
  EXPECT_NEAR(e_strong.zeta / zeta, 1.0, 0.02);
  EXPECT_NEAR(e_weak.zeta / zeta, 1.0, 0.1);
}

// The paper's numerical example (Table 1), 10 kHz, 1 s, SNR 20 dB, 20 seeds: the acceptance numbers
// of the issue. Median |zeta error| of the default (ml) method <= 0.30 / 0.45 / 0.60 %; median
// |f error| <= 0.02 %; the 95 % interval covers the truth in 85-99 % of the cases. The last check
// pools the three modes and 40 seeds (120 intervals) so that the 99 % upper limit is testable.
TEST(PaperTable1, ReproducesAccuracyTargets) {
  const double fs = 10000.0;
  const auto truth = paper_table1_components();
  const std::array<double, 3> zeta_limit_pct = {0.30, 0.45, 0.60};
  std::array<std::vector<double>, 3> zerr, ferr, zerr_rls, zerr_2p;
  int covered = 0, total = 0;
  ModeSearchOptions opt;
  opt.onset_s = 0.0;
  for (int seed = 1; seed <= 40; ++seed) {
    auto x = damped_sum(truth, fs, 10000);
    add_white_noise(x, 20.0, static_cast<std::uint64_t>(seed));
    const ModeSearchResult r = identify_modes(x, fs, opt);
    ASSERT_EQ(r.modes.size(), 3u) << "seed " << seed;
    for (std::size_t i = 0; i < 3; ++i) {
      const IdentifiedMode* m = match(r, truth[i].f_hz);
      ASSERT_NE(m, nullptr);
      ASSERT_EQ(m->selected.method, DampingMethod::ml);
      ASSERT_EQ(m->selected.status, EstimateStatus::ok) << "seed " << seed << " mode " << i;
      if (seed <= 20) {
        zerr[i].push_back(std::abs(m->ml.zeta / truth[i].zeta - 1) * 100);
        ferr[i].push_back(std::abs(m->ml.f_hz / truth[i].f_hz - 1) * 100);
        zerr_rls[i].push_back(std::abs(m->ridge_ls.zeta / truth[i].zeta - 1) * 100);
        zerr_2p[i].push_back(std::abs(m->two_point.zeta / truth[i].zeta - 1) * 100);
      }
      ++total;
      if (m->ml.zeta_ci95_lo <= truth[i].zeta && truth[i].zeta <= m->ml.zeta_ci95_hi) ++covered;
    }
  }
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_LE(median(zerr[i]), zeta_limit_pct[i]) << "mode " << i;
    EXPECT_LE(median(ferr[i]), 0.02) << "mode " << i;
    // The better estimators must beat the paper's two-point decrement on its own example.
    EXPECT_LT(median(zerr[i]), median(zerr_2p[i])) << "mode " << i;
  }
  // Ridge least squares: the reference numbers are ~0.3 / 1.0 / 0.5 %.
  EXPECT_LE(median(zerr_rls[0]), 0.5);
  EXPECT_LE(median(zerr_rls[1]), 1.2);
  EXPECT_LE(median(zerr_rls[2]), 0.7);
  const double coverage = static_cast<double>(covered) / total;
  EXPECT_GE(coverage, 0.85);
  EXPECT_LE(coverage, 0.99);
}

TEST(PaperTable1, NoiseFreeErrorsBelowFiveHundredthsOfAPercent) {
  const double fs = 10000.0;
  const auto truth = paper_table1_components();
  const auto x = damped_sum(truth, fs, 10000);
  ModeSearchOptions opt;
  const ModeSearchResult r = identify_modes(x, fs, opt);  // automatic onset
  ASSERT_EQ(r.modes.size(), 3u);
  for (const auto& c : truth) {
    const IdentifiedMode* m = match(r, c.f_hz);
    ASSERT_NE(m, nullptr);
    EXPECT_NEAR(m->selected.zeta / c.zeta, 1.0, 5e-4) << c.f_hz;
    EXPECT_NEAR(m->selected.f_hz / c.f_hz, 1.0, 5e-4) << c.f_hz;
  }
}

// The spectral ML fit restricted to a band ignores a strong tone outside it.
TEST(MlFit, BandRestrictionIgnoresOutOfBandHum) {
  const double fs = 10000.0;
  auto x = damped_sum({{1.0, 854.0, 0.024, 0.2}}, fs, 4000);
  for (std::size_t n = 0; n < x.size(); ++n) x[n] += 3.0 * std::sin(2 * kPi * 50.0 * static_cast<double>(n) / fs);
  SpectralModeFitter fitter(x.size(), fs);
  MlFitOptions o;
  o.f_lo_hz = 500;
  o.f_hi_hz = 1300;
  const ModeGuess g{850.0, 0.02};
  const MlFitResult r = fitter.fit(x, std::span<const ModeGuess>(&g, 1), o);
  ASSERT_EQ(r.modes.size(), 1u);
  EXPECT_EQ(r.modes[0].status, EstimateStatus::ok);
  // The hum's leakage into 500-1300 Hz is smooth and absorbed by the residual terms; a few 1e-4
  // remain because the 50 Hz tone is cut off at the record ends.
  EXPECT_NEAR(r.modes[0].zeta / 0.024, 1.0, 2e-3);
  EXPECT_NEAR(r.modes[0].f_hz / 854.0, 1.0, 1e-4);
}

TEST(MlFit, RejectsBadArguments) {
  EXPECT_THROW(SpectralModeFitter(8, 1000.0), std::invalid_argument);
  EXPECT_THROW(SpectralModeFitter(100, 0.0), std::invalid_argument);
  SpectralModeFitter fitter(100, 1000.0);
  std::vector<double> x(100, 0.0), wrong(99, 0.0);
  MlFitOptions o;
  o.f_lo_hz = 100;
  o.f_hi_hz = 400;
  const ModeGuess g{200.0, 0.01};
  EXPECT_THROW(fitter.fit(wrong, std::span<const ModeGuess>(&g, 1), o), std::invalid_argument);
  o.f_hi_hz = 600;  // above Nyquist
  EXPECT_THROW(fitter.fit(x, std::span<const ModeGuess>(&g, 1), o), std::invalid_argument);
}

TEST(Modes, NoModesInPureNoiseAndErrorsOnShortInput) {
  std::vector<double> noise(20000, 0.0);
  std::mt19937_64 rng(11);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (double& v : noise) v = n01(rng);
  ModeSearchOptions opt;
  const ModeSearchResult r = identify_modes(noise, 10000.0, opt);
  for (const auto& m : r.modes) EXPECT_NE(m.selected.status, EstimateStatus::ok) << m.selected.f_hz;
  std::vector<double> tiny(10, 0.0);
  EXPECT_THROW(identify_modes(tiny, 10000.0, opt), std::invalid_argument);
  opt.f_max_hz = 6000;
  EXPECT_THROW(identify_modes(noise, 10000.0, opt), std::invalid_argument);
}

// The fitter's Goertzel bins (few bins of an awkward length) equal the FFT's: a fit on the same data
// by both paths (a narrow band -> Goertzel, a wide one -> FFT; the wide band's extra bins only hold
// noise-free zeros of the residual, so both fits see the same mode) gives the same estimate. Tolerance
// 1e-9 relative: the Goertzel round-off (~M^2 eps, M = N/4) is far below it; the fits themselves are
// converged to 1e-10.
TEST(MlFit, GoertzelBinsMatchTheFft) {
  const double fs = 51200.0;
  const std::size_t n = 1766;  // 2 * 883, the pipeline's full segment at 51.2 kHz
  const auto x = damped_sum({{0.7, 861.3, 0.024, 0.4}}, fs, n);
  SpectralModeFitter fitter(n, fs);
  const ModeGuess g{858.0, 0.02};
  MlFitOptions narrow;  // 7 bins: Goertzel
  narrow.f_lo_hz = 861.3 * 0.88;
  narrow.f_hi_hz = 861.3 * 1.12;
  narrow.residual_terms = 0;
  MlFitOptions wide = narrow;  // 1 kHz / 29 Hz = 34 bins > 2 log2(1766): FFT
  wide.f_lo_hz = 400;
  wide.f_hi_hz = 1400;
  const MlFitResult a = fitter.fit(x, std::span<const ModeGuess>(&g, 1), narrow);
  const MlFitResult b = fitter.fit(x, std::span<const ModeGuess>(&g, 1), wide);
  ASSERT_EQ(a.modes.size(), 1u);
  ASSERT_EQ(b.modes.size(), 1u);
  EXPECT_EQ(a.bins, 7u);
  EXPECT_GT(b.bins, 30u);
  EXPECT_NEAR(a.modes[0].zeta / 0.024, 1.0, 1e-9);
  EXPECT_NEAR(b.modes[0].zeta / 0.024, 1.0, 1e-9);
  EXPECT_NEAR(a.modes[0].f_hz / 861.3, 1.0, 1e-11);
  EXPECT_NEAR(b.modes[0].f_hz / 861.3, 1.0, 1e-11);
}

// A fitter told that its fits use few bins (max_bins) makes no FFT plan: a narrow fit gives exactly the
// same result as the default fitter's (both take the Goertzel path), and a wide fit beyond max_bins
// still works, through the Goertzel bins, and agrees with the FFT path to the tolerance argued above.
TEST(MlFit, FitterWithoutFftPlanUsesGoertzelForEveryBand) {
  const double fs = 51200.0;
  const std::size_t n = 1766;
  const auto x = damped_sum({{0.7, 861.3, 0.024, 0.4}}, fs, n);
  SpectralModeFitter with_fft(n, fs);
  SpectralModeFitter goertzel_only(n, fs, 8);  // 8 <= 2 log2(1766) = 21.6: no plan
  const ModeGuess g{858.0, 0.02};
  MlFitOptions narrow;
  narrow.f_lo_hz = 861.3 * 0.88;
  narrow.f_hi_hz = 861.3 * 1.12;
  narrow.residual_terms = 0;
  MlFitOptions wide = narrow;
  wide.f_lo_hz = 400;
  wide.f_hi_hz = 1400;
  const MlFitResult a = with_fft.fit(x, std::span<const ModeGuess>(&g, 1), narrow);
  const MlFitResult b = goertzel_only.fit(x, std::span<const ModeGuess>(&g, 1), narrow);
  ASSERT_EQ(a.modes.size(), 1u);
  ASSERT_EQ(b.modes.size(), 1u);
  EXPECT_EQ(a.modes[0].zeta, b.modes[0].zeta);
  EXPECT_EQ(a.modes[0].f_hz, b.modes[0].f_hz);
  const MlFitResult c = with_fft.fit(x, std::span<const ModeGuess>(&g, 1), wide);
  const MlFitResult d = goertzel_only.fit(x, std::span<const ModeGuess>(&g, 1), wide);
  ASSERT_EQ(d.modes.size(), 1u);
  EXPECT_EQ(d.bins, c.bins);
  EXPECT_EQ(d.modes[0].status, EstimateStatus::ok);
  EXPECT_NEAR(d.modes[0].zeta / c.modes[0].zeta, 1.0, 1e-9);
  EXPECT_NEAR(d.modes[0].f_hz / c.modes[0].f_hz, 1.0, 1e-11);
}

// select_kth against std::nth_element (the reference it replaces in the impact analyzer): the same
// value exactly (an order statistic is an element of the input, so there is no rounding), on random
// rows, rows with ties, monotone rows (the decaying-envelope case its pivot rule is chosen for), and
// every rank of short arrays (the insertion-sort tail).
TEST(SelectKth, EqualsNthElement) {
  std::mt19937 rng(7);
  std::exponential_distribution<double> expo(1.0);
  std::uniform_int_distribution<int> small(0, 3);
  auto check = [](const std::vector<double>& v, std::size_t k) {
    std::vector<double> ref = v, a = v, b(v.size());
    std::nth_element(ref.begin(), ref.begin() + static_cast<std::ptrdiff_t>(k), ref.end());
    EXPECT_EQ(select_kth(a.data(), b.data(), v.size(), k), ref[k]) << "n " << v.size() << " k " << k;
  };
  for (std::size_t n : {1, 2, 3, 7, 8, 9, 16, 63, 64, 65, 200}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<double> random(n), ties(n), decay(n);
      for (std::size_t i = 0; i < n; ++i) {
        random[i] = expo(rng);
        ties[i] = static_cast<double>(small(rng));
        decay[i] = i < n / 10 ? 1e-3 * expo(rng) : std::exp(-0.1 * static_cast<double>(i)) + 1e-3 * expo(rng);
      }
      std::vector<double> rising = random;
      std::sort(rising.begin(), rising.end());
      for (std::size_t k : {std::size_t{0}, n / 2, n - 1, static_cast<std::size_t>(trial) % n}) {
        check(random, k);
        check(ties, k);
        check(decay, k);
        check(rising, k);
        check(std::vector<double>(rising.rbegin(), rising.rend()), k);
      }
    }
  }
}

// phase_angle against std::arg (atan2, correctly rounded in glibc): within 2 ulp of the angle on the
// series' range (the division and the Horner steps each round once; the omitted terms are below
// 3e-18 relative), and the same value as std::arg off that range, at every quadrant and at the
// range's boundary.
TEST(PhaseAngle, MatchesArg) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> angle(-0.13, 0.13), radius(1e-6, 1e3), any(-kPi, kPi);
  for (int i = 0; i < 20000; ++i) {
    const double a = i % 4 == 0 ? any(rng) : angle(rng);
    const std::complex<double> z = std::polar(radius(rng), a);
    const double ref = std::arg(z), got = phase_angle(z);
    EXPECT_LE(std::abs(got - ref), 2.0 * std::numeric_limits<double>::epsilon() * std::abs(ref))
        << "z = " << z.real() << " + " << z.imag() << " i";
  }
  for (double im : {0.125, -0.125, 0.1250000001, 0.0, -0.0}) {
    const std::complex<double> z(1.0, im);
    EXPECT_NEAR(phase_angle(z), std::arg(z), 2.0 * std::numeric_limits<double>::epsilon() * std::abs(std::arg(z)));
  }
  EXPECT_EQ(phase_angle({-1.0, 0.01}), std::arg(std::complex<double>(-1.0, 0.01)));
  EXPECT_EQ(phase_angle({0.0, 1.0}), std::arg(std::complex<double>(0.0, 1.0)));
}

// The ridge-LS standard uncertainty against a direct evaluation of its definition: the sandwich
// (X^T W X)^-1 X^T W^1/2 R W^1/2 X (X^T W X)^-1 with R_ij = exp(-(t_i - t_j)^2 / (4 s^2)) summed over
// all pairs (no lag cut-off, rho by exp per pair), on a noisy row. The estimator's cut at 6
// correlation lengths drops terms below 2e-16 of the diagonal; the rest is summation order, so the two
// agree to 1e-11.
TEST(RidgeLs, StandardUncertaintyEqualsDirectSandwich) {
  const double fs = 10000.0, f = 700.0, zeta = 0.01;
  auto x = damped_sum({{1.0, f, zeta, 0.3}}, fs, 6000);
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 1e-3);
  for (double& v : x) v += noise(rng);
  double dt = 0.0;
  const auto w = single_row(x, fs, f, dt);
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.frequencies_hz = {f};
  cfg.max_samples = x.size();
  const double noise_power = MorletCwt<double>(cfg).noise_gain(f) * 1e-6;
  const EnvelopeRow row{w, dt, f, 7.0, noise_power};
  const EnvelopeWindow win = choose_window(row, EnvelopeOptions{});
  const DampingEstimate e = estimate_ridge_ls(row, win, f);
  ASSERT_EQ(e.status, EstimateStatus::ok);
  ASSERT_GT(win.end - win.start, 100u);

  const double s = 7.0 / (2 * kPi * f);
  const auto stride = std::max<std::size_t>(1, static_cast<std::size_t>(s / (8.0 * dt)));
  std::vector<double> t, wt, y;
  for (std::size_t c = win.start; c < win.end; c += stride) {
    const double p = std::max(std::norm(w[c]) - noise_power, 0.25 * std::norm(w[c]));
    t.push_back(static_cast<double>(c) * dt);
    wt.push_back(2.0 * p / noise_power);
    y.push_back(0.5 * std::log(p));
  }
  double s0 = 0, s1 = 0, s2 = 0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    s0 += wt[i];
    s1 += wt[i] * (t[i] - t[0]);
    s2 += wt[i] * (t[i] - t[0]) * (t[i] - t[0]);
  }
  double m00 = 0, m01 = 0, m11 = 0;
  for (std::size_t i = 0; i < t.size(); ++i)
    for (std::size_t j = 0; j < t.size(); ++j) {
      const double d = (t[i] - t[j]) / (2.0 * s);
      const double r = std::sqrt(wt[i] * wt[j]) * std::exp(-d * d);
      const double ti = t[i] - t[0], tj = t[j] - t[0];
      m00 += r;
      m01 += r * ti;
      m11 += r * ti * tj;
    }
  const double det = s0 * s2 - s1 * s1;
  const double b10 = -s1 / det, b11 = s0 / det;
  const double slope_sd = std::sqrt(b10 * b10 * m00 + 2.0 * b10 * b11 * m01 + b11 * b11 * m11);
  const double omega = 2 * kPi * f, sigma = decay_from_zeta(e.zeta, omega);
  const double zeta_sd = omega * omega / std::pow(omega * omega + sigma * sigma, 1.5) * slope_sd;
  EXPECT_NEAR(e.zeta_sd / zeta_sd, 1.0, 1e-11);
}

namespace {

// A noisy decaying row (as in the direct-sandwich test) with its noise power.
struct NoisyRow {
  std::vector<std::complex<double>> w;
  double dt = 0.0, noise_power = 0.0;
};

NoisyRow noisy_row(double fs, double f, double zeta, double noise_sd, unsigned seed) {
  auto x = damped_sum({{1.0, f, zeta, 0.3}}, fs, 6000);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_sd);
  for (double& v : x) v += noise(rng);
  NoisyRow r;
  r.w = single_row(x, fs, f, r.dt);
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = fs;
  cfg.frequencies_hz = {f};
  cfg.max_samples = x.size();
  r.noise_power = MorletCwt<double>(cfg).noise_gain(f) * noise_sd * noise_sd;
  return r;
}

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

void expect_same_estimate(const DampingEstimate& a, const DampingEstimate& b) {
  EXPECT_EQ(a.status, b.status);
  EXPECT_EQ(a.points, b.points);
  EXPECT_TRUE(same_bits(a.zeta, b.zeta)) << a.zeta << " vs " << b.zeta;
  EXPECT_TRUE(same_bits(a.zeta_sd, b.zeta_sd)) << a.zeta_sd << " vs " << b.zeta_sd;
  EXPECT_TRUE(same_bits(a.zeta_ci95_lo, b.zeta_ci95_lo));
  EXPECT_TRUE(same_bits(a.zeta_ci95_hi, b.zeta_ci95_hi));
  EXPECT_TRUE(same_bits(a.amplitude, b.amplitude));
  EXPECT_TRUE(same_bits(a.snr_db, b.snr_db));
}

}  // namespace

// The line fits take their weights from the caller (EnvelopeFitWeights; nothing is kept between
// calls): weights computed once and passed to both fits of a row (the analyzer's phase slope and ridge
// LS when the stride is 1), and weights and workspace objects reused after fits on another row, must
// give the bits of fits that compute their own; weights of another window or stride are refused.
TEST(EnvelopeFitWeights, SharedAndReusedWeightsGiveTheBitsOfOwnWeights) {
  const double fs = 10000.0, f = 700.0;
  NoisyRow nr = noisy_row(fs, f, 0.01, 1e-3, 5);
  EnvelopeRow row{nr.w, nr.dt, f, 7.0, nr.noise_power};
  const EnvelopeWindow win = choose_window(row, EnvelopeOptions{});
  ASSERT_EQ(win.status, EstimateStatus::ok);
  ASSERT_GT(win.end - win.start, 50u);
  // The same samples on a coarser column grid: ridge LS then uses every column (stride 1) like the
  // phase slope, and one set of weights serves both.
  EnvelopeRow coarse = row;
  coarse.time_step_s = 7.0 / (2.0 * std::numbers::pi * f) / 12.0;  // 12 columns per kernel sd
  ASSERT_EQ(ridge_ls_stride(coarse), kPhaseSlopeStride);

  EnvelopeWorkspace ws;
  EnvelopeFitWeights fw;
  {  // leave the objects filled from another row, noise and kernel width
    EnvelopeRow other = row;
    other.eta0 = 6.0;
    EnvelopeWindow w2 = win;
    w2.noise_power *= 2.0;
    envelope_fit_weights(other, w2, kPhaseSlopeStride, fw, ws);
    double sd = NAN;
    phase_slope_frequency(other, w2, sd, fw, ws);
  }
  for (const EnvelopeRow* r : {&row, &coarse}) {
    double sd = NAN, sd_ref = NAN;
    envelope_fit_weights(*r, win, kPhaseSlopeStride, fw, ws);
    const double fd = phase_slope_frequency(*r, win, sd, fw, ws);
    const double fd_ref = phase_slope_frequency(*r, win, sd_ref);
    EXPECT_TRUE(same_bits(fd, fd_ref)) << fd << " vs " << fd_ref;
    EXPECT_TRUE(same_bits(sd, sd_ref)) << sd << " vs " << sd_ref;
    EXPECT_TRUE(std::isfinite(sd) && sd > 0);
    const std::size_t stride = ridge_ls_stride(*r);
    if (stride != kPhaseSlopeStride) {
      EXPECT_THROW(estimate_ridge_ls(*r, win, f, fw, ws), std::invalid_argument);
      envelope_fit_weights(*r, win, stride, fw, ws);
    }
    const DampingEstimate e = estimate_ridge_ls(*r, win, f, fw, ws);
    ASSERT_EQ(e.status, EstimateStatus::ok);
    expect_same_estimate(e, estimate_ridge_ls(*r, win, f));
  }
  // Weights of another window.
  EnvelopeWindow shifted = win;
  shifted.start += 1;
  EXPECT_THROW(estimate_ridge_ls(coarse, shifted, f, fw, ws), std::invalid_argument);
}

namespace {

struct PhaseFit {
  double f_hz = NAN, sd_hz = NAN;
  double sd_hz_meat = NAN;   ///< sd_hz from the three meat correlations (the estimator's form before)
  double sd_hz_exact = NAN;  ///< sd_hz in long double from the same weights, times and rho
};

// The phase-slope fit evaluated the slow way in the estimator's summation order: column by column
// the unwrapped phase (the advance phase_angle(w_c conj(w_{c-1}) derotate) + advance added to a
// running sum), the weights and the sums, rho by its recurrence, the slope variance one lag at a time
// (sum_i z_i z_{i+k}, z_i = sqrt(w_i) (s0 t_i - s1)) with the even and odd points summed separately
// and added (the SSE2 lanes), then the last point of a lag with an odd number of them. The
// estimator's advances two columns at a time and its passes over several lags at once must give
// these bits. Also the same variance from the meat's three correlations [1, t, t^2] and the bread, the
// form the estimator used before (summed the same way): the two differ by rounding only.
PhaseFit phase_fit_in_summation_order(const EnvelopeRow& row, const EnvelopeWindow& win) {
  const double dt = row.time_step_s, noise = win.noise_power;
  const double kernel_sd = row.eta0 / (2.0 * kPi * row.f_row_hz);
  const double advance = 2.0 * kPi * row.phase_reference_hz * dt;
  const std::complex<double> derotate = std::polar(1.0, -advance);
  const std::size_t count = win.end - win.start;
  std::vector<double> u(count), v(count), t(count);
  double s0 = 0, s1 = 0, s2 = 0, sy = 0, sty = 0, phase = 0.0;
  const double t_ref = static_cast<double>(win.start) * dt;
  for (std::size_t i = 0; i < count; ++i) {
    const std::size_t c = win.start + i;
    if (i > 0) phase += phase_angle(row.w[c] * std::conj(row.w[c - 1]) * derotate) + advance;
    const double p = std::max(std::norm(row.w[c]) - noise, 0.25 * std::norm(row.w[c]));
    const double w = 2.0 * p / noise;
    t[i] = static_cast<double>(c) * dt - t_ref;
    u[i] = std::sqrt(w);
    v[i] = u[i] * t[i];
    s0 += w;
    s1 += w * t[i];
    s2 += w * t[i] * t[i];
    sy += w * phase;
    sty += w * t[i] * phase;
  }
  const double det = s0 * s2 - s1 * s1;
  const double lag_step = dt / (2.0 * kernel_sd);
  const std::size_t reach = std::min<std::size_t>(count - 1, static_cast<std::size_t>(std::ceil(6.0 / lag_step)));
  const double l2 = lag_step * lag_step, q_step = std::exp(-2.0 * l2);
  double r = 1.0, q = std::exp(-l2);
  std::vector<double> z(count);
  for (std::size_t i = 0; i < count; ++i) z[i] = u[i] * (s0 * t[i] - s1);
  double m00 = 0, m01 = 0, m11 = 0, zz = 0;
  long double exact = 0;
  for (std::size_t k = 0; k <= reach; ++k) {
    const double rho = r * (k == 0 ? 1.0 : 2.0);
    r *= q;
    q *= q_step;
    const std::size_t len = count - k;
    double lanes[2] = {0, 0};
    std::size_t n = 0;
    for (; n + 2 <= len; n += 2)
      for (std::size_t lane = 0; lane < 2; ++lane) lanes[lane] += z[n + lane] * z[n + lane + k];
    double sz = lanes[0] + lanes[1];
    if (n < len) sz += z[n] * z[n + k];
    zz += rho * sz;
    long double exact_k = 0;
    for (std::size_t i = 0; i < len; ++i)
      exact_k += static_cast<long double>(u[i]) * ((static_cast<long double>(s0) * t[i]) - s1) *
                 static_cast<long double>(u[i + k]) * ((static_cast<long double>(s0) * t[i + k]) - s1);
    exact += rho * exact_k;
    double a[2] = {0, 0}, b[2] = {0, 0}, c[2] = {0, 0};
    std::size_t i = 0;
    for (; i + 2 <= len; i += 2)
      for (std::size_t lane = 0; lane < 2; ++lane) {
        const std::size_t j = i + lane;
        a[lane] += u[j] * u[j + k];
        b[lane] += v[j] * u[j + k] + u[j] * v[j + k];
        c[lane] += v[j] * v[j + k];
      }
    double sa = a[0] + a[1], sb = b[0] + b[1], sc = c[0] + c[1];
    if (i < len) {
      sa += u[i] * u[i + k];
      sb += v[i] * u[i + k] + u[i] * v[i + k];
      sc += v[i] * v[i + k];
    }
    m00 += rho * sa;
    m01 += 0.5 * rho * sb;
    m11 += rho * sc;
  }
  const double b10 = -s1 / det, b11 = s0 / det;
  const double var_meat = b10 * b10 * m00 + 2.0 * b10 * b11 * m01 + b11 * b11 * m11;
  const double var = zz / det / det;
  const long double det_exact = static_cast<long double>(s0) * s2 - static_cast<long double>(s1) * s1;
  return {(s0 * sty - s1 * sy) / det / (2.0 * kPi), std::sqrt(std::max(var, 0.0)) / (2.0 * kPi),
          std::sqrt(std::max(var_meat, 0.0)) / (2.0 * kPi),
          static_cast<double>(std::sqrt(exact) / det_exact / (2.0L * std::numbers::pi_v<long double>))};
}

}  // namespace

// The slope variance's passes over four lags at once against one lag at a time, bit for bit: windows
// of 3 to 70 points (odd and even point counts), reaches cut by the window (reach = count - 1) or by
// the 6 correlation lengths, with every remainder of the lag count modulo 4. Against a long double
// evaluation from the same weights, times and rho: within 2e-15; the meat's three correlations (the
// form before, whose combination cancels) were within 1.1e-14 of it (rw60.wav with method ridge-ls:
// f_sd_hz moved by at most 1.9e-15, zeta_ci95 by 2.8e-16, relative).
TEST(EnvelopeLineFit, SlopeVarianceOverFourLagsEqualsLagByLagBitForBit) {
  const double fs = 10000.0, f = 700.0;
  const NoisyRow nr = noisy_row(fs, f, 0.01, 1e-3, 9);
  ASSERT_GT(nr.w.size(), 400u);
  int lags_mod4[4] = {0, 0, 0, 0}, cut_by_window = 0;
  double worst_vs_meat = 0.0, worst_vs_exact = 0.0;
  // Time steps (the row's samples stand for any grid here) for lag steps dt / (2 s) that reach
  // 27 (the analyzer's), 20, 40 and 14 lags.
  for (const double lag_step : {0.2266, 0.3, 0.15, 0.45}) {
    const double dt = lag_step * 2.0 * 7.0 / (2.0 * kPi * f);
    const EnvelopeRow row{nr.w, dt, f, 7.0, nr.noise_power};
    for (std::size_t count = 3; count <= 70; ++count) {
      const EnvelopeWindow win{300, 300 + count, 300, nr.noise_power, EstimateStatus::ok};
      double sd = NAN;
      phase_slope_frequency(row, win, sd);
      const PhaseFit ref = phase_fit_in_summation_order(row, win);
      ASSERT_TRUE(std::isfinite(ref.sd_hz) && ref.sd_hz > 0);
      EXPECT_TRUE(same_bits(sd, ref.sd_hz)) << "lag step " << lag_step << " count " << count << ": " << sd << " vs " << ref.sd_hz;
      worst_vs_meat = std::max(worst_vs_meat, std::abs(sd / ref.sd_hz_meat - 1.0));
      worst_vs_exact = std::max(worst_vs_exact, std::abs(sd / ref.sd_hz_exact - 1.0));
      const std::size_t reach = std::min<std::size_t>(count - 1, static_cast<std::size_t>(std::ceil(6.0 / lag_step)));
      lags_mod4[(reach + 1) % 4] += 1;
      cut_by_window += reach == count - 1;
    }
  }
  for (int m = 0; m < 4; ++m) EXPECT_GT(lags_mod4[m], 10) << "lag counts = " << m << " mod 4";
  EXPECT_GT(cut_by_window, 20);
  EXPECT_LT(cut_by_window, 4 * 68 - 20);
  EXPECT_LT(worst_vs_exact, 2e-15);  // measured 6.7e-16 (the three-correlation form: 1.1e-14)
  EXPECT_LT(worst_vs_meat, 2e-14);
  EXPECT_GT(worst_vs_meat, 0.0);  // the forms do round differently
}

// The phase advances two columns at a time (SSE2 lanes, phase_angle's series when both lie in its
// range, else the scalar expression) against the column-by-column fit, bit for bit: a row near the
// mode (every advance in the series' range) and noise-dominated rows with advances out of it, with
// and without a phase reference (derotation), windows of odd and even length.
TEST(PhaseSlope, AdvancesInPairsEqualColumnByColumnBitForBit) {
  const double fs = 10000.0, f = 700.0;
  const NoisyRow clean = noisy_row(fs, f, 0.01, 1e-4, 21);
  const NoisyRow noisy = noisy_row(fs, f, 0.01, 0.3, 22);
  int in_range = 0, out_of_range = 0;
  for (const NoisyRow* nr : {&clean, &noisy}) {
    for (const double reference : {0.0, 690.0}) {
      for (const double dt_scale : {1.0, 9.0}) {  // every column, or a coarser grid (larger advances)
        EnvelopeRow row{nr->w, nr->dt, f, 7.0, nr->noise_power};
        row.phase_reference_hz = reference;
        std::vector<std::complex<double>> coarse;
        if (dt_scale > 1.0) {
          for (std::size_t c = 0; c < nr->w.size(); c += 9) coarse.push_back(nr->w[c]);
          row.w = coarse;
          row.time_step_s = nr->dt * dt_scale;
        }
        const double advance = 2.0 * kPi * reference * row.time_step_s;
        for (const std::size_t start : {std::size_t{20}, std::size_t{33}}) {
          for (std::size_t count = 3; count <= 64 && start + count <= row.w.size(); count += 1) {
            const EnvelopeWindow win{start, start + count, start, nr->noise_power, EstimateStatus::ok};
            double sd = NAN;
            const double got = phase_slope_frequency(row, win, sd);
            const PhaseFit ref = phase_fit_in_summation_order(row, win);
            ASSERT_TRUE(same_bits(got, ref.f_hz))
                << "reference " << reference << " dt x" << dt_scale << " start " << start << " count " << count
                << ": " << got << " vs " << ref.f_hz;
            ASSERT_TRUE(same_bits(sd, ref.sd_hz));
          }
        }
        for (std::size_t c = 21; c < std::min<std::size_t>(row.w.size(), 97); ++c) {
          const std::complex<double> z = row.w[c] * std::conj(row.w[c - 1]) * std::polar(1.0, -advance);
          (z.real() > 0 && std::abs(z.imag()) <= 0.125 * z.real() ? in_range : out_of_range) += 1;
        }
      }
    }
  }
  EXPECT_GT(in_range, 100);
  EXPECT_GT(out_of_range, 50);

  // Zero columns (a transform of a silent stretch): arg 0 = 0, where the series would give 0 / 0.
  std::vector<std::complex<double>> w = clean.w;
  for (std::size_t c = 40; c < 46; ++c) w[c] = 0.0;
  const EnvelopeRow row{w, clean.dt, f, 7.0, clean.noise_power};
  for (std::size_t count = 20; count <= 40; ++count) {
    const EnvelopeWindow win{30, 30 + count, 30, clean.noise_power, EstimateStatus::ok};
    double sd = NAN;
    const double got = phase_slope_frequency(row, win, sd);
    EXPECT_TRUE(std::isfinite(got));
    EXPECT_TRUE(same_bits(got, phase_fit_in_summation_order(row, win).f_hz)) << "count " << count;
  }
}

namespace {

// choose_window as it was before its peak scan kept the running maximum as a value: the norm at the
// running peak recomputed for every column (the row's noise power given).
EnvelopeWindow choose_window_recomputing_norms(const EnvelopeRow& row, const EnvelopeOptions& options) {
  EnvelopeWindow win;
  const std::size_t n = row.w.size();
  const double dt = row.time_step_s;
  const double s = row.eta0 / (2.0 * kPi * row.f_row_hz);
  const auto edge = static_cast<std::size_t>(std::ceil(options.edge_widths * s / dt));
  const auto onset = static_cast<std::size_t>(std::max(0.0, std::round(options.onset_s / dt)));
  win.noise_power = row.noise_power;
  if (n < 2 * edge + 3 || onset >= n - edge) {
    win.status = EstimateStatus::too_short;
    return win;
  }
  const std::size_t last = n - edge;
  win.peak = onset;
  for (std::size_t c = onset; c < last; ++c)
    if (std::norm(row.w[c]) > std::norm(row.w[win.peak])) win.peak = c;
  const auto after_peak = static_cast<std::size_t>(std::ceil(2.0 * s / dt));
  win.start = std::max(onset + edge, win.peak + after_peak);
  if (win.start >= last) {
    win.status = EstimateStatus::too_short;
    win.end = win.start;
    return win;
  }
  const double threshold = options.end_snr * win.noise_power;
  win.end = win.start;
  while (win.end < last && std::norm(row.w[win.end]) >= threshold) ++win.end;
  if (std::norm(row.w[win.peak]) < 4.0 * threshold) {
    win.status = EstimateStatus::low_snr;
  } else if (static_cast<double>(win.end - win.start) * dt < options.min_window_widths * s) {
    win.status = EstimateStatus::too_short;
  }
  return win;
}

}  // namespace

// The peak scan with the running maximum as a value against the norm recomputed at the running peak:
// random rows with exact ties (the first maximum wins), NaN columns (ignored) and a NaN at the onset
// (no column compares greater, the peak stays there), decaying rows, several onsets.
TEST(ChooseWindow, PeakScanEqualsRecomputedNorms) {
  std::mt19937 rng(17);
  std::uniform_int_distribution<int> level(0, 6), kind(0, 9);
  int ties = 0, nan_onsets = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::vector<std::complex<double>> w(40 + trial % 90);
    for (std::size_t c = 0; c < w.size(); ++c) {
      const double a = level(rng) * std::exp(-0.02 * static_cast<double>(c) * (trial % 3));
      const int k = kind(rng);
      w[c] = k < 4 ? std::complex<double>(a, 0.0) : k < 8 ? std::complex<double>(0.0, -a) : std::complex<double>(a, a);
      if (trial % 7 == 0 && k == 9 && c % 5 == 0) w[c] = {NAN, 0.0};
    }
    EnvelopeOptions opt;
    opt.onset_s = 0.001 * (trial % 11);
    const EnvelopeRow row{w, 0.001, 500.0, 7.0, 0.5 + 0.1 * (trial % 13)};
    const auto onset = static_cast<std::size_t>(std::round(opt.onset_s / row.time_step_s));
    if (trial % 29 == 0 && onset < w.size()) {
      w[onset] = {NAN, NAN};
      ++nan_onsets;
    }
    const EnvelopeWindow got = choose_window(row, opt);
    const EnvelopeWindow ref = choose_window_recomputing_norms(row, opt);
    ASSERT_EQ(got.peak, ref.peak) << "trial " << trial;
    ASSERT_EQ(got.start, ref.start) << "trial " << trial;
    ASSERT_EQ(got.end, ref.end) << "trial " << trial;
    ASSERT_EQ(got.status, ref.status) << "trial " << trial;
    for (std::size_t c = ref.peak + 1; c < w.size(); ++c) ties += std::norm(w[c]) == std::norm(w[ref.peak]);
  }
  EXPECT_GT(ties, 1000);
  EXPECT_GT(nan_onsets, 50);
}
