// The diagnose plots built from hand-made results (cli/plot_diagnosis.hpp): the candidate ladder
// draws one bar per candidate with its outcome, the error-fall plot one point per round, and the
// --history reader keeps only the runs on the given file.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "cli/plot_diagnosis.hpp"
#include "test_plots_xml.hpp"

namespace plots = ridgewatch::cli::plots;
using ridgewatch::diagnosis::CandidateOutcome;
using ridgewatch::diagnosis::DiagnoseResult;
using ridgewatch::test::xml_problem;

namespace {

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
  return n;
}

CandidateOutcome step(const std::string& effect, int round, double before, double after, bool passed, bool plausible, bool accepted) {
  CandidateOutcome s;
  s.effect = effect;
  s.round = round;
  s.excess_before = before;
  s.excess_after = after;
  s.passed = passed;
  s.plausible = plausible;
  s.plausibility = plausible ? "" : "size < 2 sd";
  s.accepted = accepted;
  return s;
}

DiagnoseResult two_rounds() {
  DiagnoseResult r;
  r.baseline_excess = 20.0;
  r.steps = {step("coulomb_friction", 1, 20.0, 0.04, true, true, true), step("quadratic_damping", 1, 20.0, 3.0, true, true, false),
             step("second_mode", 1, 20.0, 19.0, false, false, false), step("hum<50Hz>", 1, 20.0, 20.0, false, true, false),
             step("damping_drift", 2, 0.04, -0.02, false, true, false)};
  r.verdict = {"coulomb_friction"};
  r.final_excess = 0.04;
  r.rounds.resize(2);
  r.rounds[0].heldout_excess = 20.0;
  r.rounds[1].effects = {"coulomb_friction"};
  r.rounds[1].heldout_excess = 0.04;
  return r;
}

}  // namespace

TEST(PlotLadder, OneBarPerCandidateColouredByOutcome) {
  const auto f = plots::candidate_ladder(two_rounds());
  EXPECT_EQ(f.file, "candidate-ladder.svg");
  EXPECT_EQ(xml_problem(f.svg), "");
  // 20 / 0.1 spans more than a factor 30: log axis, and the negative excess is clamped to its floor,
  // so all five bars are drawn.
  EXPECT_EQ(count(f.svg, "<rect class=\"bar "), 5u);
  EXPECT_EQ(count(f.svg, "class=\"bar accepted\""), 1u);
  EXPECT_EQ(count(f.svg, "class=\"bar passed\""), 1u);
  EXPECT_EQ(count(f.svg, "class=\"bar implausible\""), 1u);
  EXPECT_EQ(count(f.svg, "class=\"bar rejected\""), 2u);
  EXPECT_EQ(count(f.svg, "class=\"segment\""), 2u);  // the excess before each of the two rounds
  EXPECT_NE(f.svg.find("R1 hum&lt;50Hz&gt;"), std::string::npos);  // names are escaped
  EXPECT_NE(f.svg.find("R2 damping_drift"), std::string::npos);
  EXPECT_NE(f.svg.find("target 0.1"), std::string::npos);
}

TEST(PlotLadder, NoCandidatesStillMakesAValidFile) {
  DiagnoseResult r;
  r.rounds.resize(1);
  const auto f = plots::candidate_ladder(r);
  EXPECT_EQ(xml_problem(f.svg), "");
  EXPECT_EQ(count(f.svg, "<rect class=\"bar "), 0u);
  EXPECT_NE(f.svg.find("no candidate was tried"), std::string::npos);
  EXPECT_EQ(xml_problem(plots::error_fall(r, {}).svg), "");
}

TEST(PlotErrorFall, OnePointPerRoundAndAHistoryPanel) {
  const auto r = two_rounds();
  auto f = plots::error_fall(r, {});
  EXPECT_EQ(xml_problem(f.svg), "");
  EXPECT_EQ(count(f.svg, "<circle"), 2u);
  EXPECT_NE(f.svg.find("+coulomb_friction: 0.04"), std::string::npos);
  EXPECT_EQ(f.svg.find("history"), std::string::npos);
  plots::HistoryRun h1{{}, {"coulomb_friction"}, 20.0, 0.04};
  plots::HistoryRun h2{{"coulomb_friction"}, {}, 0.04, 0.04};
  f = plots::error_fall(r, {h1, h2});
  EXPECT_EQ(xml_problem(f.svg), "");
  EXPECT_EQ(count(f.svg, "<circle"), 2u + 4u);  // rounds + (given, after) per run
  EXPECT_NE(f.svg.find("history: runs on this file"), std::string::npos);
}

TEST(PlotHistory, ReadsOnlyWellFormedRunsOnTheFile) {
  const auto path = std::filesystem::temp_directory_path() / ("rw-plot-hist-" + std::to_string(::getpid()) + ".jsonl");
  {
    std::ofstream f(path);
    f << R"({"file":"a.wav","model":[],"verdict":["hum"],"baseline_excess":3.5,"final_excess":0.02,"unexplained":false})" << "\n"
      << R"({"file":"b.wav","model":[],"verdict":[],"baseline_excess":1,"final_excess":1})" << "\n"
      << "not json\n"
      << R"({"file":"a.wav","model":5})" << "\n"
      << R"({"file":"a.wav","model":["hum"],"verdict":[],"baseline_excess":0.02,"final_excess":0.02})" << "\n";
  }
  const auto runs = plots::read_history(path.string(), "a.wav");
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_DOUBLE_EQ(runs[0].baseline_excess, 3.5);
  EXPECT_EQ(runs[0].verdict, std::vector<std::string>{"hum"});
  EXPECT_EQ(runs[1].model, std::vector<std::string>{"hum"});
  EXPECT_TRUE(plots::read_history((path.string() + ".missing"), "a.wav").empty());
  std::filesystem::remove(path);
}
