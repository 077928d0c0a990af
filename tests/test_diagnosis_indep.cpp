// diagnose/compare on records that ridgewatch's simulator did not make (issue 14): the independent
// gear-rig generator tests/support/indep_gear.hpp (own integrator, Hann impact pulse, own noise and
// conventions). The full confusion matrix (every hidden effect, several seeds) is
// `bench_diagnose indep`; here one seed of the cases the issue found wrong, plus the 930 Hz second
// mode on ridgewatch's own simulator and a record of another structure.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>
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

rd::DiagnoseResult run(const std::vector<double>& y, const rm::RigParameters& rig) {
  const auto seg = rd::subset_windows(rd::segment_recording(y, kRate, rig), 16);
  EXPECT_GE(seg.windows.size(), 14u);
  const rd::ModelFitter fitter(y, seg, rig);
  return rd::diagnose(fitter, {});
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
