// Checks of the independent test-signal generator (tests/support/indep_signals.hpp) against facts
// that do not come from the generator itself: a numerical integration of its envelope equation, the
// impact times implied by the speed law, and libsndfile reading back what its WAV writer wrote.
#include <gtest/gtest.h>
#include <sndfile.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "support/indep_signals.hpp"

namespace {

// Classical RK4 on dA/dt = −aA − b − cA², the equation the closed forms claim to solve.
double integrate_envelope(const indep::Mode& m, double t_end_s) {
  const double a = m.a_per_s(), b = m.coulomb, c = m.quadratic;
  auto rhs = [&](double A) { return A <= 0.0 ? 0.0 : -a * A - b - c * A * A; };
  double A = m.amplitude;
  const int steps = 20000;
  const double h = t_end_s / steps;
  for (int i = 0; i < steps; ++i) {
    const double k1 = rhs(A), k2 = rhs(A + 0.5 * h * k1), k3 = rhs(A + 0.5 * h * k2), k4 = rhs(A + h * k3);
    A = std::max(A + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), 0.0);
  }
  return A;
}

TEST(IndepSignals, EnvelopeClosedFormsSolveTheEnvelopeEquation) {
  indep::Mode viscous{.f_hz = 854.0, .zeta = 0.02, .amplitude = 2.0};
  indep::Mode coulomb{.f_hz = 854.0, .zeta = 0.002, .amplitude = 2.0, .coulomb = 60.0};
  indep::Mode quadratic{.f_hz = 854.0, .zeta = 0.002, .amplitude = 2.0, .quadratic = 40.0};
  for (const auto& m : {viscous, coulomb, quadratic}) {
    for (double t : {0.001, 0.005, 0.02}) {
      // RK4 with 20000 steps over ≤ 20 ms has a global error far below 1e-9 of A0 here.
      EXPECT_NEAR(m.envelope(t), integrate_envelope(m, t), 1e-9) << "t = " << t;
    }
  }
  // Dry friction stops the motion in finite time; the closed form must not go negative.
  EXPECT_EQ(coulomb.envelope(1.0), 0.0);
  // Backbone truth: dry friction raises ζ_eq as the amplitude falls, quadratic damping lowers it.
  EXPECT_GT(coulomb.zeta_at(0.1), coulomb.zeta_at(1.0));
  EXPECT_LT(quadratic.zeta_at(0.1), quadratic.zeta_at(1.0));
}

TEST(IndepSignals, ImpactsFallOncePerRevolution) {
  indep::RigSpec s;
  s.fs_hz = 25600.0;
  s.duration_s = 1.0;
  s.rev_hz = 20.0;
  s.first_impact_s = 0.01;
  const auto r = indep::make_rig_record(s);
  ASSERT_EQ(r.onset_s.size(), 20u);  // 0.01, 0.06, …, 0.96 s
  for (std::size_t k = 0; k < r.onset_s.size(); ++k)
    EXPECT_NEAR(r.onset_s[k], 0.01 + 0.05 * static_cast<double>(k), 1.0 / s.fs_hz);
  // A +10 % linear ramp: speed 20 → 22 rev/s, so 21 revolutions (one impact each) in the second.
  s.ramp_rel = 0.1;
  EXPECT_EQ(indep::make_rig_record(s).onset_s.size(), 21u);
}

TEST(IndepSignals, WavWriterReadsBackThroughLibsndfile) {
  const std::vector<double> x = {0.0, 0.5, -0.25, 0.999, -1.0, 123.5};
  const std::string dir = ::testing::TempDir();
  struct Case {
    indep::SampleFormat format;
    int sf_subtype;
    double full_scale, code_step;  // signal units per integer code (0 for float: exact)
  };
  for (const Case c : {Case{indep::SampleFormat::pcm16, SF_FORMAT_PCM_16, 200.0, 200.0 / 32767},
                       Case{indep::SampleFormat::pcm24, SF_FORMAT_PCM_24, 200.0, 200.0 / 8388607},
                       Case{indep::SampleFormat::float32, SF_FORMAT_FLOAT, 1.0, 0.0}}) {
    const std::string path = dir + "/indep-" + std::to_string(c.sf_subtype) + ".wav";
    indep::write_wav_mono(path, x, 48000.0, c.format, c.full_scale);
    SF_INFO info{};
    SNDFILE* f = sf_open(path.c_str(), SFM_READ, &info);
    ASSERT_NE(f, nullptr) << sf_strerror(nullptr);
    EXPECT_EQ(info.samplerate, 48000);
    EXPECT_EQ(info.channels, 1);
    EXPECT_EQ(info.format & SF_FORMAT_SUBMASK, c.sf_subtype);
    std::vector<double> back(x.size());
    // Integer PCM comes back normalised to ±1, so scale by full_scale to compare in signal units.
    ASSERT_EQ(sf_readf_double(f, back.data(), static_cast<sf_count_t>(back.size())), static_cast<sf_count_t>(x.size()));
    sf_close(f);
    for (std::size_t i = 0; i < x.size(); ++i) {
      const double want = c.format == indep::SampleFormat::float32 ? static_cast<double>(static_cast<float>(x[i])) : x[i];
      // Rounding costs half a code step; libsndfile normalises by 2^15 (2^23) where the writer scales
      // by 2^15 − 1 (2^23 − 1), a relative 2^-15 (2^-23) at most: one code step covers both.
      EXPECT_NEAR(back[i] * c.full_scale, want, c.code_step + 1e-12) << "sample " << i;
    }
    std::remove(path.c_str());
  }
}

}  // namespace
