// diagnose/compare on records that ridgewatch's simulator did not make (issue 14): the independent
// gear-rig generator tests/support/indep_gear.hpp (own integrator, Hann impact pulse, own noise and
// conventions). The full confusion matrix (every hidden effect, several seeds) is
// `bench_diagnose indep`; here one seed of the cases the issue found wrong, plus the 930 Hz second
// mode on ridgewatch's own simulator and a record of another structure.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

#include "core/diagnosis/diagnose.hpp"
#include "core/model/simulator.hpp"
#include "support/indep_gear.hpp"

namespace rd = ridgewatch::diagnosis;
namespace rm = ridgewatch::model;
namespace ig = ridgewatch::testsupport::indep;

namespace {

constexpr double kRate = 25600.0;  // the rate of ig::short_test_record

rm::RigParameters paper_rig(double load = 200.0) {
  rm::RigParameters rig;  // config/rigs/paper-rig.yaml
  rig.crack_angle_rad = 1.0;
  rig.load_torque_n_m = load;
  return rig;
}

// (every caller is a whole diagnose run, which the sanitizer pass leaves out: maybe unused there)
[[maybe_unused]] rd::DiagnoseResult run(const std::vector<double>& y, const rm::RigParameters& rig) {
  const auto seg = rd::subset_windows(rd::segment_recording(y, kRate, rig), 16);
  EXPECT_GE(seg.windows.size(), 14u);
  const rd::ModelFitter fitter(y, seg, rig);
  return rd::diagnose(fitter, {});
}

/// One round of diagnose over the given candidates only (fast: the full catalogue is
/// bench_diagnose_sweep), no term discovery.
rd::DiagnoseResult one_round(const std::vector<double>& y, const rm::RigParameters& rig, std::vector<std::string> candidates) {
  const auto seg = rd::subset_windows(rd::segment_recording(y, kRate, rig), 16);
  const rd::ModelFitter fitter(y, seg, rig);
  rd::DiagnoseOptions o;
  o.candidates = std::move(candidates);
  o.max_rounds = 1;
  o.discover_terms = false;
  return rd::diagnose(fitter, {}, o);
}

/// The independent generator's damping-step record (ζ 0.024 -> 0.032 at 0.32 s of 0.64 s, seed 1)
/// and its first 16 impact windows.
struct StepRecord {
  std::vector<double> y;
  rd::Segmentation seg;
};
StepRecord damping_step_record() {
  ig::Settings st = ig::short_test_record(ig::Hidden::kDampingStep, 0.008, 1);
  st.size2 = 0.32;
  StepRecord s{ig::generate(st).y, {}};
  s.seg = rd::subset_windows(rd::segment_recording(s.y, kRate, paper_rig()), 16);
  return s;
}

}  // namespace

// The generator itself, against hand numbers: one impact per revolution (25 Hz), and the free
// response rings at the paper rig's damped frequency f0 sqrt(1 - ζ²) = 859.9 Hz (f0 = 860.1 Hz,
// Appendix B, computed by hand from J1, J2, r_b1, r_b2, c0). Zero crossings over 10 ms after the
// first impact, noise-free: the period estimate is good to 1e-3 of a cycle per crossing pair.
TEST(IndependentGenerator, ImpactRateAndRingingFrequencyMatchThePaperRig) {
  ig::Settings s = ig::short_test_record(ig::Hidden::kNone, 0.0, 1);
  s.noise_rel = 0.0;
  const auto r = ig::generate(s);
  ASSERT_EQ(r.impact_times_s.size(), 16u);
  EXPECT_NEAR(r.impact_times_s[1] - r.impact_times_s[0], 0.04, 1e-12);
  const auto i0 = static_cast<std::size_t>((r.impact_times_s[0] + 0.001) * kRate);
  const auto i1 = static_cast<std::size_t>((r.impact_times_s[0] + 0.011) * kRate);
  std::vector<double> crossings;
  for (std::size_t i = i0 + 1; i < i1; ++i)
    if (r.y[i - 1] < 0.0 && r.y[i] >= 0.0) crossings.push_back((static_cast<double>(i) - 1.0 + r.y[i - 1] / (r.y[i - 1] - r.y[i])) / kRate);
  ASSERT_GE(crossings.size(), 6u);
  const double f = static_cast<double>(crossings.size() - 1) / (crossings.back() - crossings.front());
  EXPECT_NEAR(f, 859.9, 1.0);  // 1 Hz: linear interpolation of crossings at 30 samples per cycle
}

#ifndef RIDGEWATCH_SANITIZED  // a whole diagnose run: 13 s optimised, ~440 s under the sanitizers (the contact-loss and step cases below keep the path there)
// Issue 14: stiffness variation whose only evidence is the modulation of each free decay (no static
// load lines) was missed ("none"). Now found by its own name.
TEST(DiagnoseIndependent, MeshVariationWithoutLoadLinesIsFound) {
  const auto r = ig::generate(ig::short_test_record(ig::Hidden::kMeshVariationNoLines, 1.5, 1));
  const auto res = run(r.y, paper_rig());
  ASSERT_EQ(res.verdict, std::vector<std::string>{"mesh_stiffness_variation"}) << res.unexplained_where;
  EXPECT_GT(res.baseline_excess, 0.5);
  EXPECT_LT(res.final_excess, 0.1);
  // The fitted static coupling says "no load lines" (truth 0; 0.3 leaves room for its interval at
  // 1 % noise and 8 training impacts).
  for (const auto& e : res.final_fit.estimates) {
    if (e.name == "mesh_stiffness_variation.static_coupling") {
      EXPECT_LT(e.value, 0.3);
    }
  }
}
#endif

#ifndef RIDGEWATCH_SANITIZED
// A model with a mesh-periodic effect keeps the impact pulse length at the rig's value during the
// rounds (fitted from the start it is trapped); the final model frees it, from its converged fit.
// The other generator's pulse is a Hann window where ridgewatch's is a half-sine: with the length
// fixed this seed (bench_diagnose_sweep's seed 3) ended at 0.125, flagged unexplained, and term
// discovery's x·cos kθ force was listed as ambiguous with the right effect. Now at the noise (< 0.1,
// the diagnose target; the sweep's seeds 1-3 end at -0.06 … 0.012) with a pulse length inside its
// range (0.5-2x the rig's), and the training fit no worse than the fixed-length one.
TEST(DiagnoseIndependent, MeshVariationFinalModelFitsThePulseLength) {
  const auto r = ig::generate(ig::short_test_record(ig::Hidden::kMeshVariationNoLines, 1.5, 3u * 104729u + 17u));
  const auto res = one_round(r.y, paper_rig(), {"mesh_stiffness_variation"});
  ASSERT_EQ(res.verdict, std::vector<std::string>{"mesh_stiffness_variation"});
  EXPECT_LT(res.final_excess, 0.1);
  EXPECT_FALSE(res.unexplained) << res.unexplained_where;
  const auto pulse = std::find_if(res.final_fit.estimates.begin(), res.final_fit.estimates.end(),
                                   [](const rd::ParameterEstimate& e) { return e.name == "pulse_duration_s"; });
  ASSERT_NE(pulse, res.final_fit.estimates.end()) << "the final model's pulse length was not freed";
  EXPECT_FALSE(pulse->at_bound);
}
#endif

#ifndef RIDGEWATCH_SANITIZED
// The three transmission-error cases take 1.5-3 s each here and 95-130 s each under the sanitizers;
// the sanitizer pass keeps the contact-loss case below (the same candidate-fit path) and the
// transmission error's own force test (test_model_effects.cpp).

// A transmission error in the other generator's convention: it forces with +c (q - e) where Eq. A1
// has -c (q + e), so its e(θ) = 0.3 µm sin(θ + φ) + 0.1 µm sin 2(θ + φ), φ = 0.4 rad, is in
// ridgewatch's sign -e: harmonics at phases φ + π and 2φ + π, which no single shift of the mesh angle
// gives. With one common phase the catalogue fit stayed far from the lines (the sweep's held-out
// excess 282 -> 60) and diagnose named mesh_stiffness_variation; now each harmonic has its own phase.
// Checked against the generator's truth, worked out by hand:
//  - amplitudes 0.3 and 0.1 µm (±5 %: the fit's sd is ~0.1 %, the rest covers the other pulse shape
//    and integrator);
//  - mesh phase: the impact sits at pinion angle 1 rad, mesh angle 22 rad, so ridgewatch's angle
//    (0 at the onset) is the generator's minus 22; e1 sin(θ + ψ) = -0.3 µm sin(θ + 22 + φ) gives
//    ψ = 22 + φ + π (mod 2π) = 0.409 rad; then the 2nd harmonic's own phase is 2(22 + φ) + π - 2ψ = π
//    (mod 2π). ±0.05 rad: 14 µs of onset at f_z (a third of a sample at 25.6 kHz), 40 times the
//    fitted sd;
//  - a held-out excess at the noise (< 0.1, the diagnose target).
// The stiffness-variation fit cannot reach these lines (Eq. B1's fixed ratios between harmonics,
// and it predicts sidebands f0 ± k f_z the record does not have): its held-out excess stays > 10.
TEST(DiagnoseIndependent, TransmissionErrorWithItsOwnPhasesIsReached) {
  ig::Settings s = ig::short_test_record(ig::Hidden::kTransmissionError, 0.3e-6, 1);
  s.size2 = 0.1e-6;
  const auto r = ig::generate(s);
  const auto seg = rd::subset_windows(rd::segment_recording(r.y, kRate, paper_rig()), 16);
  ASSERT_GE(seg.windows.size(), 14u);
  const rd::ModelFitter fitter(r.y, seg, paper_rig());
  const auto te = fitter.fit({"transmission_error"});
  EXPECT_LT(te.heldout_excess, 0.1);
  const double pi = std::numbers::pi;
  const double psi = std::remainder(22.0 + 0.4 + pi, 2.0 * pi);
  auto angle_gap = [&](double a, double b) { return std::abs(std::remainder(a - b, 2.0 * pi)); };
  int seen = 0;
  for (const auto& e : te.estimates) {
    if (e.name == "transmission_error.e1_m") {
      EXPECT_NEAR(e.value, 0.3e-6, 0.015e-6);
      ++seen;
    } else if (e.name == "transmission_error.e2_m") {
      EXPECT_NEAR(e.value, 0.1e-6, 0.005e-6);
      ++seen;
    } else if (e.name == "transmission_error.phase2_rad") {
      EXPECT_LT(angle_gap(e.value, pi), 0.05) << e.value;
      ++seen;
    } else if (e.name == "mesh_phase_rad") {
      EXPECT_LT(angle_gap(e.value, psi), 0.05) << e.value;
      ++seen;
    }
  }
  EXPECT_EQ(seen, 4);
  const auto msv = fitter.fit({"mesh_stiffness_variation"});
  EXPECT_GT(msv.heldout_excess, 10.0);
}

// The same record through diagnose, with the two mesh-periodic candidates only (one round): named transmission_error, not the stiffness
// variation it was named before the harmonics had their own phases, with nothing ambiguous and the
// held-out excess at the noise (< 0.1).
TEST(DiagnoseIndependent, TransmissionErrorIsNamedNotStiffnessVariation) {
  ig::Settings s = ig::short_test_record(ig::Hidden::kTransmissionError, 0.3e-6, 1);
  s.size2 = 0.1e-6;
  const auto res = one_round(ig::generate(s).y, paper_rig(), {"mesh_stiffness_variation", "transmission_error"});
  EXPECT_EQ(res.verdict, std::vector<std::string>{"transmission_error"});
  EXPECT_TRUE(res.ambiguous.empty()) << res.ambiguous_evidence;
  EXPECT_LT(res.final_excess, 0.1);
  // The evidence that tells it from a stiffness variation: lines at k f_z and no sidebands f0 ± k f_z
  // (the generator's error is additive: nothing modulates the free decays).
  for (const auto& step : res.steps) {
    if (step.effect == "transmission_error") {
      EXPECT_NE(step.evidence.find("no sideband"), std::string::npos) << step.evidence;
    }
  }
}

// The same on ridgewatch's own simulator (its sign, harmonics in phase): the 2nd harmonic's own phase
// may end a full turn from its start (φ_2 = 2π is the phase 0); that is no bound of the physics and
// must not reject the fit (it did: the verdict was mesh_stiffness_variation with 400 left).
TEST(DiagnoseIndependent, TransmissionErrorOnOwnSimulatorIsNamed) {
  const auto rig = paper_rig();
  rm::SimulationSettings s;
  s.sample_rate_hz = kRate;
  s.duration_s = 0.74;
  s.seed = 7919;  // bench_diagnose's seed 1 at 0.5 % noise
  const auto sim = rm::simulate(
      rig, {{"transmission_error", {{"e1_m", 0.3e-6}, {"e2_m", 0.1e-6}}}, {"noise", {{"std_rel", 0.005}}}}, s);
  const std::vector<double> y(sim.output.begin() + static_cast<std::ptrdiff_t>(0.1 * kRate), sim.output.end());
  const auto res = one_round(y, rig, {"mesh_stiffness_variation", "transmission_error"});
  EXPECT_EQ(res.verdict, std::vector<std::string>{"transmission_error"});
  EXPECT_LT(res.final_excess, 0.1);
}
#endif

// Contact loss at light load (20 N m: the 2 kN impacts separate the teeth): the linear model's fit
// drives the pulse length to the end of its range to mimic the softening, and contact loss started
// from there stayed at a held-out excess of 2.3 (named, but "unexplained", and mesh-periodic
// candidates then passed on the remainder). Diagnose also starts it cold: at the noise (< 0.1).
TEST(DiagnoseIndependent, ContactLossAtLightLoadReachesTheNoise) {
  ig::Settings s = ig::short_test_record(ig::Hidden::kContactLoss, 1.0, 1);
  s.load_torque_n_m = 20.0;
  s.seed = 104729u + 17u;  // bench_diagnose_sweep's seed 1
  const auto res = one_round(ig::generate(s).y, paper_rig(20.0), {"contact_loss"});
  EXPECT_EQ(res.verdict, std::vector<std::string>{"contact_loss"});
  EXPECT_LT(res.final_excess, 0.1);
  EXPECT_FALSE(res.unexplained) << res.unexplained_where;
}

#ifndef RIDGEWATCH_SANITIZED
// A control from the other generator: nothing accepted and nothing unexplained. Before the impact
// pulse length was fitted, the Hann pulse alone left a held-out excess of 0.04-0.12 here.
TEST(DiagnoseIndependent, ControlAcceptsNothing) {
  const auto r = ig::generate(ig::short_test_record(ig::Hidden::kNone, 0.0, 2));
  const auto res = run(r.y, paper_rig());
  EXPECT_TRUE(res.verdict.empty());
  EXPECT_TRUE(res.ambiguous.empty());
  EXPECT_LT(std::abs(res.final_excess), 0.1);
}

// Issue 14's own-simulator case: a second mode at 930 Hz next to f0 = 860 Hz (ζ 0.02, participation
// 0.5, 1 % noise) was named stiffness_nonlinearity, then quadratic_damping, then second_mode. The
// verdict must be exactly second_mode (bench_diagnose sm930 runs seeds 1-3 at both rates).
TEST(DiagnoseLoopIssue14, SecondModeNearF0IsExactlySecondMode) {
  const auto rig = paper_rig();
  rm::SimulationSettings s;
  s.sample_rate_hz = kRate;
  s.duration_s = 0.74;
  s.seed = 1;
  const auto sim = rm::simulate(
      rig, {{"second_mode", {{"frequency_hz", 930.0}, {"damping_ratio", 0.02}, {"participation", 0.5}}}, {"noise", {{"std_rel", 0.01}}}}, s);
  const std::vector<double> y(sim.output.begin() + static_cast<std::ptrdiff_t>(0.1 * kRate), sim.output.end());
  const auto res = run(y, rig);
  EXPECT_EQ(res.verdict, std::vector<std::string>{"second_mode"});
  EXPECT_FALSE(res.unexplained) << res.unexplained_where;
}
#endif

// A record of another structure (the issue's case: modes at 3.5 and 8 kHz, nothing at the rig's
// 860 Hz, impacts once per revolution): the rig cannot describe it, and compare must say so instead
// of printing a fitted ζ and c0 as if they were physical.
TEST(CompareIndependent, RecordOfAnotherStructureIsFlagged) {
  const auto rig = paper_rig();
  const double dur = 0.64;
  std::vector<double> y(static_cast<std::size_t>(dur * kRate), 0.0);
  std::uint64_t state = 99;
  auto uniform = [&] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(state >> 11) / 9007199254740992.0;
  };
  for (double t0 = 1.0 / (2 * std::numbers::pi) * 0.04; t0 < dur; t0 += 0.04)
    for (std::size_t i = static_cast<std::size_t>(t0 * kRate); i < y.size() && i < static_cast<std::size_t>((t0 + 0.03) * kRate); ++i) {
      const double t = static_cast<double>(i) / kRate - t0;
      if (t < 0.0) continue;
      y[i] += 0.3 * std::exp(-2.0 * std::numbers::pi * 3500.0 * 0.01 * t) * std::sin(2.0 * std::numbers::pi * 3500.0 * t) +
              0.15 * std::exp(-2.0 * std::numbers::pi * 8000.0 * 0.01 * t) * std::sin(2.0 * std::numbers::pi * 8000.0 * t);
    }
  for (double& v : y) v += 0.003 * (uniform() + uniform() + uniform() - 1.5) * 2.0;
  rd::Segmentation seg;
  try {
    seg = rd::subset_windows(rd::segment_recording(y, kRate, rig), 16);
  } catch (const std::invalid_argument&) {
    GTEST_SKIP() << "the detector refuses the record outright (also acceptable)";
  }
  if (seg.windows.size() < 4) GTEST_SKIP() << "fewer than 4 usable impacts (compare refuses with exit 3)";
  const rd::ModelFitter fitter(y, seg, rig);
  const auto fit = fitter.fit({});
  const auto rep = rd::analyse_residual(fitter, fit);
  const auto problems = rd::description_problems(fitter, fit, rep);
  EXPECT_FALSE(problems.empty()) << "fit " << fit.fit_percent << " %";
}

// A damping step (ζ 0.024 -> 0.032 between two impacts, at 0.32 s of a 0.64 s record; the independent
// generator's own integrator finds the kink by step-size control): `compare --with
// damping_drift:step_time_s=0.32!` fits the step at that time. Without the time only the drift rate is
// fitted, a straight line through a step.
TEST(CompareIndependent, DampingStepAtAGivenTimeIsFitted) {
  const auto r = damping_step_record();
  ASSERT_GE(r.seg.windows.size(), 14u);
  rd::ModelFitter fitter(r.y, r.seg, paper_rig());
  const rd::FitResult rate_only = fitter.fit({"damping_drift"});
  for (const auto& e : rate_only.estimates) EXPECT_NE(e.name, "damping_drift.step");
  // The time is set, never fitted; it must lie between fitted impacts.
  EXPECT_THROW(fitter.set_parameter_settings({{"damping_drift.step_time_s", {0.32, false}}}), std::invalid_argument);
  EXPECT_THROW(fitter.set_parameter_settings({{"damping_drift.step_time_s", {5.0, true}}}), std::invalid_argument);
  fitter.set_parameter_settings({{"damping_drift.step_time_s", {0.32, true}}});
  const rd::FitResult with_step = fitter.fit({"damping_drift"});
  const auto estimate = [](const rd::FitResult& f, const std::string& name) -> const rd::ParameterEstimate* {
    for (const auto& e : f.estimates)
      if (e.name == name) return &e;
    return nullptr;
  };
  const rd::ParameterEstimate* step = estimate(with_step, "damping_drift.step");
  ASSERT_NE(step, nullptr);
  std::printf("damping step: rate-only excess %.3f, with the step %.3f; step %.5f (%.5f .. %.5f), zeta %.5f\n",
              rate_only.heldout_excess, with_step.heldout_excess, step->value, step->ci95_lo, step->ci95_hi,
              estimate(with_step, "zeta")->value);
  // The truth inside the 95 % interval, and within 10 % (the interval is a few % wide at 1 % noise).
  EXPECT_LT(step->ci95_lo, 0.008);
  EXPECT_GT(step->ci95_hi, 0.008);
  EXPECT_NEAR(step->value, 0.008, 0.0008);
  EXPECT_LT(with_step.heldout_excess, 0.1);
  EXPECT_LT(with_step.heldout_excess, rate_only.heldout_excess);
}

// diagnose finds a damping step on its own (the step-time scan, core/diagnosis/damping_step.hpp): the
// independent generator's step record (ζ 0.024 -> 0.032 at 0.32 s, 1 % noise), three seeds. The
// verdict is damping_drift with a step whose bracketing impacts contain 0.32 s and whose 95 % interval
// covers the true 0.008. One round over damping_drift alone (the full catalogue is
// bench_diagnose_sweep's damping_step row).
TEST(DiagnoseIndependent, DampingStepIsFoundWithItsGap) {
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    ig::Settings st = ig::short_test_record(ig::Hidden::kDampingStep, 0.008, seed);
    st.size2 = 0.32;
    const auto r = one_round(ig::generate(st).y, paper_rig(), {"damping_drift"});
    ASSERT_EQ(r.verdict, std::vector<std::string>{"damping_drift"}) << "seed " << seed;
    ASSERT_TRUE(r.damping_step.found) << "seed " << seed;
    const auto& t = r.damping_step.time;
    const auto& s = r.damping_step.step;
    std::printf("seed %d: step %.5f (%.5f .. %.5f) between %.4f and %.4f s (model %.4f s), excess %.3f -> %.3f\n",
                static_cast<int>(seed), s.value, s.ci95_lo, s.ci95_hi, t.ci95_lo, t.ci95_hi, t.value, r.baseline_excess, r.final_excess);
    EXPECT_LT(t.ci95_lo, 0.32) << "seed " << seed;
    EXPECT_GT(t.ci95_hi, 0.32) << "seed " << seed;
    // The gap is one impact period (40 ms at 1500 rpm) when the impacts around it are both fitted.
    EXPECT_LT(t.ci95_hi - t.ci95_lo, 0.045) << "seed " << seed;
    EXPECT_LT(s.ci95_lo, 0.008) << "seed " << seed;
    EXPECT_GT(s.ci95_hi, 0.008) << "seed " << seed;
    EXPECT_LT(r.final_excess, 0.1) << "seed " << seed;
  }
}

// A drift without a step (ζ + 0.008/s over 2 s, the README sweep's drift row) is fitted as a drift:
// no step is found by the scan.
TEST(DiagnoseIndependent, DampingDriftHasNoStep) {
  ig::Settings st = ig::short_test_record(ig::Hidden::kDampingDrift, 0.008, 1);
  st.duration_s = 2.0;
  const auto r = one_round(ig::generate(st).y, paper_rig(), {"damping_drift"});
  ASSERT_EQ(r.verdict, std::vector<std::string>{"damping_drift"});
  EXPECT_FALSE(r.damping_step.found) << "step " << r.damping_step.step.value << " between " << r.damping_step.time.ci95_lo
                                     << " and " << r.damping_step.time.ci95_hi << " s";
  for (const auto& e : r.final_fit.estimates) EXPECT_NE(e.name, "damping_drift.step");
}

// A step time chosen from the data (diagnose's scan) is one more parameter in the BIC of a model with
// damping_drift, and only there: the same fit with the time given by the user differs by exactly
// ln n in BIC (k ln n with one more k) and not in χ²; a model without damping_drift fitted with the
// chosen time in the settings is the plain model (the time acts on nothing, costs nothing).
TEST(CompareIndependent, ChosenStepTimeCountsInTheBicOfItsModelsOnly) {
  const auto r = damping_step_record();
  const auto rig = paper_rig();
  const auto& seg = r.seg;
  rd::ModelFitter given(r.y, seg, rig), chosen(r.y, seg, rig);
  given.set_parameter_settings({{"damping_drift.step_time_s", {0.336, true, false}}});
  chosen.set_parameter_settings({{"damping_drift.step_time_s", {0.336, true, true}}});
  const rd::FitResult g = given.fit({"damping_drift"});
  const rd::FitResult c = chosen.fit({"damping_drift"});
  EXPECT_EQ(c.free_parameters, g.free_parameters + 1);
  EXPECT_DOUBLE_EQ(c.train_chi2, g.train_chi2);
  // Relative 1e-9: the two BICs are sums of the same terms but one ln n, ~1e4 in size.
  EXPECT_NEAR(c.bic - g.bic, std::log(c.train_n), 1e-9 * std::abs(c.bic));
  const rd::FitResult plain = rd::ModelFitter(r.y, seg, rig).fit({});
  const rd::FitResult without = chosen.fit({});
  EXPECT_EQ(without.free_parameters, plain.free_parameters);
  EXPECT_DOUBLE_EQ(without.bic, plain.bic);
}
