// Golden replay regression: `ridgewatch analyze` over every bundled replay-data/sim-*.wav case must give
// the events stored in tests/golden/<case>.jsonl. This guards against unnoticed changes; whether the
// numbers are *right* is checked against the simulator's truth by test_analyze_acceptance.cpp (and the
// goldens were inspected against the truth files when they were made, see tests/golden/README.md).
//
// Rebuild with one flag: RIDGEWATCH_REGEN_GOLDEN=1 ./build/tests/test_replay_regression rewrites the
// golden files from the current binary instead of comparing.
//
// Tolerances. The pipeline is deterministic, so differences come only from code, compiler or library
// changes. A change is accepted when it is small against the estimate's own statistical uncertainty:
// zeta within 10 % of the golden event's 95 % half-interval, f within 10 % of 1.96 f_sd, both with a
// 1e-6 relative floor (noise-free cases have intervals near zero; FFTW/libm rounding differs at ~1e-12).
// Onsets within 2 samples (an onset is the interpolated 50 % crossing of a smooth envelope, rounded);
// status and alarm level exactly.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"

namespace ridgewatch::test {
namespace {

namespace fs = std::filesystem;
const fs::path kSource = RIDGEWATCH_SOURCE_DIR;

std::vector<std::string> cases() {
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(kSource / "replay-data")) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("sim-", 0) == 0 && entry.path().extension() == ".wav") names.push_back(entry.path().stem().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::vector<nlohmann::json> parse_lines(const std::string& text) {
  std::vector<nlohmann::json> out;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);)
    if (!line.empty()) out.push_back(nlohmann::json::parse(line));
  return out;
}

bool close(const nlohmann::json& got, const nlohmann::json& want, double tol) {
  if (want.is_null() || got.is_null()) return want.is_null() && got.is_null();
  return std::abs(got.get<double>() - want.get<double>()) <= tol;
}

class ReplayRegression : public ::testing::TestWithParam<std::string> {};

TEST_P(ReplayRegression, MatchesGolden) {
  const std::string name = GetParam();
  const std::string rel = "replay-data/" + name + ".wav";
  const CliResult r = run_cli({"analyze", (kSource / rel).string()});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::vector<nlohmann::json> got = parse_lines(r.out);
  for (auto& e : got) e["source"] = rel;  // goldens do not depend on the checkout path
  const fs::path golden = kSource / "tests" / "golden" / (name + ".jsonl");

  if (const char* regen = std::getenv("RIDGEWATCH_REGEN_GOLDEN"); regen && std::string(regen) == "1") {
    std::ofstream f(golden);
    for (const auto& e : got) f << e.dump() << "\n";
    GTEST_SKIP() << "rewrote " << golden;
  }
  ASSERT_TRUE(fs::exists(golden)) << golden << " missing: run with RIDGEWATCH_REGEN_GOLDEN=1";
  const std::vector<nlohmann::json> want = parse_lines(slurp(golden));
  ASSERT_EQ(got.size(), want.size()) << "event count changed";
  for (std::size_t i = 0; i < want.size(); ++i) {
    const auto& g = got[i];
    const auto& w = want[i];
    SCOPED_TRACE("event " + std::to_string(i) + " golden " + w.dump());
    const auto gi = g["sample_index"].get<long long>(), wi = w["sample_index"].get<long long>();
    EXPECT_LE(std::llabs(gi - wi), 2);
    EXPECT_EQ(g["status"], w["status"]);
    EXPECT_EQ(g["alarm"], w["alarm"]);
    if (!w["zeta"].is_null()) {
      const double half = w["zeta_ci95"][1].is_null() ? 0.0
                                                      : 0.5 * (w["zeta_ci95"][1].get<double>() - w["zeta_ci95"][0].get<double>());
      EXPECT_TRUE(close(g["zeta"], w["zeta"], std::max(0.1 * half, 1e-6 * w["zeta"].get<double>())))
          << "zeta " << g["zeta"] << " vs " << w["zeta"];
    } else {
      EXPECT_TRUE(g["zeta"].is_null());
    }
    if (!w["f_hz"].is_null()) {
      const double sd = w["f_sd_hz"].is_null() ? 0.0 : w["f_sd_hz"].get<double>();
      EXPECT_TRUE(close(g["f_hz"], w["f_hz"], std::max(0.1 * 1.96 * sd, 1e-6 * w["f_hz"].get<double>())))
          << "f " << g["f_hz"] << " vs " << w["f_hz"];
    } else {
      EXPECT_TRUE(g["f_hz"].is_null());
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Cases, ReplayRegression, ::testing::ValuesIn(cases()),
                         [](const ::testing::TestParamInfo<std::string>& param) {
                           std::string s = param.param;
                           for (char& c : s)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return s;
                         });

}  // namespace
}  // namespace ridgewatch::test
