// Survey step 4''' (core/survey/averaged_response.hpp): the ringing mode identified from spectra and
// band power averaged over the impacts, for decays too short and weak to be found in any single free
// response. Records of the independent generator (tests/support/indep_signals.hpp through
// bench/survey_cases.hpp, no code shared with core/model).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "bench/survey_cases.hpp"
#include "core/survey/averaged_response.hpp"
#include "core/survey/band_envelope.hpp"
#include "core/survey/survey.hpp"

namespace {

namespace sv = ridgewatch::survey;

// The significance test's distribution against closed forms: for n = 1 the ratio of two
// exponentials has P(X/Y > r) = 1/(1+r); for n = 2, I_x(2, 2) = 3x^2 - 2x^3 with x = 1/(1+r).
TEST(SurveyAverage, GammaRatioTailMatchesClosedForms) {
  for (double r : {0.5, 1.0, 3.0, 10.0}) {
    EXPECT_NEAR(sv::gamma_ratio_tail(1, r), 1.0 / (1.0 + r), 1e-12);
    const double x = 1.0 / (1.0 + r);
    EXPECT_NEAR(sv::gamma_ratio_tail(2, r), 3 * x * x - 2 * x * x * x, 1e-12);
  }
  EXPECT_NEAR(sv::gamma_ratio_tail(24, 1.0), 0.5, 1e-12);  // symmetric at r = 1
  // The tail narrows with n (the variance of an N-average falls as 1/N): r = 3 is common for n = 1, rare for 24.
  EXPECT_GT(sv::gamma_ratio_tail(1, 3.0), 0.2);
  EXPECT_LT(sv::gamma_ratio_tail(24, 3.0), 2e-4);
}

// Onsets on a regular grid over a record (the averaging's input), from `first` every `period`.
void grid(double duration, double first, double period, std::vector<double>& onset, std::vector<double>& previous) {
  for (double t = first + period; t + 0.05 < duration && onset.size() < 24; t += period) {
    onset.push_back(t);
    previous.push_back(t - period);
  }
}

// No invention: 8 records of mesh lines, hum and noise only, averaged at a regular grid of "impacts"
// (what a train test passed by chance would hand over), at 10/25/40 dB, both speed laws and four
// sample rates: no mode. (The test is the averaged peak's own significance test and the decay's
// asymmetry; the survey also runs it only after the train tests.)
TEST(SurveyAverage, NoModeInRecordsWithoutImpacts) {
  const double rates_fs[] = {25600, 44100, 48000, 51200};
  for (int s = 0; s < 8; ++s) {
    survey_cases::Case c;
    c.impacts = false;
    c.seed = static_cast<std::uint64_t>(3000 + s);
    c.fs_hz = rates_fs[s % 4];
    c.rate_hz = 5 + 10 * (s % 3);
    c.snr_db = 10 + 15 * (s % 3);
    c.wobble = s % 2;
    c.duration_s = 3;
    SCOPED_TRACE(survey_cases::describe(c));
    const auto r = survey_cases::make_record(c);
    const sv::RecordSpectrum spectrum(r.x, c.fs_hz);
    std::vector<double> onset, previous;
    grid(c.duration_s, 0.013, 1.0 / c.rate_hz, onset, previous);
    const auto m = sv::identify_averaged_mode(spectrum, onset, previous);
    EXPECT_FALSE(m.found) << m.f_hz << " Hz, zeta " << m.zeta << ", ratio " << m.ratio << " (needed " << m.ratio_needed << ")";
  }
}

// A short decay at 10 dB with the generator's own onsets: found, f within 1 % (the proposal's
// figure), zeta within a factor 1.5 (a first value for the decay window: the per-impact zeta is the
// analyzer's job).
TEST(SurveyAverage, ShortDecayAtTenDecibelsFromTheTrueOnsets) {
  survey_cases::Case c = survey_cases::sweep_case(2500, 5, 0.05, 0, 60);
  ASSERT_EQ(c.seed, 160u);
  ASSERT_EQ(c.snr_db, 10.0);
  const auto r = survey_cases::make_record(c);
  const sv::RecordSpectrum spectrum(r.x, c.fs_hz);
  std::vector<double> onset, previous;
  for (std::size_t j = 1; j < r.onset_s.size() && onset.size() < 24; ++j) {
    onset.push_back(r.onset_s[j]);
    previous.push_back(r.onset_s[j - 1]);
  }
  const auto m = sv::identify_averaged_mode(spectrum, onset, previous);
  ASSERT_TRUE(m.found) << m.why;
  EXPECT_NEAR(m.f_hz / c.f_hz, 1.0, 0.01);
  EXPECT_GT(m.zeta, c.zeta / 1.5);
  EXPECT_LT(m.zeta, c.zeta * 1.5);
}

#ifndef RIDGEWATCH_SANITIZED
// The sweep's records that had no proposal because the mode was ok in too few single free responses
// (README, bullet "no proposal, short decays at 10 dB"): the whole survey now proposes f within 1 %.
TEST(SurveyAverage, ShortDecaysAtTenDecibelsGetAProposal) {
  const survey_cases::Case cases[] = {survey_cases::sweep_case(8000, 5, 0.01, 0, 84),   // seed 184
                                      survey_cases::sweep_case(2500, 5, 0.05, 0, 60),   // seed 160
                                      survey_cases::sweep_case(2500, 25, 0.05, 1, 70)}; // seed 170
  const std::uint64_t seeds[] = {184, 160, 170};
  for (int i = 0; i < 3; ++i) {
    const survey_cases::Case& c = cases[i];
    ASSERT_EQ(c.seed, seeds[i]);
    ASSERT_EQ(c.snr_db, 10.0);
    SCOPED_TRACE(survey_cases::describe(c));
    const auto r = survey_cases::make_record(c);
    const auto res = sv::run_survey(r.x, c.fs_hz);
    ASSERT_TRUE(res.proposal.has_value()) << [&] {
      std::string s;
      for (const auto& e : res.evidence) s += e + "\n";
      return s;
    }();
    EXPECT_NEAR(res.proposal->analyzer.f_expected_hz / c.f_hz, 1.0, 0.01);  // the 1 %
    // The first zeta (it sets window_s) within 25 %: a line through the averaged power's logarithm
    // read 0.0162, 0.060 and 0.077 (the band's own response and the onsets' scatter steepen it), the
    // fit of the band-limited decay 0.0118, 0.058, 0.052 (measured); 25 % for the fit's spread at 10 dB.
    ASSERT_FALSE(res.modes.empty());
    EXPECT_NEAR(res.modes[0].zeta / c.zeta, 1.0, 0.25) << res.modes[0].zeta;
  }
}
#endif

#ifndef RIDGEWATCH_SANITIZED
// With their proposal, `analyze` finds the impacts of those short decays (the issue's >= 97 %, no
// false event). The proposal's trigger_ratio was half the impacts' median STA peak over the LTA (8 for
// both); the detector triggered every impact of seed 184 and its 2 ms confirmation rejected 18 (mean
// 3.9-7.8x the reference: the decays' power time constant is 1 ms), and seed 160's missed 4 whose STA
// reached only 5.6-6.1x a pre-window mean raised by the impact's own rise: 22/40 and 33/40 found. The
// ratio now comes from what both tests see (impact_trigger_levels() in core/survey/survey.cpp).
TEST(SurveyAverage, ShortDecaysAtTenDecibelsAreFoundWithTheProposal) {
  const std::string dir = (std::filesystem::temp_directory_path() / ("test_survey_average-" + std::to_string(::getpid()))).string();
  std::filesystem::create_directories(dir);
  const survey_cases::Case cases[] = {survey_cases::sweep_case(8000, 5, 0.01, 0, 84),   // seed 184
                                      survey_cases::sweep_case(2500, 5, 0.05, 0, 60)};  // seed 160
  for (const auto& c : cases) {
    SCOPED_TRACE(survey_cases::describe(c));
    const auto o = survey_cases::run_case(c, dir);
    ASSERT_TRUE(o.proposal);
    EXPECT_GE(static_cast<double>(o.found), 0.97 * static_cast<double>(o.truth)) << o.found << " of " << o.truth;
    EXPECT_EQ(o.false_events, 0u);
  }
  std::filesystem::remove_all(dir);
}
#endif

// The survey on a record without impacts still proposes nothing.
TEST(SurveyAverage, ControlWithoutImpactsGetsNoProposal) {
  survey_cases::Case c;
  c.impacts = false;
  c.seed = 1000;  // bench_survey controls' first record
  c.fs_hz = 25600;
  c.rate_hz = 5;
  c.snr_db = 10;
  const auto r = survey_cases::make_record(c);
  const auto res = sv::run_survey(r.x, c.fs_hz);
  EXPECT_FALSE(res.proposal.has_value());
}

}  // namespace
