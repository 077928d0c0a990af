// Mode identification on signals ridgewatch did not make (tests/support/indep_signals.hpp: closed-form
// decays with viscous, dry-friction and quadratic envelopes) and on the paper's Table-1 signal:
// detection independent of the band and of eta0, statuses that keep their promise, backbones that
// see amplitude-dependent damping with the right sign and do not see it where there is none.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/dsp/modes.hpp"
#include "core/dsp/synthetic.hpp"
#include "support/indep_signals.hpp"

using namespace ridgewatch::dsp;

namespace {

#ifdef RIDGEWATCH_SANITIZED
constexpr int kSeeds = 2;  // sanitizer builds: a representative subset
#else
constexpr int kSeeds = 6;
#endif

std::vector<double> decay_signal(const std::vector<indep::Mode>& modes, double fs, double seconds, double noise_sd,
                                 std::uint64_t seed) {
  std::vector<double> x(static_cast<std::size_t>(seconds * fs), 0.0);
  for (const auto& m : modes) indep::add_decay(x, fs, 0.0, m);
  indep::Rng rng(seed);
  for (double& v : x) v += noise_sd * rng.gauss();
  return x;
}

const IdentifiedMode* nearest(const ModeSearchResult& r, double f_hz) {
  const IdentifiedMode* best = nullptr;
  for (const auto& m : r.modes)
    if (!best || std::abs(m.selected.f_hz - f_hz) < std::abs(best->selected.f_hz - f_hz)) best = &m;
  return best;
}

}  // namespace

// A single mode with dry friction (dA/dt = -aA - b): zeta_eq = (a + b/A) / (2 pi f) rises as A falls,
// so the backbone's slope against A is negative and the Coulomb law fits. Quadratic damping
// (dA/dt = -aA - cA^2) the other way round. 48 kHz, physical units (amplitude 50, far above 1).
TEST(ModesBackbone, FrictionAndQuadraticDecaysAreFlaggedWithTheRightSlope) {
  const double fs = 48000.0;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    indep::Mode coulomb;
    coulomb.f_hz = 1000.0;
    coulomb.zeta = 0.002;    // a = 12.6 /s
    coulomb.amplitude = 50.0;
    coulomb.coulomb = 100.0;  // b / A = 2 /s at A = 50, 40 /s at A = 2.5: zeta_eq 0.0023 -> 0.0084
    coulomb.phase_rad = 0.3 * seed;
    const auto x = decay_signal({coulomb}, fs, 0.5, 0.01, static_cast<std::uint64_t>(seed));
    ModeSearchOptions opt;
    opt.onset_s = 0.0;
    const ModeSearchResult r = identify_modes(x, fs, opt);
    const IdentifiedMode* m = nearest(r, 1000.0);
    ASSERT_NE(m, nullptr);
    ASSERT_TRUE(m->backbone.tested) << seed;
    EXPECT_TRUE(m->backbone.amplitude_dependent) << seed << " z " << m->backbone.slope_z;
    EXPECT_LT(m->backbone.slope_z, 0.0) << seed;
    EXPECT_EQ(m->backbone.law, BackboneLaw::coulomb) << seed;
    // The backbone's points follow the closed-form zeta_eq(A) to 10 % (segment averages over a
    // curved envelope and the noise at the lowest amplitudes).
    for (const auto& p : m->backbone.points) {
      if (std::isfinite(p.zeta) && p.amplitude > 2.0) {
        EXPECT_NEAR(p.zeta / coulomb.zeta_at(p.amplitude), 1.0, 0.10) << "A " << p.amplitude;
      }
    }

    indep::Mode quad;
    quad.f_hz = 1500.0;
    quad.zeta = 0.002;
    quad.amplitude = 50.0;
    quad.quadratic = 1.0;  // cA = 50 /s at A = 50, 1 /s at A = 1: zeta_eq 0.0073 -> 0.0021
    quad.phase_rad = 0.7 * seed;
    const auto y = decay_signal({quad}, fs, 0.5, 0.01, static_cast<std::uint64_t>(100 + seed));
    const ModeSearchResult q = identify_modes(y, fs, opt);
    const IdentifiedMode* mq = nearest(q, 1500.0);
    ASSERT_NE(mq, nullptr);
    ASSERT_TRUE(mq->backbone.tested) << seed;
    EXPECT_TRUE(mq->backbone.amplitude_dependent) << seed << " z " << mq->backbone.slope_z;
    EXPECT_GT(mq->backbone.slope_z, 0.0) << seed;
    EXPECT_EQ(mq->backbone.law, BackboneLaw::linear) << seed;
    EXPECT_GT(mq->backbone.b, 0.0);
  }
}

// Table 1 at 20 dB: viscous modes; the constancy test flags none of them (the bench measures 0 of
// 114 over 40 seeds; here a few seeds, where a single flag would already exceed the 5 % target).
TEST(ModesBackbone, ViscousTable1ModesAreNotFlagged) {
  int tested = 0, flagged = 0;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    auto x = damped_sum(paper_table1_components(), 10000.0, 10000);
    add_white_noise(x, 20.0, static_cast<std::uint64_t>(500 + seed));
    ModeSearchOptions opt;
    opt.onset_s = 0.0;
    for (const auto& m : identify_modes(x, 10000.0, opt).modes) {
      tested += m.backbone.tested;
      flagged += m.backbone.tested && m.backbone.amplitude_dependent;
    }
  }
  EXPECT_GE(tested, 2 * kSeeds);  // at least the two longer decays (250 and 1250 Hz) per file
  EXPECT_EQ(flagged, 0);
}

// Table 1 at 20 dB with the bands of the issue: the same three modes in every band, zeta within its
// 95 % interval widened by 3x (a single realisation may fall outside its 95 % interval 5 % of the
// time; 3x the half-width is a > 5 sigma bound), f to 0.1 %.
TEST(ModesDetection, Table1ModesDoNotDependOnTheBandOrEta0) {
  const auto truth = paper_table1_components();
  struct Case {
    double lo, hi, eta0;
  };
  const Case cases[] = {{0, 0, 0}, {100, 2000, 0}, {0, 3000, 0}, {200, 1400, 0}, {0, 0, 5}, {0, 0, 12}};
  for (int seed = 1; seed <= std::min(kSeeds, 3); ++seed) {
    auto x = damped_sum(truth, 10000.0, 10000);
    add_white_noise(x, 20.0, static_cast<std::uint64_t>(seed));
    for (const Case& c : cases) {
      ModeSearchOptions opt;
      opt.onset_s = 0.0;
      opt.f_min_hz = c.lo;
      opt.f_max_hz = c.hi;
      opt.eta0 = c.eta0;
      const ModeSearchResult r = identify_modes(x, 10000.0, opt);
      ASSERT_EQ(r.modes.size(), 3u) << seed << " band " << c.lo << "-" << c.hi << " eta0 " << c.eta0;
      for (std::size_t i = 0; i < 3; ++i) {
        const auto& e = r.modes[i].ml;
        EXPECT_EQ(e.status, EstimateStatus::ok) << seed << " " << truth[i].f_hz << " " << r.modes[i].note;
        EXPECT_NEAR(e.f_hz / truth[i].f_hz, 1.0, 1e-3);
        const double half = 3.0 * 0.5 * (e.zeta_ci95_hi - e.zeta_ci95_lo);
        EXPECT_NEAR(e.zeta, truth[i].zeta, half) << seed << " " << truth[i].f_hz;
      }
      // The reported noise is the noise: SNR 20 dB over the record of the Table-1 sum.
      double ps = 0;
      for (double v : damped_sum(truth, 10000.0, 10000)) ps += v * v / 10000.0;
      EXPECT_NEAR(r.noise_sd / std::sqrt(ps / 100.0), 1.0, 0.1);  // floor estimate: +-10 %
    }
  }
}

// Random multi-mode signals from the independent generator (1-5 modes 1.3-1.9x apart, zeta log-uniform
// in 1e-4..0.01 and clamped so that every decay lasts 10 ms..0.3 s, amplitudes 50-300 in physical
// units, a strong mode at 10 kHz above the band of interest): every mode inside the band is found, and
// an `ok` zeta agrees with the truth within 3x its interval. 44.1 / 48 kHz.
// Not covered here (measured limits, see README): weak, heavily damped modes (zeta > 0.01) next to a
// much stronger neighbour can be missed.
TEST(ModesDetection, RandomMultiModeSignalsAreFoundInAnyBandContainingThem) {
  indep::Rng rng(2024);
  int checked = 0;
  for (int trial = 0; trial < 2 * kSeeds; ++trial) {
    const double fs = trial % 2 ? 44100.0 : 48000.0;
    const int k = 1 + static_cast<int>(rng.uniform() * 5.0);
    std::vector<indep::Mode> modes;
    double f = rng.uniform(300.0, 600.0);
    for (int i = 0; i < k; ++i) {
      indep::Mode m;
      m.f_hz = f;
      // zeta log-uniform in [1e-4, 0.05], but the decay must last at least 40 ms and at most the record
      m.zeta = std::exp(rng.uniform(std::log(1e-4), std::log(0.01)));
      m.zeta = std::clamp(m.zeta, 1.0 / (indep::kTwoPi * f * 0.3), 1.0 / (indep::kTwoPi * f * 0.01));
      m.amplitude = rng.uniform(50.0, 300.0);
      m.phase_rad = rng.uniform(0.0, 6.28);
      modes.push_back(m);
      f *= rng.uniform(1.3, 1.9);
    }
    indep::Mode strong;  // far above the band of interest
    strong.f_hz = 10000.0;
    strong.zeta = 0.002;
    strong.amplitude = 3000.0;
    modes.push_back(strong);
    const auto x = decay_signal(modes, fs, 1.0, 0.05, static_cast<std::uint64_t>(trial + 1));
    const double band_hi = modes[static_cast<std::size_t>(k - 1)].f_hz * 1.3;
    ModeSearchOptions opt;
    opt.onset_s = 0.0;
    opt.f_min_hz = 200.0;
    opt.f_max_hz = band_hi;
    const ModeSearchResult r = identify_modes(x, fs, opt);
    for (int i = 0; i < k; ++i) {
      const auto& m = modes[static_cast<std::size_t>(i)];
      const IdentifiedMode* got = nearest(r, m.f_hz);
      ASSERT_NE(got, nullptr) << "trial " << trial << " f " << m.f_hz;
      EXPECT_NEAR(got->selected.f_hz / m.f_hz, 1.0, 2e-3) << "trial " << trial << " f " << m.f_hz;
      if (got->ml.status == EstimateStatus::ok) {
        const double half = 3.0 * 0.5 * (got->ml.zeta_ci95_hi - got->ml.zeta_ci95_lo);
        EXPECT_NEAR(got->ml.zeta, m.zeta, std::max(half, 0.01 * m.zeta)) << "trial " << trial << " f " << m.f_hz;
        ++checked;
      }
    }
    // nothing reported outside the band
    for (const auto& mm : r.modes) {
      if (mm.selected.status != EstimateStatus::ok) continue;
      EXPECT_GE(mm.selected.f_hz, 200.0);
      EXPECT_LE(mm.selected.f_hz, band_hi);
    }
  }
  EXPECT_GT(checked, 2 * kSeeds);  // most modes end up ok (clean, well separated decays)
}

// Status rules: every reported value is possible, statuses sorted by frequency, a note when no mode.
TEST(ModesStatus, ImpossibleValuesAreNullAndNoModeHasANote) {
  std::vector<double> noise(20000);
  indep::Rng rng(7);
  for (double& v : noise) v = rng.gauss();
  ModeSearchOptions opt;
  const ModeSearchResult r = identify_modes(noise, 20000.0, opt);
  if (r.modes.empty()) {
    EXPECT_FALSE(r.note.empty());
  }
  for (const auto& m : r.modes)
    for (const DampingEstimate* e : {&m.two_point, &m.ridge_ls, &m.ml}) {
      if (std::isfinite(e->zeta)) {
        EXPECT_GT(e->zeta, 0.0);
        EXPECT_LT(e->zeta, 1.0);
      }
    }
  for (std::size_t i = 1; i < r.modes.size(); ++i) EXPECT_LE(r.modes[i - 1].selected.f_hz, r.modes[i].selected.f_hz);
}
