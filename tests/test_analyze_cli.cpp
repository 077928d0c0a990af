// `ridgewatch analyze` as a user runs it: stdout holds only JSON event lines, exit codes 0/2/3.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "cli_runner.hpp"

namespace ridgewatch::test {
namespace {

const std::string kData = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/";

std::filesystem::path temp_file(const std::string& name, const std::string& text) {
  const auto p = std::filesystem::temp_directory_path() / ("rw-analyze-" + std::to_string(::getpid()) + "-" + name);
  std::ofstream(p) << text;
  return p;
}

TEST(AnalyzeCli, StdoutIsJsonLinesOnly) {
  const CliResult r = run_cli({"analyze", kData + "sim-spikes.wav"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::istringstream lines(r.out);
  std::size_t n = 0;
  for (std::string line; std::getline(lines, line); ++n) {
    const auto j = nlohmann::json::parse(line);  // throws (test error) on anything but JSON
    ASSERT_TRUE(j.is_object());
    for (const char* key : {"t_s", "sample_index", "source", "f_hz", "zeta", "zeta_ci95", "snr_db", "status",
                            "alarm", "f_sd_hz", "amplitude", "window_s", "alarm_detail"})
      EXPECT_TRUE(j.contains(key)) << key;
    EXPECT_EQ(j["source"], kData + "sim-spikes.wav");
    EXPECT_EQ(j["zeta_ci95"].size(), 2u);
    EXPECT_FALSE(j.contains("wall_time"));
  }
  EXPECT_EQ(n, 50u);  // the file's 50 impacts
  EXPECT_NE(r.err.find("4 spikes"), std::string::npos) << r.err;  // summary on stderr
}

TEST(AnalyzeCli, BadUsageIsExit2NamingTheFlag) {
  CliResult r = run_cli({"analyze"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("FILE"), std::string::npos) << r.err;
  r = run_cli({"analyze", kData + "sim-noise.wav", "--bogus"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--bogus"), std::string::npos) << r.err;
  r = run_cli({"analyze", kData + "sim-noise.wav", "--channel", "x"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--channel"), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty());
}

TEST(AnalyzeCli, BadInputIsExit3NamingTheFile) {
  CliResult r = run_cli({"analyze", kData + "no-such-file.wav"});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_NE(r.err.find("no-such-file.wav"), std::string::npos) << r.err;
  r = run_cli({"analyze", kData + "sim-noise.wav", "--channel", "3"});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_NE(r.err.find("channel"), std::string::npos) << r.err;
  const auto junk = temp_file("junk.wav", "this is not audio");
  r = run_cli({"analyze", junk.string()});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_NE(r.err.find(junk.string()), std::string::npos) << r.err;
  EXPECT_TRUE(r.out.empty());
  std::filesystem::remove(junk);
}

TEST(AnalyzeCli, ConfigFile) {
  // A valid config changes the analysis (ridge-ls instead of ml gives different numbers).
  const auto good = temp_file("good.yaml", "pipeline:\n  analyzer:\n    method: ridge-ls\n");
  const CliResult a = run_cli({"analyze", kData + "sim-noise.wav"});
  const CliResult b = run_cli({"analyze", kData + "sim-noise.wav", "--config", good.string()});
  ASSERT_EQ(b.exit_code, 0) << b.err;
  EXPECT_NE(a.out, b.out);
  // A bad value is exit 2 naming the key.
  const auto bad = temp_file("bad.yaml", "pipeline:\n  analyzer:\n    window_s: 0\n");
  CliResult r = run_cli({"analyze", kData + "sim-noise.wav", "--config", bad.string()});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("window_s"), std::string::npos) << r.err;
  // A band that does not fit the file's sample rate (25.6 kHz) is exit 2 naming key and file.
  const auto nyq = temp_file("nyq.yaml", "pipeline:\n  detector:\n    band_hi_hz: 20000\n");
  r = run_cli({"analyze", kData + "sim-noise.wav", "--config", nyq.string()});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("detector.band_hi_hz"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("sim-noise.wav"), std::string::npos) << r.err;
  r = run_cli({"analyze", kData + "sim-noise.wav", "--config", "/nonexistent/ridgewatch.yaml"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("/nonexistent/ridgewatch.yaml"), std::string::npos) << r.err;
  for (const auto& p : {good, bad, nyq}) std::filesystem::remove(p);
}

}  // namespace
}  // namespace ridgewatch::test
