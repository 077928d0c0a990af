// `ridgewatch compare` end to end on bundled replay data (issue 5).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_runner.hpp"

using ridgewatch::test::run_cli;

namespace {
const std::string kRig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";
const std::string kData = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/";

// A short simulated recording (as replay-data/generate.sh makes them, 25.6 kHz, seed 1) in the temp
// directory: the bundled 2 s files (50 impacts) cost 2-3 minutes per test under ASan, and what these
// tests check does not need 50 impacts. Returns the WAV path.
std::string simulate_fixture(const std::string& name, std::vector<std::string> args) {
  const auto stem = std::filesystem::temp_directory_path() / ("rw-compare-" + name + "-" + std::to_string(::getpid()));
  std::vector<std::string> cmd = {"simulate", "--rig", kRig, "--rate", "25600", "--seed", "1", "--out", stem.string()};
  cmd.insert(cmd.end(), args.begin(), args.end());
  const auto r = run_cli(cmd);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  return stem.string() + ".wav";
}
void remove_fixture(const std::string& wav) {
  std::filesystem::remove(wav);
  std::filesystem::remove(wav.substr(0, wav.size() - 4) + ".truth.json");
}
}  // namespace

TEST(CompareCli, BaselineFitsToTheNoiseFloorWithNominalC0) {
  // sim-baseline-noise-0.5pct shortened to 0.8 s: 20 impacts.
  const std::string file = simulate_fixture("baseline", {"--duration", "0.8", "--noise", "0.005"});
  const auto r = run_cli({"compare", "--rig", kRig, file, "--json"});
  remove_fixture(file);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  // Simulated with the nominal rig: the fitted c0 within 0.05 % of it (its 95 % interval is ~1e-4
  // wide at 0.5 % noise with 10 fitted impacts), and nothing left above the noise floor.
  EXPECT_NEAR(j["c0"]["relative_gap"].get<double>(), 0.0, 5e-4);
  EXPECT_LT(std::abs(j["heldout_excess"].get<double>()), 0.1);
  EXPECT_GT(j["fit_percent"].get<double>(), 90.0);
  EXPECT_TRUE(j["residual"]["whiteness"]["white"].get<bool>());
  EXPECT_EQ(j["impacts"]["total"].get<int>(), 20);
  EXPECT_TRUE(j["residual"]["spectrum"]["markers"].contains("f0+1fz"));
}

TEST(CompareCli, MissingDampingChangeShowsAndWithDriftShrinks) {
  // Like sim-damping-step on 1 s: ζ steps 0.024 -> 0.030 at t = 0.5 s, noise 0.5 %, 25 impacts. A
  // constant-ζ model leaves a large held-out excess; adding damping_drift (a linear trend, the
  // catalogue's nearest description) must at least halve it and find ζ rising (measured: 6.8 -> 1.8,
  // rate 0.0083 per s).
  const std::string file = simulate_fixture("damping-step", {"--duration", "1", "--noise", "0.005", "--effect",
                                                             "damping_drift:rate_per_s=0,step=0.006,step_time_s=0.5"});
  const auto base = run_cli({"compare", "--rig", kRig, file, "--json"});
  const auto with = run_cli({"compare", "--rig", kRig, file, "--with", "damping_drift", "--json"});
  remove_fixture(file);
  ASSERT_EQ(base.exit_code, 0) << base.err;
  ASSERT_EQ(with.exit_code, 0) << with.err;
  const auto jb = nlohmann::json::parse(base.out), jw = nlohmann::json::parse(with.out);
  EXPECT_GT(jb["heldout_excess"].get<double>(), 5.0);
  EXPECT_LT(jw["heldout_excess"].get<double>(), 0.5 * jb["heldout_excess"].get<double>());
  bool found = false;
  for (const auto& p : jw["parameters"])
    if (p["name"] == "damping_drift.rate_per_s") {
      found = true;
      EXPECT_GT(p["ci95"][0].get<double>(), 0.0);
    }
  EXPECT_TRUE(found);
}

TEST(CompareCli, TextSummaryAndErrors) {
  const std::string file = simulate_fixture("noise-3pct", {"--duration", "0.8", "--noise", "0.03"});
  const auto r = run_cli({"compare", "--rig", kRig, file});
  remove_fixture(file);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("held-out excess"), std::string::npos);
  EXPECT_NE(r.out.find("c0"), std::string::npos);
  EXPECT_EQ(run_cli({"compare", kData + "sim-baseline.wav"}).exit_code, 2);  // no --rig
  EXPECT_EQ(run_cli({"compare", "--rig", kRig, kData + "sim-baseline.wav", "--with", "hum"}).exit_code, 2);
  EXPECT_EQ(run_cli({"compare", "--rig", kRig, kData + "does-not-exist.wav"}).exit_code, 3);
}
