// Mode identification on signals ridgewatch did not make (tests/support/indep_signals.hpp: closed-form
// decays with viscous, dry-friction and quadratic envelopes) and on the paper's Table-1 signal:
// detection independent of the band and of eta0, statuses that keep their promise, backbones that
// see amplitude-dependent damping with the right sign and do not see it where there is none.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
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

// Any eta0 the user types: Table 1 at 20 dB with eta0 5 ... 100. Every mode is reported at every eta0
// (none dropped: a dropped mode biased its neighbours' joint fit by 5-7 % with status ok); the ml
// estimates do not depend on eta0 (the maximum-likelihood optimum does not depend on its start: within
// a tenth of their standard uncertainty, so no eta0 changes a conclusion); an ok zeta is within 3x its
// 95 % half-width of the truth (> 5 sigma); a mode that is not ok has a note saying why. eta0 5-20
// resolve the three modes (the nearest neighbour is 250 Hz away: eta0 >= 3 f / df <= 3.75 suffices at
// 250 Hz, 3 at 500 Hz; the shortest decay, 500 Hz, lasts > 10 kernel widths at eta0 20): all ok.
// eta0 below 5 is refused (the Morlet correction term of Eq. 4 is no longer negligible).
TEST(ModesDetection, ResultsDoNotDependOnTheEta0TheUserTypes) {
  const auto truth = paper_table1_components();
  const double eta0s[] = {5, 8, 12, 20, 50, 100};
  for (int seed = 1; seed <= std::min(kSeeds, 3); ++seed) {
    auto x = damped_sum(truth, 10000.0, 10000);
    add_white_noise(x, 20.0, static_cast<std::uint64_t>(40 + seed));
    std::vector<double> ref_zeta, ref_sd;
    for (double eta0 : eta0s) {
      ModeSearchOptions opt;
      opt.onset_s = 0.0;
      opt.eta0 = eta0;
      const ModeSearchResult r = identify_modes(x, 10000.0, opt);
      ASSERT_EQ(r.modes.size(), 3u) << "seed " << seed << " eta0 " << eta0;
      for (std::size_t i = 0; i < 3; ++i) {
        const IdentifiedMode& m = r.modes[i];
        const auto& e = m.ml;
        EXPECT_NEAR(e.f_hz / truth[i].f_hz, 1.0, 1e-3) << seed << " eta0 " << eta0;
        if (ref_zeta.size() < 3) {
          ref_zeta.push_back(e.zeta);
          ref_sd.push_back(e.zeta_sd);
        } else {
          EXPECT_NEAR(e.zeta, ref_zeta[i], 0.1 * ref_sd[i]) << seed << " eta0 " << eta0 << " " << truth[i].f_hz;
        }
        if (m.selected.status == EstimateStatus::ok) {
          EXPECT_NEAR(e.zeta, truth[i].zeta, 3.0 * 0.5 * (e.zeta_ci95_hi - e.zeta_ci95_lo)) << seed << " eta0 " << eta0;
        } else {
          EXPECT_FALSE(m.note.empty()) << seed << " eta0 " << eta0 << " " << truth[i].f_hz;
        }
        if (eta0 <= 20) {
          EXPECT_EQ(m.selected.status, EstimateStatus::ok) << seed << " eta0 " << eta0 << " " << truth[i].f_hz << ": " << m.note;
        }
      }
    }
  }
  ModeSearchOptions bad;
  bad.eta0 = 3.0;
  EXPECT_THROW(identify_modes(damped_sum(truth, 10000.0, 10000), 10000.0, bad), std::invalid_argument);
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
