// `ridgewatch diagnose` end to end: JSON contract, history file, spikes as a sensor problem (issue 5).
#include <gtest/gtest.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_runner.hpp"

using ridgewatch::test::run_cli;
using ridgewatch::test::slurp;

namespace {
const std::string kRig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";
const std::string kData = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/";
}  // namespace

TEST(DiagnoseCli, BaselineNoiseAcceptsNothingAndWritesHistory) {
  const auto hist = std::filesystem::temp_directory_path() / ("rw-diag-hist-" + std::to_string(::getpid()) + ".jsonl");
  std::filesystem::remove(hist);
  // 8 impacts (4 held out) keep the test cheap (under ASan too); the JSON contract, the history line and
  // an empty verdict on pure noise do not depend on how many impacts are fitted.
  const auto r = run_cli({"diagnose", "--rig", kRig, kData + "sim-baseline-noise-3pct.wav", "--json", "--history", hist.string(),
                          "--max-impacts", "8"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  for (const char* key : {"baseline_excess", "steps", "verdict", "final_excess", "unexplained"}) EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_TRUE(j["verdict"].empty()) << j["verdict"];
  EXPECT_FALSE(j["unexplained"]["present"].get<bool>());
  ASSERT_FALSE(j["steps"].empty());
  for (const auto& s : j["steps"]) {
    for (const char* key : {"effect", "excess_before", "excess_after", "accepted", "parameters"}) EXPECT_TRUE(s.contains(key)) << key;
    EXPECT_FALSE(s["accepted"].get<bool>());
  }
  const std::string h = slurp(hist);
  EXPECT_EQ(std::count(h.begin(), h.end(), '\n'), 1);
  EXPECT_TRUE(nlohmann::json::accept(h.substr(0, h.find('\n'))));
  std::filesystem::remove(hist);
}

#ifndef RIDGEWATCH_SANITIZED  // a whole diagnose run: 7 s optimised, ~170 s under the sanitizers (the baseline-noise case keeps the CLI path there)
TEST(DiagnoseCli, SpikesAreASensorProblemNotPhysics) {
  // 8 impacts: the spikes are found by the segmentation over the whole record, whatever is fitted.
  const auto r = run_cli({"diagnose", "--rig", kRig, kData + "sim-spikes.wav", "--json", "--max-impacts", "8"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j["verdict"].empty()) << j["verdict"];
  ASSERT_FALSE(j["sensor_problems"].empty());
  EXPECT_NE(j["sensor_problems"][0].get<std::string>().find("spike"), std::string::npos);
}
#endif
