// Term discovery (core/diagnosis/term_discovery.hpp, issue 14 item 3) on records of the independent
// generator (tests/support/indep_gear.hpp: its own integrator, Hann pulse and noise; no code shared
// with core/model):
//  * hidden cubic damping (out of the catalogue; 15 s CPU, release only): diagnose with the catalogue only accepts no
//    catalogue effect alone (none, or flagged ambiguous with the discovered force), reports unexplained
//    residual and proposes a force containing v³ with the right sign; the proposal pasted into a rig
//    file (the real CLI: `diagnose --json` then `compare --with discovered_force`) ends with a held-out
//    excess below 0.1 (the error falls);
//  * a 0.1 µm dead zone: the direct fit from the grid's gaps finds gap and coefficient, and the force of
//    that form, fitted with the pulse shape chosen by the training fit, reaches the 0.1 target;
//  * a hidden drift of the mesh stiffness: the proposal contains t_abs·x, stiffening;
//  * a control: no proposal.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "cli_runner.hpp"
#include "core/diagnosis/diagnose.hpp"
#include "core/diagnosis/term_discovery.hpp"
#include "core/model/custom_effect.hpp"
#include "core/model/effect_registry.hpp"
#include "core/model/mesh_dynamics.hpp"
#include "support/indep_gear.hpp"
#include "support/indep_signals.hpp"

namespace rd = ridgewatch::diagnosis;
namespace rm = ridgewatch::model;
namespace ig = ridgewatch::testsupport::indep;

namespace {

constexpr double kRate = 25600.0;  // the rate of ig::short_test_record

rm::RigParameters paper_rig() {
  rm::RigParameters rig;  // config/rigs/paper-rig.yaml
  rig.crack_angle_rad = 1.0;
  return rig;
}

/// Term discovery on the linear model's fit of a record (what diagnose does when nothing passes).
rd::TermDiscoveryResult discover_on_linear_fit(const std::vector<double>& y) {
  const auto rig = paper_rig();
  const auto seg = rd::subset_windows(rd::segment_recording(y, kRate, rig), 16);
  const rd::ModelFitter fitter(y, seg, rig);
  return rd::discover_terms(fitter, fitter.fit({}));
}

const rd::DiscoveredTerm* find_term(const std::vector<rd::DiscoveredTerm>& terms, const std::string& t) {
  for (const auto& d : terms)
    if (d.term == t) return &d;
  return nullptr;
}

[[maybe_unused]] std::string paper_rig_without_model() {  // unused in sanitizer builds (the CLI case is release only)
  std::ifstream f(std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml");
  std::ostringstream s;
  s << f.rdbuf();
  const std::string t = s.str();
  return t.substr(0, t.find("\nmodel:")) + "\n";
}

}  // namespace

// A control of the other generator: no term of the library improves the held-out impacts beyond
// the noise, so nothing is proposed.
TEST(TermDiscovery, ControlGivesNoProposal) {
  const auto rec = ig::generate(ig::short_test_record(ig::Hidden::kNone, 0.0, 3));
  const auto r = discover_on_linear_fit(rec.y);
  EXPECT_FALSE(r.proposed) << r.force;
  // The linearised correction of c0 and ζ alone leaves the control at the noise (0.1: the target).
  EXPECT_LT(std::abs(r.heldout_excess_before), 0.1);
}

// A mesh stiffness drifting over the record (+0.4 %/s of c0, out of the catalogue; frequency drift):
// the term t_abs·x with a negative coefficient (a restoring force growing with time). Truth:
// -0.004 c0 = -3.2e6 N/(m s); the first-order estimate is allowed a factor 2 (it is a start for
// compare's nonlinear refit, and the fitted c0 absorbs part of a drift over a short record).
TEST(TermDiscovery, StiffnessDriftGivesTimeTimesDeflection) {
  auto s = ig::short_test_record(ig::Hidden::kFrequencyDrift, 0.004, 1);
  s.duration_s = 2.0;  // README's drift case: 2 s, 16 impacts spread over it
  const auto rec = ig::generate(s);
  const auto r = discover_on_linear_fit(rec.y);
  ASSERT_TRUE(r.proposed) << r.note;
  const auto* t = find_term(r.terms, "t_abs*x");
  ASSERT_NE(t, nullptr) << r.force;
  EXPECT_LT(t->coefficient, -0.5 * 3.216e6);
  EXPECT_GT(t->coefficient, -2.0 * 3.216e6);
}

// A dead zone in the mesh (the dynamic restoring force vanishes inside |x| < b, linear outside; out
// of the catalogue; b = 20 nm, 2 % of the typical 1 µm response, where the first-order step is still
// close): the library's dead-zone family proposes a_dz · min(max(x, -b_dz), b_dz) with a positive
// coefficient (the spring force lost inside the gap: a_dz = c0 = 8.04e8 N/m at the truth). Allowed:
// a factor 2 on a_dz · b_dz, the force the gap removes (the grid's gap and the coefficient trade off
// to first order).
TEST(TermDiscovery, DeadZoneGivesTheDeadZoneTerm) {
  const auto rec = ig::generate(ig::short_test_record(ig::Hidden::kDeadZone, 2e-8, 1));
  const auto r = discover_on_linear_fit(rec.y);
  const auto* t = find_term(r.terms, "min(max(x, -b_dz), b_dz)");
  ASSERT_NE(t, nullptr) << r.force << " " << r.note;
  EXPECT_GT(t->coefficient * t->gap, 0.5 * 8.04e8 * 2e-8);
  EXPECT_LT(t->coefficient * t->gap, 2.0 * 8.04e8 * 2e-8);
}

#ifndef RIDGEWATCH_SANITIZED

// A 0.1 µm dead zone (the generator's c0 = 8.04e8 N/m lost inside |x| < 1e-7 m) moves the record so
// far from the linear model (held-out excess > 100) that the first-order step picks the wrong gap;
// the direct fit from the grid's gaps finds the gap and the coefficient. 8 impacts (4 fitted).
// Tolerances: 16 impacts on two seeds gave a_dz within 2.2 % and b_dz within 2 % of the truth
// (README); 10 % and 20 % leave room for half the impacts. The excess bound 1 is far below the
// linear model's (> 100) and above the 0.16 measured here (0.50 before the gap between windows was
// integrated and the pulse shape chosen).
TEST(TermDiscovery, DeadZoneFittedFromTheGridFindsGapAndCoefficient) {
  const auto rec = ig::generate(ig::short_test_record(ig::Hidden::kDeadZone, 1e-7, 1));
  const auto rig = paper_rig();
  const auto seg = rd::subset_windows(rd::segment_recording(rec.y, kRate, rig), 8);
  const rd::ModelFitter fitter(rec.y, seg, rig);
  const rd::FitResult linear = fitter.fit({});
  const auto r = rd::fit_dead_zone(fitter, linear);
  ASSERT_TRUE(r.proposed) << r.note;
  ASSERT_EQ(r.terms.size(), 1u);
  EXPECT_NEAR(r.terms[0].coefficient, 8.04e8, 0.1 * 8.04e8);
  EXPECT_NEAR(r.terms[0].gap, 1e-7, 0.2e-7);
  EXPECT_GT(linear.heldout_excess, 100.0);
  EXPECT_LT(r.verified_excess, 1.0);
  EXPECT_EQ(r.definition.kinks, (std::vector<std::string>{"x - b_dz", "x + b_dz"}));
  std::printf("dead zone fitted from the grid: a_dz %.4g, b_dz %.4g, held-out excess %.3g -> %.3g\n",
              r.terms[0].coefficient, r.terms[0].gap, linear.heldout_excess, r.verified_excess);
}

// The dead-zone force in the form term discovery proposes, fitted as compare fits a pasted block (all
// 16 impacts, the pulse shape chosen by the training fit), on a 0.1 µm dead zone of the independent
// generator: the held-out excess must reach the 0.1 target. Two things stood in the way, each
// checked here: between windows the model's tail was decayed in closed form (the linear mesh's),
// while the generator's tail falls into the gap and drifts to rest anywhere in it, which shapes the
// next response (held-out excess 0.2-0.45 with the truth's force); and the generator's Hann pulse
// drives the mesh through the gap while it acts, where a half-sine of fitted length is not the same
// (0.12-0.21 left, mostly in the first ms). Measured with both fixed on the paste sweep's three
// records: -0.02 ... 0.07 (README). Started at the truth: from a_dz = 8e8 (0.5 % low) LM ends in
// another basin at 0.37 (the rest offset the gap integration carries depends steeply on the
// stiffness left inside the gap, c0 - a_dz; README "Term discovery"), so this checks what the model
// can describe, not the search. Tolerances: 3 % on a_dz and b_dz (measured within 0.3 %).
TEST(TermDiscovery, DeadZoneOfTheRightFormFitsToTheNoise) {
  const auto rec = ig::generate(ig::short_test_record(ig::Hidden::kDeadZone, 1e-7, 1));
  const auto rig = paper_rig();
  const auto seg = rd::subset_windows(rd::segment_recording(rec.y, kRate, rig), 16);
  const rd::ModelFitter fitter(rec.y, seg, rig);
  // Defaults (the fit's start) at the truth: a_dz = c0 = 8.04e8 N/m, b_dz = 1e-7 m.
  rm::set_user_effects({{rm::make_custom_effect(rd::dead_zone_definition("dead_zone", 8.04e8, 1e-7)), {}}});
  const auto f = rd::fit_pulse_shapes(fitter, {"dead_zone"});
  rm::set_user_effects({});
  double a = 0.0, b = 0.0;
  for (const auto& e : f.estimates) {
    if (e.name == "dead_zone.a_dz") a = e.value;
    if (e.name == "dead_zone.b_dz") b = e.value;
  }
  std::printf("dead zone of the right form: pulse %s, a_dz %.4g, b_dz %.4g, held-out excess %.3g\n",
              rm::to_string(f.params.pulse_shape), a, b, f.heldout_excess);
  EXPECT_LT(f.heldout_excess, 0.1);
  EXPECT_NEAR(a, 8.04e8, 0.03 * 8.04e8);
  EXPECT_NEAR(b, 1e-7, 0.03e-7);
}

// Hidden cubic damping (7e8 N s³/m³: at the impact's peak velocity 3.5x the linear damping force), end to end through the CLI as a user would: diagnose proposes
// a v³ term; the YAML it prints, pasted into the rig file, makes compare's held-out excess < 0.1.
TEST(TermDiscovery, CubicDampingProposalPastedMakesTheErrorFall) {
  const auto rec = ig::generate(ig::short_test_record(ig::Hidden::kCubicDamping, 7e8, 2));
  const auto dir = std::filesystem::temp_directory_path() / ("ridgewatch-term-discovery-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string wav = (dir / "cubic.wav").string();
  indep::write_wav_mono(wav, rec.y, kRate, indep::SampleFormat::float32);
  const std::string rig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";

  // 8 impacts (4 fitted, 4 held out): half the time of the default 16, and the v³ term still passes
  // every gate at this size.
  const auto d = ridgewatch::test::run_cli({"diagnose", "--rig", rig, wav, "--json", "--quiet", "--max-impacts", "8"});
  ASSERT_EQ(d.exit_code, 0) << d.err;
  const auto j = nlohmann::json::parse(d.out);
  EXPECT_TRUE(j["unexplained"]["present"].get<bool>());
  // No catalogue effect named alone: either none accepted, or the accepted ones flagged ambiguous
  // with the discovered force.
  const auto verdict = j["verdict"].get<std::vector<std::string>>();
  const auto ambiguous = j["ambiguous"].get<std::vector<std::string>>();
  for (const auto& v : verdict) EXPECT_NE(std::find(ambiguous.begin(), ambiguous.end(), v), ambiguous.end()) << v;
  ASSERT_TRUE(j["proposed"].is_object());
  ASSERT_TRUE(j["proposed"]["present"].get<bool>()) << j["proposed"].dump();
  bool has_v3 = false;
  for (const auto& t : j["proposed"]["terms"])
    if (t["term"] == "v^3") {
      has_v3 = true;
      EXPECT_LT(t["coefficient"].get<double>(), 0.0);  // opposes the motion
    }
  EXPECT_TRUE(has_v3) << j["proposed"].dump();
  EXPECT_GT(j["proposed"]["heldout_gain"].get<double>(), j["proposed"]["required_gain"].get<double>());

  // Paste: the paper rig with the proposed block as its model section.
  const std::string pasted = (dir / "rig-discovered.yaml").string();
  std::ofstream(pasted) << paper_rig_without_model() << j["proposed"]["yaml"].get<std::string>();
  const auto before = ridgewatch::test::run_cli({"compare", "--rig", rig, wav, "--json"});
  std::vector<std::string> args = {"compare", "--rig", pasted, wav, "--json"};
  for (const auto& e : j["proposed"]["base_effects"]) args.insert(args.end(), {"--with", e.get<std::string>()});
  args.insert(args.end(), {"--with", j["proposed"]["effect"].get<std::string>()});
  const auto after = ridgewatch::test::run_cli(args);
  std::filesystem::remove_all(dir);
  ASSERT_EQ(before.exit_code, 0) << before.err;
  ASSERT_EQ(after.exit_code, 0) << after.err;
  const double ex_before = nlohmann::json::parse(before.out)["heldout_excess"].get<double>();
  const double ex_after = nlohmann::json::parse(after.out)["heldout_excess"].get<double>();
  EXPECT_GT(ex_before, 0.5);  // the linear model leaves clear structure (4.3 on the README walkthrough)
  EXPECT_LT(ex_after, 0.1);   // the acceptance target: nothing left above the noise
}
#endif

// Whether the rig describes a record is judged on the best description diagnose found. On the
// independent generator's cubic damping the catalogue's approximation (quadratic damping + friction)
// drives ζ to its 1e-4 bound, and diagnose exited 3, "the rig does not describe this record", although
// the discovered force on the starting model superseded that fit (listed as ambiguous with it) and
// explains the record. The superseding proposal's own fit is the one judged; without the ambiguity
// (the proposal only adds to the accepted effects) the final fit is.
TEST(TermDiscovery, SupersedingProposalIsTheDescriptionJudged) {
  rd::DiagnoseResult r;
  r.verdict = {"quadratic_damping", "coulomb_friction"};
  r.final_fit.estimates.push_back({"zeta", 1e-4, 0.0, 1e-4, 1e-4, true});
  r.proposal.proposed = true;
  r.proposal.definition.name = "discovered_force";
  r.proposal.verified_fit.estimates.push_back({"zeta", 0.024, 1e-4, 0.0238, 0.0242, false});
  EXPECT_EQ(&rd::best_description(r), &r.final_fit);
  r.ambiguous = {"quadratic_damping", "coulomb_friction", "discovered_force"};
  EXPECT_EQ(&rd::best_description(r), &r.proposal.verified_fit);
  r.proposal.proposed = false;  // withdrawn by its own gate: nothing supersedes the catalogue fit
  EXPECT_EQ(&rd::best_description(r), &r.final_fit);
}
