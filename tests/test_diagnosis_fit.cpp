// core/diagnosis model fit: output-error fit of Eq. A2 to simulated impacts (issue 5, step 1).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "core/diagnosis/diagnose.hpp"
#include "core/diagnosis/model_fit.hpp"
#include "core/diagnosis/segmentation.hpp"
#include "core/model/simulator.hpp"

namespace rd = ridgewatch::diagnosis;
namespace rm = ridgewatch::model;

namespace {

// A short recording of the paper rig at 25.6 kHz: 0.1 s lead-in dropped (the simulator starts from
// rest, a real recording starts in steady state), then `impacts` impacts 40 ms apart.
std::vector<double> record(const rm::RigParameters& rig, std::vector<rm::EffectSpec> effects, double noise,
                           int impacts, std::uint64_t seed, double rate = 25600.0) {
  if (noise > 0.0) effects.push_back({"noise", {{"std_rel", noise}}});
  rm::SimulationSettings s;
  s.sample_rate_hz = rate;
  s.duration_s = 0.1 + impacts * 0.04;
  s.seed = seed;
  const auto r = rm::simulate(rig, effects, s);
  return {r.output.begin() + static_cast<std::ptrdiff_t>(0.1 * rate), r.output.end()};
}

}  // namespace

TEST(DiagnosisSegmentation, FindsImpactsNoiseAndSpikes) {
  rm::RigParameters rig;
  const auto y = record(rig, {{"spikes", {{"rate_per_s", 10.0}, {"amplitude_rel", 1.0}}}}, 0.01, 12, 3);
  const auto seg = rd::segment_recording(y, 25600.0, rig);
  EXPECT_GE(seg.windows.size(), 11u);
  EXPECT_NEAR(seg.revolution_s, 0.04, 1e-4);
  // Noise: 1 % of the clean peak (~0.33 at 2000 N with 10 % jitter); the estimate within 10 %
  // (2000 gap samples give a MAD-based sd within ~3 %).
  double peak = 0.0;
  for (double v : y) peak = std::max(peak, std::abs(v));
  EXPECT_GT(seg.noise_sd, 0.0);
  EXPECT_LT(seg.noise_sd, 0.02 * peak);
  EXPECT_GE(seg.spikes.size(), 1u);
}

TEST(DiagnosisFit, RecoversStiffnessAndDampingOnHeldOut) {
  // The paper's gap: the rig runs at 854 Hz while Appendix B's c0 gives 859-860 Hz. Simulate with
  // c0 scaled by (854/860.1)^2 and fit with the nominal rig: the fitted c0 must land on the truth.
  rm::RigParameters truth;
  const double scale = std::pow(854.0 / truth.natural_frequency_hz(), 2.0);
  truth.mean_mesh_stiffness_n_per_m *= scale;
  truth.damping_ratio = 0.028;
  const auto y = record(truth, {}, 0.005, 12, 7);
  rm::RigParameters nominal;
  const auto seg = rd::segment_recording(y, 25600.0, nominal);
  ASSERT_GE(seg.windows.size(), 10u);
  const rd::ModelFitter fitter(y, seg, nominal);
  const rd::FitResult r = fitter.fit({});
  ASSERT_EQ(r.estimates.size(), 3u);  // c0, ζ and the impact pulse length
  // c0 within 0.1 % (f0 within 0.05 % = 0.4 Hz; the CRB at this SNR is ~0.01 %), ζ within 3 %.
  EXPECT_NEAR(r.estimates[0].value / truth.mean_mesh_stiffness_n_per_m, 1.0, 1e-3);
  EXPECT_NEAR(r.estimates[1].value / 0.028, 1.0, 0.03);
  EXPECT_LT(r.estimates[0].ci95_lo, truth.mean_mesh_stiffness_n_per_m);
  EXPECT_GT(r.estimates[0].ci95_hi, truth.mean_mesh_stiffness_n_per_m);
  // No dry friction, no held start offset: the intervals are s² (JᵀJ)⁻¹ alone.
  for (const auto& e : r.estimates) EXPECT_EQ(e.offset_var, 0.0) << e.name;
  // Nothing left to explain: the held-out excess is within sampling noise of 0 (n ~ 2500 held-out
  // samples -> sd of a power ratio sqrt(2/n) ~ 0.03) and the model error (carried tails, RK4) small.
  EXPECT_LT(std::abs(r.heldout_excess), 0.1) << r.heldout_excess;
  EXPECT_GT(r.fit_percent, 90.0);
}

TEST(DiagnosisFit, MissingEffectLeavesExcess) {
  rm::RigParameters rig;
  const auto y = record(rig, {{"coulomb_friction", {{"force_n", 30.0}}}}, 0.005, 12, 11);
  const auto seg = rd::segment_recording(y, 25600.0, rig);
  const rd::ModelFitter fitter(y, seg, rig);
  const rd::FitResult base = fitter.fit({});
  EXPECT_GT(base.heldout_excess, 1.0);
  const rd::FitResult with = fitter.fit({"coulomb_friction"}, &base);
  EXPECT_LT(with.heldout_excess, 0.1) << with.heldout_excess << " baseline " << base.heldout_excess << " F " << with.estimates[2].value;
  EXPECT_NEAR(with.estimates[2].value, 30.0, 3.0);
}

TEST(DiagnosisFit, DryFrictionIntervalsHoldTheTruth) {
  // ridgewatch's own simulator with the fitted model's very physics (dry friction 30 N, exact
  // stick/slip), 16 impacts at 25.6 kHz, 1 % noise, fitted with linear + coulomb_friction: nothing
  // but the noise separates the fit from the truth, so force_n and ζ must lie within 3 of the fit's
  // own standard deviations (a chance miss per parameter at 0.3 % when the sd is right). When the
  // held-out windows' nuisances stayed at their onset-grid starts in the training fit, their carried
  // stuck offsets put force_n 3-4 % low and ζ 5-6 % high, 4-6 sd, on every seed (0/20 intervals
  // covering, `bench_diagnose coverage coulomb-own 20`). Seeds 2 and 3 of that bench: then 28.83 and
  // 28.89 N (-5.9 and -5.1 sd), ζ +5.1 and +4.6 sd; now within 0.8 sd.
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  for (std::uint64_t seed : {2u, 3u}) {
    const auto y = record(rig, {{"coulomb_friction", {{"force_n", 30.0}}}}, 0.01, 16, seed * 7727u + 3u);
    const auto seg = rd::subset_windows(rd::segment_recording(y, 25600.0, rig), 16);
    const rd::ModelFitter fitter(y, seg, rig);
    const rd::FitResult f = fitter.fit({"coulomb_friction"});
    ASSERT_EQ(f.estimates.size(), 4u);  // c0, ζ, force_n, the pulse length
    const auto& zeta = f.estimates[1];
    const auto& force = f.estimates[2];
    ASSERT_EQ(force.name, "coulomb_friction.force_n");
    EXPECT_LT(std::abs(force.value - 30.0), 3.0 * force.sd) << "seed " << seed << ": " << force.value << " sd " << force.sd;
    EXPECT_LT(std::abs(zeta.value - 0.024), 3.0 * zeta.sd) << "seed " << seed << ": " << zeta.value << " sd " << zeta.sd;
  }
}

#ifndef RIDGEWATCH_SANITIZED  // three whole friction fits: ~2 s optimised, minutes under the sanitizers
TEST(DiagnosisFit, HeldStartOffsetOfDryFrictionWidensTheStiffnessInterval) {
  // Dry friction 50 N on ridgewatch's own simulator after a 0.1 s lead-in: the record's first window
  // starts with the mesh held somewhere in the friction band (±F_c / c0), where the fit's window
  // model starts at x = 0. That offset moves c0 by more than s² (JᵀJ)⁻¹ allows (20 seeds of
  // `bench_diagnose coverage coulomb-own 20 50`: 14/20 covered, RMS z 1.85), and the fit adds its
  // propagated effect to the covariance (ParameterEstimate::offset_var). Seeds 5, 6 and 13 of that
  // bench are three where the interval without the term misses the truth: with it each must cover
  // it, and without it (sd² - offset_var) each must miss, so the term is what makes them cover.
  // Measured: |z| 1.16, 1.63, 1.23 with the term, 2.47, 3.58, 2.14 without (the term about doubles
  // c0's sd); the seeds with the largest margins on both sides of 1.96 of the six that missed.
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  const double c0_true = rig.mean_mesh_stiffness_n_per_m;
  for (std::uint64_t seed : {5u, 6u, 13u}) {
    const auto y = record(rig, {{"coulomb_friction", {{"force_n", 50.0}}}}, 0.01, 16, seed * 7727u + 3u);
    const auto seg = rd::subset_windows(rd::segment_recording(y, 25600.0, rig), 16);
    const rd::ModelFitter fitter(y, seg, rig);
    const rd::FitResult f = fitter.fit({"coulomb_friction"});
    ASSERT_EQ(f.estimates.size(), 4u);  // c0, ζ, force_n, the pulse length
    const auto& c0 = f.estimates[0];
    ASSERT_EQ(c0.name, "c0_n_per_m");
    ASSERT_GT(c0.offset_var, 0.0) << "seed " << seed;
    ASSERT_LT(c0.offset_var, c0.sd * c0.sd) << "seed " << seed;
    const double sd0 = std::sqrt(c0.sd * c0.sd - c0.offset_var);
    std::printf("seed %d: c0 %.6g, sd %.3g (without the offset term %.3g), z %.2f (%.2f), interval %.6g .. %.6g\n",
                static_cast<int>(seed), c0.value, c0.sd, sd0, (c0.value - c0_true) / c0.sd, (c0.value - c0_true) / sd0,
                c0.ci95_lo, c0.ci95_hi);
    EXPECT_LT(c0.ci95_lo, c0_true) << "seed " << seed;
    EXPECT_GT(c0.ci95_hi, c0_true) << "seed " << seed;
    EXPECT_GT(std::abs(c0.value - c0_true), 1.96 * sd0) << "seed " << seed << ": the seed no longer tests the term";
  }
}
#endif

TEST(DiagnosisFit, FrictionWindowMovesSmoothlyWithTheOnsetWhileTheMeshIsHeld) {
  // A window that starts with the mesh held by dry friction (30 N) at an offset inside the band, as
  // the fit's windows start after a stopped predecessor: the impact pulse (1855 N) releases it about
  // 0.5 µs after its onset, once pulse and spring force exceed the static limit. The fit's Jacobian
  // differences the window output over onset steps of 1e-4 samples, so the output must follow the
  // onset smoothly. Onsets scanned over one sample period (78 ns apart): between neighbours the output
  // may change only by the onset's own effect, about the same at every onset. With the release tested
  // at step starts only, it jumps by a step wherever a step start crosses the release time (seed 1 of
  // `bench_diagnose coverage coulomb-own`: one onset column 30x, ζ's and force_n's 100x too long);
  // measured with the release left to the next step start: the largest change 290x the median.
  // Smoothly, the change varies with the response's shape over a sample (the 860 Hz wave moves by
  // 0.2 rad): 3x the median allows that and no jump.
  rm::RigParameters rig;
  rd::PhysicsValues phys;
  phys.c0_n_per_m = rig.mean_mesh_stiffness_n_per_m;
  phys.zeta = rig.damping_ratio;
  phys.effects = {{"coulomb_friction", {{"force_n", 30.0}}}};
  const double fs = 25600.0;
  const rd::WindowSimulator sim(rig, phys, fs);
  const double offset_m = -11.0 / rig.mean_mesh_stiffness_n_per_m;  // the friction holds 11 N of spring force
  const rd::ModelState held{offset_m, 0.0, 0.0, 0.0};
  const std::uint64_t first = 10000;
  const std::size_t n = 300;
  constexpr int kOnsets = 500;
  std::vector<double> previous(n), out(n), change;
  for (int k = 0; k <= kOnsets; ++k) {
    const rd::WindowSimulator::Impact imp{(static_cast<double>(first) + 26.0 + k / static_cast<double>(kOnsets)) / fs,
                                          rig.impact_force_n, rig.mesh_frequency_hz(), 1.0};
    rd::WindowSimulator::End end;
    sim.simulate(first, n, imp, held, out.data(), end);
    ASSERT_TRUE(end.stopped) << "the window must end held again (the scan's premise)";
    if (k > 0) {
      double d = 0.0;
      for (std::size_t i = 0; i < n; ++i) d = std::max(d, std::abs(out[i] - previous[i]));
      change.push_back(d);
    }
    previous.swap(out);
  }
  std::vector<double> sorted = change;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
  const double median = sorted[sorted.size() / 2];
  const auto worst = std::max_element(change.begin(), change.end());
  ASSERT_GT(median, 0.0);
  EXPECT_LT(*worst, 3.0 * median) << "output jumps between onsets " << (worst - change.begin()) << " and "
                                  << (worst - change.begin()) + 1 << " (of " << kOnsets << " per sample): "
                                  << *worst / median << " x the median change";
}

TEST(DiagnosisFit, DiagnoseReportsTheUnbiasedFrictionFit) {
  // diagnose screens candidates without the held-out nuisances in the training fit (half the cost)
  // and refits the final model with them when it has dry friction: the reported force_n and ζ are
  // the ones compare gives. Seed 2 of the test above: the screened fit (warm from the linear model,
  // polished) ends at 29.78 N, 1.4 sd from the joint fit's 30.11 N; diagnose reports 30.11 N.
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  const auto y = record(rig, {{"coulomb_friction", {{"force_n", 30.0}}}}, 0.01, 16, 2u * 7727u + 3u);
  const auto seg = rd::subset_windows(rd::segment_recording(y, 25600.0, rig), 16);
  const rd::ModelFitter fitter(y, seg, rig);
  rd::DiagnoseOptions o;
  o.candidates = {"coulomb_friction"};
  o.max_rounds = 1;
  o.discover_terms = false;
  const rd::DiagnoseResult r = rd::diagnose(fitter, {}, o);
  ASSERT_EQ(r.verdict, std::vector<std::string>{"coulomb_friction"});
  const rd::ParameterEstimate* force = nullptr;
  const rd::ParameterEstimate* zeta = nullptr;
  for (const auto& e : r.final_fit.estimates) {
    if (e.name == "coulomb_friction.force_n") force = &e;
    if (e.name == "zeta") zeta = &e;
  }
  ASSERT_NE(force, nullptr);
  ASSERT_NE(zeta, nullptr);
  std::printf("diagnose's friction fit: force_n %.3f N (sd %.3f), zeta %.5f (sd %.5f)\n", force->value, force->sd, zeta->value, zeta->sd);
  EXPECT_LT(std::abs(force->value - 30.0), 3.0 * force->sd) << force->value << " sd " << force->sd;
  EXPECT_LT(std::abs(zeta->value - 0.024), 3.0 * zeta->sd) << zeta->value << " sd " << zeta->sd;
  // And it is the fit compare makes (the same optimum from another start: within a tenth of an sd;
  // the screened fit sits 1.5 sd from it on this record).
  const rd::FitResult direct = fitter.fit({"coulomb_friction"});
  ASSERT_EQ(direct.estimates[2].name, "coulomb_friction.force_n");
  std::printf("compare's friction fit: force_n %.3f N\n", direct.estimates[2].value);
  EXPECT_LT(std::abs(force->value - direct.estimates[2].value), 0.1 * force->sd);
}
