// `ridgewatch compare/diagnose --plots DIR` end to end on a small simulated recording (10 impacts, so
// that the fits stay quick): every file is written and well-formed, index.html shows them all, the
// candidate ladder has one bar per candidate tried, the spectrum one curve per round; a directory
// that cannot be made is a usage error naming --plots and the directory.
#include <gtest/gtest.h>

#include <cctype>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cli_runner.hpp"
#include "test_plots_xml.hpp"

using ridgewatch::test::run_cli;
using ridgewatch::test::slurp;

namespace {

const std::string kRig = std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml";

// A "nan"/"inf" standing alone (a printed non-finite number), not part of a word.
bool has_non_finite(const std::string& s) {
  for (const char* w : {"nan", "inf"})
    for (auto p = s.find(w); p != std::string::npos; p = s.find(w, p + 1))
      if ((p == 0 || !std::isalpha(static_cast<unsigned char>(s[p - 1]))) &&
          (p + 3 >= s.size() || !std::isalpha(static_cast<unsigned char>(s[p + 3]))))
        return true;
  return false;
}

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
  return n;
}

class PlotsCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = std::filesystem::temp_directory_path() / ("rw-plots-cli-" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    // 0.4 s at 25.6 kHz: 10 impacts; a second mode near f0 gives the diagnose loop something to find.
    const auto r = run_cli({"simulate", "--rig", kRig, "--rate", "25600", "--duration", "0.4", "--seed", "3", "--noise", "0.005",
                            "--effect", "second_mode:frequency_hz=930,damping_ratio=0.02,participation=0.5", "--out",
                            (dir_ / "rec").string()});
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  static void TearDownTestSuite() { std::filesystem::remove_all(dir_); }

  static std::string wav() { return (dir_ / "rec.wav").string(); }

  static void check_files(const std::filesystem::path& out, const std::vector<std::string>& svgs) {
    const bool lint = ridgewatch::test::have_xmllint();
    for (const auto& name : svgs) {
      const auto p = out / name;
      ASSERT_TRUE(std::filesystem::exists(p)) << p;
      const std::string s = slurp(p);
      EXPECT_NE(s.find("<svg xmlns=\"http://www.w3.org/2000/svg\""), std::string::npos) << name;
      EXPECT_EQ(ridgewatch::test::xml_problem(s), "") << name;
      EXPECT_FALSE(has_non_finite(s)) << name;  // no NaN or infinity leaked into coordinates or labels
      if (lint) {
        EXPECT_EQ(ridgewatch::test::xmllint_problem(p), "") << name;
      }
    }
    const std::string html = slurp(out / "index.html");
    ASSERT_FALSE(html.empty());
    for (const auto& name : svgs) EXPECT_NE(html.find("<img src=\"" + name + "\""), std::string::npos) << name;
    EXPECT_EQ(ridgewatch::test::xml_problem(html), "");  // HTML5 written as well-formed XML
    // Self-contained: no scripts, no external resources.
    EXPECT_EQ(html.find("<script"), std::string::npos);
    EXPECT_EQ(html.find("http://"), std::string::npos);
    EXPECT_EQ(html.find("https://"), std::string::npos);
    EXPECT_EQ(html.find("<link"), std::string::npos);
  }

  static std::filesystem::path dir_;
};

std::filesystem::path PlotsCli::dir_;

const std::vector<std::string> kComparePlots = {"impacts.svg", "residual-scalogram.svg", "envelopes.svg", "backbones.svg",
                                                "residual-where.svg", "residual-spectrum.svg"};

}  // namespace

TEST_F(PlotsCli, CompareWritesEveryPlotAndTheIndex) {
  const auto out = dir_ / "compare" / "nested";  // parents are created too
  const auto r = run_cli({"compare", "--rig", kRig, wav(), "--plots", out.string()});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("held-out excess"), std::string::npos);  // the text report is unchanged on stdout
  check_files(out, kComparePlots);
  // The page carries the text report, and the spectrum has the one fit's curve.
  EXPECT_NE(slurp(out / "index.html").find("held-out excess"), std::string::npos);
  EXPECT_EQ(count(slurp(out / "residual-spectrum.svg"), "<path class=\"series\""), 1u);
  EXPECT_EQ(std::filesystem::exists(out / "candidate-ladder.svg"), false);
}

#ifndef RIDGEWATCH_SANITIZED  // a whole diagnose run: 20 s optimised, ~370 s under the sanitizers (the compare plots keep the writers there)
TEST_F(PlotsCli, DiagnoseWritesLadderWithOneBarPerCandidate) {
  const auto out = dir_ / "diagnose";
  const auto hist = dir_ / "history.jsonl";
  const auto r = run_cli({"diagnose", "--rig", kRig, wav(), "--max-impacts", "8", "--json", "--history", hist.string(), "--plots",
                          out.string()});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);  // --json output stays one clean JSON object
  std::vector<std::string> all = kComparePlots;
  all.insert(all.end(), {"candidate-ladder.svg", "error-fall.svg"});
  check_files(out, all);

  const std::string ladder = slurp(out / "candidate-ladder.svg");
  const auto& steps = j["steps"];
  std::size_t accepted = 0;
  for (const auto& s : steps) accepted += s["accepted"].get<bool>() ? 1 : 0;
  EXPECT_EQ(count(ladder, "class=\"xcat\""), steps.size());
  // Every bar is drawable (the log axis clamps small excesses at its floor), so one <rect> per step.
  EXPECT_EQ(count(ladder, "<rect class=\"bar "), steps.size());
  EXPECT_EQ(count(ladder, "class=\"bar accepted\""), accepted);
  EXPECT_EQ(accepted, j["verdict"].size());
  EXPECT_NE(ladder.find("target 0.1"), std::string::npos);
  // One spectrum curve per round: the starting model and one per accepted effect.
  EXPECT_EQ(count(slurp(out / "residual-spectrum.svg"), "<path class=\"series\""), j["verdict"].size() + 1);
  // With an accepted effect, the impact plot also shows the starting model.
  if (!j["verdict"].empty()) {
    EXPECT_NE(slurp(out / "impacts.svg").find("starting model"), std::string::npos);
  }
  // The history panel appears once the history file has a run on this recording.
  EXPECT_NE(slurp(out / "error-fall.svg").find("history: runs on this file"), std::string::npos);
}
#endif

TEST_F(PlotsCli, UnusableDirectoryIsAUsageErrorNamingIt) {
  const auto file = dir_ / "a-file";
  std::ofstream(file) << "x";
  for (const auto& bad : {file, file / "sub"}) {
    for (const char* cmd : {"compare", "diagnose"}) {
      const auto r = run_cli({cmd, "--rig", kRig, wav(), "--plots", bad.string()});
      EXPECT_EQ(r.exit_code, 2) << cmd << " " << bad << ": " << r.err;
      EXPECT_NE(r.err.find("--plots"), std::string::npos) << r.err;
      EXPECT_NE(r.err.find(bad.string()), std::string::npos) << r.err;
      EXPECT_TRUE(r.out.empty()) << r.out;  // refused before any work
    }
  }
  EXPECT_EQ(run_cli({"compare", "--rig", kRig, wav(), "--plots", ""}).exit_code, 2);
}
