// `--format table`: the JSON of modes/analyze/compare/diagnose as aligned text. Expected texts are
// written by hand from the JSON below, not produced by the formatter.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include <nlohmann/json.hpp>
#include <sstream>

#include "cli/format_table.hpp"
#include "cli_runner.hpp"

using ridgewatch::cli::format_number;
using ridgewatch::cli::format_table;
using ridgewatch::test::run_cli;

TEST(FormatTable, NumbersHaveFourSignificantDigitsFiveForFrequencies) {
  EXPECT_EQ(format_number(0.0023456789, 4), "0.002346");
  EXPECT_EQ(format_number(854.23456, 5), "854.23");
  EXPECT_EQ(format_number(1.0e-7, 4), "1e-07");
  EXPECT_EQ(format_number(NAN, 4), "-");
  const std::string doc = R"({"file":"a.wav","sample_rate_hz":51200,"band_hz":[20.5,23040.123],"noise_sd":1.23456e-05,)"
                          R"("modes":[{"f_hz":499.98765,"zeta":0.0020012345,"zeta_ci95":[0.00195,0.00205],"status":"ok"},)"
                          R"({"f_hz":1250.0312,"zeta":null,"status":"low_snr","note":"x"}]})";
  EXPECT_EQ(format_table(doc + "\n"),
            "file: a.wav\n"
            "sample_rate_hz: 51200\n"
            "band_hz: [20.5, 23040]\n"
            "noise_sd: 1.235e-05\n"
            "\n"
            "modes:\n"
            "  f_hz    zeta      zeta_ci95           status   note\n"
            "  499.99  0.002001  [0.00195, 0.00205]  ok\n"
            "  1250    -                             low_snr  x\n");
}

TEST(FormatTable, JsonLinesBecomeOneTableAndNestedObjectsFlatten) {
  const std::string lines = "{\"t_s\":0.04,\"zeta\":0.0241234,\"alarm_detail\":{\"cusum_up\":0.5,\"zeta\":1}}\n"
                            "{\"t_s\":0.08,\"zeta\":0.0239,\"alarm_detail\":{\"cusum_up\":1.25,\"zeta\":2}}\n";
  EXPECT_EQ(format_table(lines),
            "t_s   zeta     cusum_up  alarm_detail.zeta\n"
            "0.04  0.02412  0.5       1\n"
            "0.08  0.0239   1.25      2\n");
  EXPECT_EQ(format_table("not json\n"), "not json\n");
}

// An object of equal-length arrays (compare's backbone) becomes one table; a matrix stays a matrix.
TEST(FormatTable, ColumnObjectsAndMatrices) {
  const std::string doc = R"({"backbone":{"a":[1,2,3,4,5],"measured":{"f_hz":[860.123,null,859.5,860,861]}},)"
                          R"("correlation":[[1,0.5],[0.5,1]]})";
  EXPECT_EQ(format_table(doc + "\n"),
            "\n"
            "backbone:\n"
            "  a  measured.f_hz\n"
            "  1  860.12\n"
            "  2  -\n"
            "  3  859.5\n"
            "  4  860\n"
            "  5  861\n"
            "\n"
            "correlation:\n"
            "          1       0.5\n"
            "        0.5         1\n");
}

// Through the binary: modes --format table has one row per mode of the JSON output, with the same
// frequencies to 5 significant digits; a bad format is exit 2 naming the flag.
TEST(FormatTable, ModesAndAnalyzeThroughTheBinary) {
  const std::string file = std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/paper-table1.wav";
  const auto json = run_cli({"modes", file});
  const auto table = run_cli({"modes", file, "--format", "table"});
  ASSERT_EQ(json.exit_code, 0) << json.err;
  ASSERT_EQ(table.exit_code, 0) << table.err;
  const auto doc = nlohmann::json::parse(json.out);
  ASSERT_GE(doc["modes"].size(), 1u);
  std::istringstream in(table.out);
  std::string line;
  while (std::getline(in, line) && line != "modes:") {
  }
  std::getline(in, line);
  EXPECT_EQ(line.rfind("  f_hz", 0), 0u) << table.out;
  for (const auto& m : doc["modes"]) {
    ASSERT_TRUE(std::getline(in, line)) << table.out;
    std::istringstream row(line);
    std::string f;
    row >> f;
    EXPECT_EQ(f, format_number(m["f_hz"].get<double>(), 5)) << line;
  }
  const auto bad = run_cli({"modes", file, "--format", "xml"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--format: 'xml' is not one of json, table"), std::string::npos) << bad.err;

  // The file is reached through a directory with a long name: the event's `source` (the path as given)
  // is a name and stays a column however long it is (CI checks out under a longer path than a laptop).
  const auto dir = std::filesystem::temp_directory_path() /
                   ("ridgewatch-format-table-a-directory-name-longer-than-forty-characters-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string sim = (dir / "sim-noise.wav").string();
  std::filesystem::copy_file(std::string(RIDGEWATCH_SOURCE_DIR) + "/replay-data/sim-noise.wav", sim,
                             std::filesystem::copy_options::overwrite_existing);
  const auto ev = run_cli({"analyze", sim});
  const auto tab = run_cli({"analyze", sim, "--format=table"});
  ASSERT_EQ(tab.exit_code, 0) << tab.err;
  std::size_t events = 0, rows = 0;
  for (char c : ev.out) events += c == '\n';
  for (char c : tab.out) rows += c == '\n';
  EXPECT_EQ(rows, events + 1) << "a header and one row per event";
  EXPECT_EQ(tab.out.rfind("t_s", 0), 0u) << tab.out.substr(0, 200);
  EXPECT_NE(tab.out.find(sim), std::string::npos) << "the source path is a column of every row";
  std::filesystem::remove_all(dir);
}
