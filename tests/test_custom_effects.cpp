// User-defined effects (rig file model.custom_effects, core/model/custom_effect.hpp): load-time
// errors name the file, the effect and the column; a custom force equal to a catalogue effect
// simulates the same record; `--with NAME:key=value!` fixes a parameter; and on a record with a hidden
// effect that is not in the catalogue (a mesh stiffness drifting over the record, e.g. with
// temperature) diagnose without the custom effect accepts nothing and reports unexplained residual,
// with it accepts the custom effect, recovers its size and the held-out excess falls below 0.1.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "app/args.hpp"
#include "app/rig_yaml.hpp"
#include "cli_runner.hpp"
#include "core/diagnosis/diagnose.hpp"
#include "core/diagnosis/impact_model.hpp"
#include "core/model/custom_effect.hpp"
#include "core/model/effect_registry.hpp"
#include "core/model/simulator.hpp"
#include "support/indep_gear.hpp"

namespace rd = ridgewatch::diagnosis;
namespace rm = ridgewatch::model;
namespace rc = ridgewatch::app;

namespace {

std::string paper_rig_text() {
  std::ifstream f(std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml");
  std::ostringstream s;
  s << f.rdbuf();
  std::string t = s.str();
  return t.substr(0, t.find("\nmodel:")) + "\n";
}

std::string rig_with(const std::string& force, const std::string& params) {
  return paper_rig_text() + "model:\n  custom_effects:\n    - name: my_force\n      force: \"" + force +
         "\"\n      parameters:\n" + params;
}

const std::string kParamC3 = "        c3: {unit: \"N s^3/m^3\", min: 0, max: 1e11, default: 0, null: 0}\n";

std::string load_error(const std::string& text) {
  try {
    rc::parse_rig_yaml(text, "rig.yaml");
  } catch (const rc::UsageError& e) {
    return e.what();
  }
  return "";
}

TEST(CustomEffects, LoadErrorsNameFileEffectAndColumn) {
  // Unknown variable 'y' at column 13 of "-c3 * v^3 + y" (1-based; counted by hand).
  std::string e = load_error(rig_with("-c3 * v^3 + y", kParamC3));
  EXPECT_NE(e.find("rig.yaml: model.custom_effects[0]: effect my_force: force:"), std::string::npos) << e;
  EXPECT_NE(e.find("column 13"), std::string::npos) << e;
  EXPECT_NE(e.find("'y'"), std::string::npos) << e;
  // Syntax error: the missing parenthesis is reported at the end of the text.
  e = load_error(rig_with("-c3 * (v^3", kParamC3));
  EXPECT_NE(e.find("effect my_force: force:"), std::string::npos) << e;
  EXPECT_NE(e.find("arenthes"), std::string::npos) << e;
  // Non-finite at rest (v = 0 is on the check grid).
  e = load_error(rig_with("-c3 / v", kParamC3));
  EXPECT_NE(e.find("not finite"), std::string::npos) << e;
  // A catalogue name, a parameter named like a variable, a default outside the range, the key null.
  std::string t = rig_with("-c3 * v", kParamC3);
  t.replace(t.find("name: my_force"), 14, "name: coulomb_friction");
  EXPECT_NE(load_error(t).find("is a catalogue effect"), std::string::npos);
  EXPECT_NE(load_error(rig_with("-x * v", "        x: {min: 0, max: 1, default: 0}\n")).find("is a variable"), std::string::npos);
  EXPECT_NE(load_error(rig_with("-c3 * v", "        c3: {min: 0, max: 1, default: 2}\n")).find("default 2 is outside"),
            std::string::npos);
  EXPECT_NE(load_error(rig_with("-c3 * v", "        c3: {min: 0, max: 1, default: 0, nul: 0}\n")).find("unknown key"),
            std::string::npos);
  // A valid file defines the effect for this thread; a file without custom effects removes it.
  const rc::RigConfig ok = rc::parse_rig_yaml(rig_with("-c3 * v^3", kParamC3), "rig.yaml");
  ASSERT_EQ(ok.custom_effects.size(), 1u);
  EXPECT_NE(rm::find_effect("my_force"), nullptr);
  EXPECT_NE(rd::find_candidate("my_force"), nullptr);
  rc::parse_rig_yaml(paper_rig_text(), "rig.yaml");
  EXPECT_EQ(rm::find_effect("my_force"), nullptr);
}

TEST(CustomEffects, CliExitsTwoOnABadExpression) {
  const auto path = std::filesystem::temp_directory_path() / ("ridgewatch-custom-" + std::to_string(::getpid()) + ".yaml");
  std::ofstream(path) << rig_with("-c3 * v^3 + y", kParamC3);
  const auto r = ridgewatch::test::run_cli({"simulate", "--rig", path.string(), "--out", path.string() + ".out"});
  std::filesystem::remove(path);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("effect my_force: force:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("column 13"), std::string::npos) << r.err;
}

// quadratic_damping's force as a user-defined effect "squeeze" with one parameter d2 (N s²/m²),
// registered for this thread; each test that registers it clears the list at its end.
void register_squeeze() {
  rm::CustomEffectDefinition def;
  def.name = "squeeze";
  def.force = "-d2 * v * abs(v)";
  def.parameters = {{"d2", "N s^2/m^2", 0.0, 1e9, 0.0, 0.0, ""}};
  rm::set_user_effects({{rm::make_custom_effect(def), {}}});
}

TEST(CustomEffects, ForceEqualToACatalogueEffectSimulatesTheSameRecord) {
  // quadratic_damping's force d2 q'|q'| (core/model/effects/quadratic_damping.cpp, a separate C++
  // implementation) written as an expression: both go through the same integrator, so the records
  // agree to rounding (1e-9 of the peak: muparser's byte code and the C++ differ in the order of
  // the multiplications only).
  register_squeeze();
  rm::RigParameters rig;
  rm::SimulationSettings s;
  s.duration_s = 0.2;
  s.sample_rate_hz = 25600.0;
  const auto a = rm::simulate(rig, {{"quadratic_damping", {{"coefficient_n_s2_per_m2", 3e6}}}}, s);
  const auto b = rm::simulate(rig, {{"squeeze", {{"d2", 3e6}}}}, s);
  const auto lin = rm::simulate(rig, {}, s);
  ASSERT_EQ(a.output.size(), b.output.size());
  double max_diff = 0.0, max_effect = 0.0;
  for (std::size_t i = 0; i < a.output.size(); ++i) {
    max_diff = std::max(max_diff, std::abs(a.output[i] - b.output[i]));
    max_effect = std::max(max_effect, std::abs(a.output[i] - lin.output[i]));
  }
  EXPECT_GT(max_effect, 0.01 * a.clean_peak);  // the effect is visible at all
  EXPECT_LT(max_diff, 1e-9 * a.clean_peak);
  rm::set_user_effects({});
}

// The fit's window model (core/diagnosis/impact_model.hpp) at the simulation's true values
// reproduces a record simulated with a user-defined force that uses every variable (v, x, the mesh
// angle θ and the time since the impact t): both run the one integrator of Eq. A1/A2
// (core/model/mesh_dynamics.hpp), so the force acts identically in `simulate` and in the fit.
// Independent check: the simulator's own record, its impact time and force, and the window model's
// conventions (mesh angle φ_z = z1 × crack angle at the impact, steady state, no carried tail).
double window_vs_simulation(double rate_hz, double& peak) {
  rm::CustomEffectDefinition def;
  def.name = "mixed_force";
  def.force = "-c3 * v^3 - k1 * x * cos(theta) - d1 * v * exp(-t / 0.004)";
  def.parameters = {{"c3", "N s^3/m^3", 0.0, 1e11, 0.0, 0.0, ""},
                    {"k1", "N/m", 0.0, 1e9, 0.0, 0.0, ""},
                    {"d1", "N s/m", 0.0, 1e6, 0.0, 0.0, ""}};
  rm::set_user_effects({{rm::make_custom_effect(def), {}}});
  const rm::EffectValues truth = {{"c3", 2e9}, {"k1", 6e7}, {"d1", 2e3}};
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  rm::SimulationSettings s;
  s.sample_rate_hz = rate_hz;
  s.duration_s = 0.04;  // one impact (at 6.4 ms; the next would come 40 ms later)
  const auto sim = rm::simulate(rig, {{"mixed_force", truth}}, s);
  const auto lin = rm::simulate(rig, {}, s);
  EXPECT_EQ(sim.impacts.size(), 1u);
  if (sim.impacts.empty()) return INFINITY;
  rd::PhysicsValues phys;
  phys.c0_n_per_m = rig.mean_mesh_stiffness_n_per_m;
  phys.zeta = rig.damping_ratio;
  phys.mesh_phase_rad = rig.pinion_teeth * rig.crack_angle_rad;  // θ_z at the impact
  phys.pulse_s = rig.impact_duration_s;
  phys.effects = {{"mixed_force", truth}};
  const rd::WindowSimulator win(rig, phys, rate_hz);
  const auto first = static_cast<std::uint64_t>(std::floor((sim.impacts[0].t_s - 0.001) * rate_hz));
  const std::size_t n = sim.output.size() - first;
  std::vector<double> model(n);
  rd::WindowSimulator::End end;
  win.simulate(first, n, {sim.impacts[0].t_s, sim.impacts[0].peak_force_n, rig.mesh_frequency_hz(), 1.0}, {},
               model.data(), end);
  double max_diff = 0.0, max_effect = 0.0;
  peak = sim.clean_peak;
  for (std::size_t i = 0; i < n; ++i) {
    max_diff = std::max(max_diff, std::abs(model[i] - sim.clean_output[first + i]));
    max_effect = std::max(max_effect, std::abs(sim.clean_output[first + i] - lin.clean_output[first + i]));
  }
  EXPECT_GT(max_effect, 0.05 * peak);  // the force changes the response visibly
  rm::set_user_effects({});
  return max_diff;
}

TEST(CustomEffects, SimulateAndTheFitsWindowModelIntegrateTheSameForce) {
  // At 200 kHz both take the same RK4 steps (the simulator one per sample, the fit ω h = 0.027 <=
  // 0.25, one per sample): what differs is rounding (the mesh angle from the state vs the window's
  // phase, the time since the impact), measured 6e-15 of the peak; 1e-9 leaves margin.
  double peak = 0.0;
  const double same_steps = window_vs_simulation(200000.0, peak);
  EXPECT_LT(same_steps, 1e-9 * peak);
  // At 51.2 kHz the fit steps once per sample (ω h = 0.105), the simulator four times: the records
  // differ by RK4's error at the fit's step, a phase lag of about n (ωh)^5/120 = 1.6e-4 rad after
  // the 1700 steps of the window (measured 4e-5 of the peak); 1e-3 bounds it with margin.
  const double fit_steps = window_vs_simulation(51200.0, peak);
  EXPECT_LT(fit_steps, 1e-3 * peak);
  std::printf("window model vs simulate: %.3g (200 kHz), %.3g (51.2 kHz) of the peak\n", same_steps / peak, fit_steps / peak);
}

TEST(CustomEffects, KinkErrorsNameTheKinkAndColumn) {
  // model.custom_effects[0].kinks: checked like the force (unknown name 'q' at column 5 of "x - q",
  // counted by hand), and the key must be a list of strings.
  const std::string params = "        b: {unit: \"m\", min: 0, max: 1e-5, default: 1e-7, null: 0}\n";
  const std::string base = rig_with("-1e8 * min(max(x, -b), b)", params);
  std::string e = load_error(base + "      kinks: [\"x + b\", \"x - q\"]\n");
  EXPECT_NE(e.find("rig.yaml: model.custom_effects[0]: effect my_force: kinks[1]:"), std::string::npos) << e;
  EXPECT_NE(e.find("column 5"), std::string::npos) << e;
  EXPECT_NE(e.find("'q'"), std::string::npos) << e;
  e = load_error(base + "      kinks: \"x - b\"\n");
  EXPECT_NE(e.find("model.custom_effects[0].kinks: must be a list"), std::string::npos) << e;
  EXPECT_NE(load_error(base + "      kinks: [\"x / 0\"]\n").find("kinks[0]: 'x / 0' is not finite"), std::string::npos);
  EXPECT_EQ(load_error(base + "      kinks: [\"x - b\", \"x + b\"]\n"), "");
  rm::set_user_effects({});
}

// A dead zone (the spring force a_dz · min(max(x, -b), b) lost inside |x| < b, b = 0.1 µm, a_dz = c0:
// the mesh carries no dynamic force there, the independent generator's hidden dead zone) written
// with and without its kinks: RK4 at one step per sample (25.6 kHz, ω h = 0.24 as in the fit) steps
// over the kink at |x| = b without them, and loses its order there. Reference: the same force at 128
// steps per sample (3.3 MHz) with its kinks located.
double dead_zone_error(bool kinks, double& peak, std::uint64_t& events) {
  rm::CustomEffectDefinition def;
  def.name = "dead_zone";
  def.force = "a_dz * min(max(x, -b_dz), b_dz)";
  def.parameters = {{"a_dz", "N/m", 0.0, 1e10, 0.0, 0.0, ""}, {"b_dz", "m", 0.0, 1e-5, 1e-7, 0.0, ""}};
  rm::CustomEffectDefinition located = def;
  located.name = "dead_zone_located";
  located.kinks = {"x - b_dz", "x + b_dz"};
  rm::set_user_effects({{rm::make_custom_effect(def), {}}, {rm::make_custom_effect(located), {}}});
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  const rm::EffectValues truth = {{"a_dz", rig.mean_mesh_stiffness_n_per_m}, {"b_dz", 1e-7}};
  rm::SimulationSettings s;
  s.sample_rate_hz = 25600.0;
  s.duration_s = 0.04;  // one impact and its decay
  s.min_internal_rate_hz = s.sample_rate_hz;
  const auto run = rm::simulate(rig, {{kinks ? "dead_zone_located" : "dead_zone", truth}}, s);
  s.min_internal_rate_hz = 128.0 * s.sample_rate_hz;
  const auto ref = rm::simulate(rig, {{"dead_zone_located", truth}}, s);
  const auto lin = rm::simulate(rig, {}, s);
  rm::set_user_effects({});
  double max_diff = 0.0, max_effect = 0.0;
  for (std::size_t i = 0; i < ref.clean_output.size(); ++i) {
    max_diff = std::max(max_diff, std::abs(run.clean_output[i] - ref.clean_output[i]));
    max_effect = std::max(max_effect, std::abs(ref.clean_output[i] - lin.clean_output[i]));
  }
  peak = ref.clean_peak;
  events = run.located_events;
  EXPECT_GT(max_effect, 0.05 * peak);  // the dead zone changes the response visibly
  return max_diff;
}

TEST(CustomEffects, DeclaredKinksAreLocatedByTheIntegrator) {
  double peak = 0.0;
  std::uint64_t ev_plain = 0, ev_located = 0;
  const double plain = dead_zone_error(false, peak, ev_plain);
  const double located = dead_zone_error(true, peak, ev_located);
  std::printf("dead zone at 25.6 kHz vs 3.3 MHz: %.3g of the peak stepping over the kinks, %.3g located (%llu events)\n",
              plain / peak, located / peak, static_cast<unsigned long long>(ev_located));
  EXPECT_EQ(ev_plain, 0u);
  EXPECT_GT(ev_located, 10u);  // two kinks per half-cycle of the decaying response
  EXPECT_LT(located, 0.2 * plain);
}

// A mesh stiffness drifting linearly over the record (f0 +1 % per second, e.g. warming): not in the
// catalogue. 25.6 kHz, 1 % noise, 8 impacts over a 1 s record.
struct DriftRecord {
  rm::RigParameters rig;
  std::vector<double> y;
  rd::Segmentation seg;
};

constexpr double kDriftTruth = 1.6e7;  // N/(m s): Δc0 = 2 % over 1 s

rm::UserEffect drift_effect() {
  rm::CustomEffectDefinition def;
  def.name = "stiffness_drift";
  def.force = "-kd * t_abs * x";
  def.parameters = {{"kd", "N/(m s)", -1e9, 1e9, 0.0, 0.0, ""}};
  return {rm::make_custom_effect(def), {}};
}

DriftRecord drift_record() {
  DriftRecord r;
  r.rig.crack_angle_rad = 1.0;
  rm::set_user_effects({drift_effect()});
  rm::SimulationSettings s;
  s.sample_rate_hz = 25600.0;
  s.duration_s = 1.0;
  s.seed = 3;
  const auto sim = rm::simulate(r.rig, {{"stiffness_drift", {{"kd", kDriftTruth}}}, {"noise", {{"std_rel", 0.01}}}}, s);
  r.y = sim.output;
  r.seg = rd::subset_windows(rd::segment_recording(r.y, s.sample_rate_hz, r.rig), 8);
  return r;
}

TEST(CustomEffects, FixedParameterIsNotFittedAndActs) {
  const DriftRecord r = drift_record();
  ASSERT_GE(r.seg.windows.size(), 8u);
  rd::ModelFitter fitter(r.y, r.seg, r.rig);
  // Unknown key, out of range: refused.
  EXPECT_THROW(fitter.set_parameter_settings({{"stiffness_drift.k", {1.0, true}}}), std::invalid_argument);
  EXPECT_THROW(fitter.set_parameter_settings({{"stiffness_drift.kd", {5e9, true}}}), std::invalid_argument);
  fitter.set_parameter_settings({{"stiffness_drift.kd", {kDriftTruth, true}}});
  const rd::FitResult at_truth = fitter.fit({"stiffness_drift"});
  for (const auto& e : at_truth.estimates) EXPECT_NE(e.name, "stiffness_drift.kd");  // not fitted
  fitter.set_parameter_settings({{"stiffness_drift.kd", {0.0, true}}});
  const rd::FitResult at_zero = fitter.fit({"stiffness_drift"});
  // Fixed at the truth the model is right (excess at the noise: < 0.1, the loop's target); fixed at
  // zero it is the linear model, which misses the drift (excess > 1 measured; 0.5 leaves margin).
  EXPECT_LT(at_truth.heldout_excess, 0.1);
  EXPECT_GT(at_zero.heldout_excess, 0.5);
  rm::set_user_effects({});
}

TEST(CustomEffects, DiagnoseFindsAHiddenEffectOnlyWithTheCustomEffect) {
  const DriftRecord r = drift_record();
  ASSERT_GE(r.seg.windows.size(), 8u);
  const rd::ModelFitter fitter(r.y, r.seg, r.rig);
  rd::DiagnoseOptions opt;
  opt.max_rounds = 1;
#ifndef RIDGEWATCH_SANITIZED
  {
    // Without it: every catalogue candidate tried, none accepted, the residual unexplained.
    rm::set_user_effects({});
    const rd::DiagnoseResult without = rd::diagnose(fitter, {}, opt);
    EXPECT_TRUE(without.verdict.empty());
    EXPECT_TRUE(without.unexplained);
    EXPECT_GT(without.final_excess, 0.5);
  }
#endif
  // With it (and the two catalogue effects nearest in kind, a drift and an amplitude-dependent
  // frequency, as rivals): the custom effect is accepted and the error falls below the target.
  rm::set_user_effects({drift_effect()});
  opt.candidates = {"damping_drift", "stiffness_nonlinearity", "stiffness_drift"};
  const rd::DiagnoseResult with = rd::diagnose(fitter, {}, opt);
  ASSERT_EQ(with.verdict, std::vector<std::string>{"stiffness_drift"});
  EXPECT_GT(with.baseline_excess, 0.5);
  EXPECT_LT(with.final_excess, 0.1);
  EXPECT_FALSE(with.unexplained);
  // Its size: within 5 % of the truth (measured 1.56e7, 95 % interval ±2 %; the rest is the
  // window model's approximations, e.g. the steady state and the carried tail ignore the drift).
  bool found = false;
  for (const auto& e : with.final_fit.estimates) {
    if (e.name != "stiffness_drift.kd") continue;
    found = true;
    EXPECT_NEAR(e.value, kDriftTruth, 0.05 * kDriftTruth);
  }
  EXPECT_TRUE(found);
  rm::set_user_effects({});
}

}  // namespace

namespace {

TEST(CustomEffects, CliSimulateCompareWithFixedValueAndDiagnoseProgress) {
  // The whole path as a user runs it: a rig file with the custom effect, `simulate --effect`,
  // `compare --with NAME:key=value!` (fixed), bad --with values (exit 2), and diagnose's progress
  // lines on stderr (none with --quiet). 0.5 s at 25.6 kHz, 4 impacts: the loop's smallest run.
  const auto dir = std::filesystem::temp_directory_path() / ("ridgewatch-custom-cli-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string rig = (dir / "rig.yaml").string();
  std::ofstream(rig) << paper_rig_text()
                     << "model:\n  custom_effects:\n    - name: stiffness_drift\n      force: \"-kd * t_abs * x\"\n"
                        "      parameters:\n        kd: {unit: \"N/(m s)\", min: -1e9, max: 1e9, default: 0, null: 0}\n";
  const std::string base = (dir / "rec").string();
  using ridgewatch::test::run_cli;
  auto r = run_cli({"simulate", "--rig", rig, "--effect", "stiffness_drift:kd=1.6e7", "--noise", "0.01", "--duration", "0.5",
                    "--rate", "25600", "--out", base});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = run_cli({"compare", "--rig", rig, base + ".wav", "--with", "stiffness_drift:kd=1.6e7!", "--json"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("\"fixed_parameters\":{\"stiffness_drift.kd\":16000000.0}"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("\"name\":\"stiffness_drift.kd\""), std::string::npos);  // not among the fitted
  r = run_cli({"compare", "--rig", rig, base + ".wav", "--with", "stiffness_drift:k=1"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("'k' is not a fitted parameter (fitted: kd)"), std::string::npos) << r.err;
  r = run_cli({"compare", "--rig", rig, base + ".wav", "--with", "stiffness_drift:kd=x!"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("kd: 'x' is not a number"), std::string::npos) << r.err;
  r = run_cli({"diagnose", "--rig", rig, base + ".wav", "--with", "stiffness_drift", "--max-impacts", "4"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("diagnose: ["), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("round 1: fitting coulomb_friction"), std::string::npos) << r.err;
  EXPECT_NE(r.out.find("model [stiffness_drift]"), std::string::npos) << r.out;
#ifndef RIDGEWATCH_SANITIZED  // the same run again, only the flag differs
  r = run_cli({"diagnose", "--rig", rig, base + ".wav", "--with", "stiffness_drift", "--max-impacts", "4", "--quiet"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err.find("diagnose: ["), std::string::npos) << r.err;
#endif
  std::filesystem::remove_all(dir);
}

}  // namespace

namespace {

TEST(CustomEffects, DuplicateOfACatalogueEffectFitsTheSameParameters) {
  // quadratic_damping (2e6 N s²/m², the README sweep's size) hidden; the fit with the catalogue
  // effect and the fit with the same force as an expression must agree: each value inside the
  // other's 95 % interval (they differ only in the log range's lower end and the start).
  register_squeeze();
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  rm::SimulationSettings s;
  s.sample_rate_hz = 25600.0;
  s.duration_s = 0.5;
  s.seed = 2;
  const auto sim = rm::simulate(rig, {{"quadratic_damping", {{"coefficient_n_s2_per_m2", 2e6}}}, {"noise", {{"std_rel", 0.01}}}}, s);
  const auto seg = rd::subset_windows(rd::segment_recording(sim.output, s.sample_rate_hz, rig), 8);
  ASSERT_GE(seg.windows.size(), 8u);
  const rd::ModelFitter fitter(sim.output, seg, rig);
  const rd::FitResult a = fitter.fit({"quadratic_damping"});
  const rd::FitResult b = fitter.fit({"squeeze"});
  auto find = [](const rd::FitResult& f, const std::string& n) {
    for (const auto& e : f.estimates)
      if (e.name == n) return e;
    ADD_FAILURE() << n;
    return rd::ParameterEstimate{};
  };
  const auto qa = find(a, "quadratic_damping.coefficient_n_s2_per_m2"), qb = find(b, "squeeze.d2");
  EXPECT_GE(qa.value, qb.ci95_lo);
  EXPECT_LE(qa.value, qb.ci95_hi);
  EXPECT_GE(qb.value, qa.ci95_lo);
  EXPECT_LE(qb.value, qa.ci95_hi);
  EXPECT_NEAR(a.heldout_excess, b.heldout_excess, 0.01);  // same model: same held-out error
  rm::set_user_effects({});
}

}  // namespace

#ifndef RIDGEWATCH_SANITIZED
// Hidden cubic damping from the independent generator (tests/support/indep_gear.hpp, 2 s at 25.6 kHz,
// 1 % noise, seed 1, 16 impacts; README "User-defined effects"), the user-defined cubic_damping the
// only candidate: the candidate fit must not stop where the linear model's ζ (twice the truth, it
// absorbed the cubic damping) counts the damping twice. That warm-only fit ended at held-out excess
// 0.26 with c3 = 1.91e9 and an interval (1.89e9 .. 1.94e9) that missed the truth 2e9. Required: below
// the 0.1 target and the 95 % interval covering the truth.
TEST(CustomEffects, CubicDampingCandidateIsNotStuckAtTheLinearModelsDamping) {
  namespace ig = ridgewatch::testsupport::indep;
  auto st = ig::short_test_record(ig::Hidden::kCubicDamping, 2e9, 1);
  st.duration_s = 2.0;
  const auto rec = ig::generate(st);
  rm::RigParameters rig;
  rig.crack_angle_rad = 1.0;
  const auto seg = rd::subset_windows(rd::segment_recording(rec.y, st.sample_rate_hz, rig), 16);
  const rd::ModelFitter fitter(rec.y, seg, rig);
  rm::set_user_effects({{rm::make_custom_effect({"cubic_damping", "-c3 * v^3", {{"c3", "N s^3/m^3", 0.0, 1e11, 0.0, 0.0, ""}}, {}, {}}), {}}});
  rd::DiagnoseOptions opt;
  opt.max_rounds = 1;
  opt.candidates = {"cubic_damping"};
  opt.discover_terms = false;
  const rd::DiagnoseResult r = rd::diagnose(fitter, {}, opt);
  rm::set_user_effects({});
  ASSERT_EQ(r.verdict, std::vector<std::string>{"cubic_damping"});
  EXPECT_LT(r.final_excess, 0.1);
  bool found = false;
  for (const auto& e : r.final_fit.estimates) {
    if (e.name != "cubic_damping.c3") continue;
    found = true;
    EXPECT_LE(e.ci95_lo, 2e9);
    EXPECT_GE(e.ci95_hi, 2e9);
  }
  EXPECT_TRUE(found);
}
#endif
