// `ridgewatch survey` (issue 19): kurtosis facts, acceptance cases on records of the independent
// generator (tests/support/indep_signals.hpp, no code shared with core/model) through the real CLI
// (`survey --write-config` then `analyze --config` with the proposal unchanged), controls without
// impacts, the shared real hammer hit repeated with gaps, and the --write-config merge.
// The full acceptance sweep is bench/bench_survey.cpp (numbers in the README).
#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>

#include <unistd.h>

#include "bench/survey_cases.hpp"
#include "app/args.hpp"
#include "cli/commands.hpp"
#include "app/config_yaml.hpp"

#include "core/survey/kurtogram.hpp"
#include "core/survey/survey.hpp"
#include "drivers/replay_file.hpp"

namespace {

// One directory per test and process: ctest runs the tests of this file in parallel, and cases that
// shared one directory overwrote each other's record between the survey and the analyze step.
std::string temp_dir(const std::string& name) {
  const std::string test = ::testing::UnitTest::GetInstance()->current_test_info()->name();
  const auto d = std::filesystem::temp_directory_path() /
                 ("ridgewatch-test-survey-" + name + "-" + test + "-" + std::to_string(::getpid()));
  std::filesystem::create_directories(d);
  return d.string();
}

TEST(SpectralKurtosis, SteadyLineIsMinusOneAndNoiseIsZero) {
  // A constant-modulus complex tone: <|c|^4> / <|c|^2>^2 = 1, SK = -1 exactly (to rounding).
  std::vector<std::complex<double>> tone(4000);
  for (std::size_t i = 0; i < tone.size(); ++i) tone[i] = std::polar(2.0, 0.1 * static_cast<double>(i));
  EXPECT_NEAR(ridgewatch::survey::spectral_kurtosis(tone), -1.0, 1e-12);
  // Complex Gaussian noise: SK = 0 with sd 2 / sqrt(n) (kurtogram.hpp); 5 sd for n = 40000.
  indep::Rng rng(7);
  std::vector<std::complex<double>> noise(40000);
  for (auto& v : noise) v = {rng.gauss(), rng.gauss()};
  EXPECT_NEAR(ridgewatch::survey::spectral_kurtosis(noise), 0.0, 5 * 2 / std::sqrt(40000.0));
  // Bursts: one sample in 20 carries the power -> <y^2>/<y>^2 = 20, SK = 18.
  std::vector<std::complex<double>> bursts(4000, {0.0, 0.0});
  for (std::size_t i = 0; i < bursts.size(); i += 20) bursts[i] = {1.0, 0.0};
  EXPECT_NEAR(ridgewatch::survey::spectral_kurtosis(bursts), 18.0, 1e-9);
}

// The acceptance figures of the proposal and the detection for one record (outcome into o): a
// proposal, f within 1 %, >= 97 % of the impacts found, none false.
void expect_proposed_and_found(const survey_cases::Case& c, const std::string& dir_name, survey_cases::Outcome& o) {
  o = survey_cases::run_case(c, temp_dir(dir_name));
  ASSERT_TRUE(o.proposal) << o.survey_text;
  EXPECT_NEAR(o.f_expected_hz / c.f_hz, 1.0, 0.01);                                      // within 1 %
  EXPECT_GE(static_cast<double>(o.found), 0.97 * static_cast<double>(o.truth)) << o.analyze_err;  // >= 97 %
  EXPECT_EQ(o.false_events, 0u);
}

// Acceptance figures of issue 19 for one record (its outcome into *out when given).
void expect_accepted(const survey_cases::Case& c, survey_cases::Outcome* out = nullptr) {
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  expect_proposed_and_found(c, "acc", o);
  if (out) *out = o;
  if (o.proposal) {
    EXPECT_LE(o.median_zeta_err, 0.02);  // median <= 2 %
  }
}

TEST(SurveyAcceptance, PaperLikeRigInt16) {
  survey_cases::Case c;  // 854 Hz, 25/s with a -5..+5 % ramp, zeta 0.02, 30 dB, 51.2 kHz int16
  c.zeta = 0.02;
  c.seed = 1;
  expect_accepted(c);
}

#ifndef RIDGEWATCH_SANITIZED
TEST(SurveyAcceptance, SlowRateHighModeFloatWobble) {
  survey_cases::Case c;
  c.fs_hz = 51200;
  c.f_hz = 2500;
  c.rate_hz = 5;
  c.zeta = 0.002;
  c.snr_db = 25;
  c.float32 = true;
  c.wobble = true;
  c.duration_s = 8;
  c.seed = 119;
  expect_accepted(c);
}

TEST(SurveyAcceptance, LowModeAt44k) {
  survey_cases::Case c;
  c.fs_hz = 44100;
  c.f_hz = 300;
  c.rate_hz = 5;
  c.zeta = 0.01;
  // 20 dB: at 10 dB this record's median |zeta error| is 2.1 % (39 ok of 40 found, f 0.006 % off):
  // the pipeline's accuracy at that noise, listed in the README sweep.
  c.snr_db = 20;
  c.float32 = true;
  c.duration_s = 8;
  c.seed = 101;
  expect_accepted(c);
}

TEST(SurveyAcceptance, WellDampedModeAtTenDecibelsGetsAProposal) {
  // zeta 0.05 at 854 Hz (time constant 3.7 ms) at 5/s and 10 dB: the free responses the survey gives
  // the mode search are 50 ms, not the whole 200 ms interval, and start at the impact, not on the
  // first noise sample at half the peak; before, the mode was ok in 3 of 24 free responses (zeta read
  // 0.02) and there was no proposal. The proposal's f and the detection figures are checked; the
  // per-impact zeta at this noise is not precise enough for `ok` (the analyzer says low_snr in 39 of
  // 40 events, README), so the median zeta error is not.
  survey_cases::Case c;
  c.fs_hz = 48000;
  c.f_hz = 854;
  c.rate_hz = 5;
  c.zeta = 0.05;
  c.snr_db = 10;
  c.wobble = true;
  c.duration_s = 8;
  c.seed = 134;  // the sweep's record (bench_survey sweep 3 854 5 0.05)
  SCOPED_TRACE(survey_cases::describe(c));
  const auto o = survey_cases::run_case(c, temp_dir("damped"));
  ASSERT_TRUE(o.proposal) << o.survey_text;
  EXPECT_NEAR(o.f_expected_hz / c.f_hz, 1.0, 0.01);                                      // within 1 %
  EXPECT_GE(static_cast<double>(o.found), 0.97 * static_cast<double>(o.truth)) << o.analyze_err;  // >= 97 %
  EXPECT_EQ(o.false_events, 0u);
}
#endif

#ifndef RIDGEWATCH_SANITIZED
TEST(SurveyAcceptance, SweptMeshLineTrainWithoutModeGivesWayToTheImpacts) {
  // 120 impacts/s ringing at 8 kHz (zeta 0.01), +-5 % speed wobble: the 22-tooth mesh's second
  // harmonic (5280 Hz) sweeps through the kurtogram's sharpest band (5200-5300 Hz) twice a second and
  // its envelope forms a regular "train" at ~2/s, whose 480 ms free responses hold no decaying mode.
  // The survey must go on to the band whose train holds the ringing mode, not give up. The sweep's
  // record (bench_survey sweep 3 8000 120 0.01, 51.2 kHz float, 40 dB).
  survey_cases::Case c = survey_cases::sweep_case(8000, 120, 0.01, 1, 103);
  ASSERT_EQ(c.seed, 203u);
  ASSERT_TRUE(c.wobble);
  c.duration_s = 3;  // (the sweep's 6 s: the same outcome, twice the time)
  SCOPED_TRACE(survey_cases::describe(c));
  const auto o = survey_cases::run_case(c, temp_dir("swept"));
  ASSERT_TRUE(o.proposal) << o.survey_text;
  // The impact rate, independently of the generator's onsets: 120/s +-5 % wobble (the line's train
  // said 2.07/s).
  EXPECT_NEAR(nlohmann::json::parse(o.survey_text)["impacts"]["rate_hz"].get<double>(), 120.0, 6.0);
  EXPECT_NEAR(o.f_expected_hz / c.f_hz, 1.0, 0.01);                                      // within 1 %
  EXPECT_GE(static_cast<double>(o.found), 0.97 * static_cast<double>(o.truth)) << o.analyze_err;  // >= 97 %
  EXPECT_EQ(o.false_events, 0u);
  EXPECT_LE(o.median_zeta_err, 0.02);                                                    // median <= 2 %
  // `ok` is a promise: each ok zeta within 10 % of the truth (40 dB, a 20 ms decay: the per-impact
  // spread is ~1 %; 10 % catches a fit to noise or to the mesh line, which reads zeta far off).
  for (double z : o.ok_zeta) EXPECT_NEAR(z / c.zeta, 1.0, 0.10);
}
#endif

#ifndef RIDGEWATCH_SANITIZED
TEST(SurveyAcceptance, ShortDecayAtEightKilohertzGetsAProposal) {
  // zeta 0.05 at 8 kHz (time constant 0.4 ms) at 5/s: every gap between two impacts holds a noise
  // maximum of the band envelope, and the impacts' threshold from the median maximum let them in
  // (no train); 4.5 time constants are 46 samples, under the analyzer's 80-sample minimum window.
  // The sweep's record (bench_survey sweep 3 8000 5 0.05, 25.6 kHz int16, 40 dB).
  survey_cases::Case c = survey_cases::sweep_case(8000, 5, 0.05, 1, 88);
  ASSERT_EQ(c.seed, 188u);
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  ASSERT_NO_FATAL_FAILURE(expect_proposed_and_found(c, "short", o));
  // `ok` is a promise: each ok zeta within 25 % of the truth (the per-impact spread of a 0.4 ms decay
  // is several %; 25 % catches a fit to noise or to a mesh line, which reads zeta 2-10x off).
  for (double z : o.ok_zeta) EXPECT_NEAR(z / c.zeta, 1.0, 0.25);
}
#endif

#ifndef RIDGEWATCH_SANITIZED
// The sweep's record s of the cell 854 Hz 25/s zeta 0.01 (bench_survey sweep 3 854 25 0.01; record
// 39 + s of the sweep), checked against the seed and SNR the comments below name.
survey_cases::Case sweep_record_854_25_001(int s, std::uint64_t seed, double snr_db) {
  const survey_cases::Case c = survey_cases::sweep_case(854, 25, 0.01, s, 39 + s);
  EXPECT_EQ(c.seed, seed);
  EXPECT_EQ(c.snr_db, snr_db);
  return c;
}

TEST(SurveyAcceptance, DecaysFillingTheIntervalPassTheContrastAgainstTheFloorBeforeEachImpact) {
  // 854 Hz, zeta 0.01, 25/s, 10 dB: 13 % of the amplitude is left at the next impact, so the band
  // envelope's median is the ringing itself, 8 dB under the peaks; the survey found the mode (16 of
  // 24 free responses), the train's period and 96 % regular intervals, but said "no repeated
  // impacts" on the 10 dB contrast. Against the envelope just before each impact the peaks stand
  // 13 dB. The sweep's record (bench_survey sweep 3 854 25 0.01, 44.1 kHz float, seed 141).
  const survey_cases::Case c = sweep_record_854_25_001(2, 141, 10.0);
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  ASSERT_NO_FATAL_FAILURE(expect_proposed_and_found(c, "fill", o));
  EXPECT_NE(o.survey_text.find("over the envelope just before them"), std::string::npos) << o.survey_text;
}

TEST(SurveyAcceptance, NoEventAtTheFirstSampleWithALoweredTriggerRatio) {
  // 854 Hz, zeta 0.01, 25/s, 40 dB: the survey lowers trigger_ratio to 3 (the decays fill the
  // interval), and the detector's start transient on the lines and hum the record starts in then
  // triggered, its onset clamped to the first sample: an event at 0 s, 30 ms before the first
  // impact, the record's one false event. An onset at the segment's first sample is no onset now
  // (detector_onset.cpp). The sweep's record (bench_survey sweep 3 854 25 0.01, 25.6 kHz int16).
  expect_accepted(sweep_record_854_25_001(1, 140, 40.0));
}

TEST(SurveyProposal, SaysWhenBandNoiseAloneReachesTheLoweredTriggerRatio) {
  // 854 Hz, zeta 0.002, 5/s, 10 dB (bench_survey sweep 3 854 5 0.002, 51.2 kHz float, seed 127): the
  // decays fill the interval and the ratio is lowered to 3, but before the first impact the band
  // holds noise only and the detector's LTA is the noise's mean: traced in the detector on this
  // record, a trigger at 0.099 s whose 2 ms confirmation stood 4.47x its reference (a false event,
  // and the hold-off hid the first impact at 0.108 s). The survey must measure that level (above the
  // ratio) and say so.
  const survey_cases::Case c = survey_cases::sweep_case(854, 5, 0.002, 0, 27);
  ASSERT_EQ(c.seed, 127u);
  ASSERT_EQ(c.snr_db, 10.0);
  const auto r = survey_cases::make_record(c);
  const auto res = ridgewatch::survey::run_survey(r.x, c.fs_hz);
  ASSERT_TRUE(res.proposal.has_value());
  EXPECT_EQ(res.proposal->detector.trigger_ratio, 3.0);
  // Noise's exponential tail: a different stretch than the detector's trigger; 3.5 ... 8 brackets
  // the traced 4.47 (the survey's envelope is not the detector's filter chain).
  EXPECT_GT(res.noise_trigger_level, 3.5);
  EXPECT_LT(res.noise_trigger_level, 8.0);
  bool noted = false;
  for (const auto& n : res.proposal->notes) noted = noted || n.find("band noise alone reaches") != std::string::npos;
  EXPECT_TRUE(noted);
  // The impacts cannot afford a ratio above 3 against the decay-filled LTA, so the noise-only
  // stretches get the detector's noise floor instead (at least 12x the white-noise band power).
  EXPECT_GE(res.proposal->detector.trigger_noise_ratio, 12.0);
}

TEST(SurveyAcceptance, NoFalseEventBeforeTheFirstImpactWithALoweredTriggerRatio) {
  // The same record as above through `survey --write-config` and `analyze`: before the noise floor
  // the band noise triggered at 0.094 s, the hold-off (96 ms) hid the first impact at 0.108 s: 39/40
  // found and 1 false. With trigger_noise_ratio 12: 40/40, 0 false.
  const survey_cases::Case c = survey_cases::sweep_case(854, 5, 0.002, 0, 27);
  ASSERT_EQ(c.seed, 127u);
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  ASSERT_NO_FATAL_FAILURE(expect_proposed_and_found(c, "noise-floor", o));  // includes 0 false events
  EXPECT_EQ(o.found, o.truth) << o.analyze_err;
}
#endif

#ifndef RIDGEWATCH_SANITIZED
TEST(SurveyAcceptance, LowModeAtTwentyFivePerSecondGetsAProposalWithALowerEta0) {
  // 300 Hz at 25/s +-5 %: 38 ms between the closest impacts, the analyzer's minimum window at eta0 7
  // (10 kernel widths, 37 ms) did not fit 0.9 of that minus the pretrigger (32.5 ms): no proposal,
  // although the decay (zeta 0.05, time constant 10.6 ms) is 3 % of its start at the next impact.
  // The lone mode needs no finer frequency resolution: eta0 6 (31.8 ms). The sweep's record
  // (bench_survey sweep 3 300 25 0.05, 25.6 kHz int16 ramp, 40 dB).
  survey_cases::Case c = survey_cases::sweep_case(300, 25, 0.05, 1, 16);
  ASSERT_EQ(c.seed, 116u);
  survey_cases::Outcome o;
  expect_accepted(c, &o);  // proposal, f within 1 %, >= 97 % found, 0 false, median |zeta error| <= 2 %
  ASSERT_TRUE(o.proposal);
  const double eta0 = nlohmann::json::parse(o.survey_text)["proposal"]["pipeline"]["analyzer"]["eta0"].get<double>();
  EXPECT_GE(eta0, 5.0);  // the analyzer's range
  // Its minimum window fits between the closest impacts (10 kernel widths eta0 / (2 pi f) < 0.9 x 38 ms - 2 ms).
  EXPECT_LT(10.0 * eta0 / (2 * std::numbers::pi * c.f_hz), 0.9 * 0.038 - 0.002);
  // `ok` is a promise: at 40 dB one decay gives zeta to ~0.3 % (README, Cramer-Rao); 10 % catches a
  // fit to a mesh line or to noise.
  EXPECT_GE(o.ok, 3u);
  for (double z : o.ok_zeta) EXPECT_NEAR(z / c.zeta, 1.0, 0.10);
}
#endif

#ifndef RIDGEWATCH_SANITIZED
TEST(SurveyAcceptance, LowWellDampedModeBesideAMeshLineGetsAProposal) {
  // 300 Hz, zeta 0.05 (time constant 10.6 ms) at 5/s, the 22-tooth mesh at 110/220 Hz (15 % of the
  // impact at 220 Hz, 27 % below the mode), locked to the impacts: over the whole range the mode was
  // ok in fewer than half of the free responses (ridge drawn to the line at eta0 7, free responses
  // cut to 50 ms): no proposal. The search focused on the candidate finds it in most of them.
  // The sweep's record (bench_survey sweep 3 300 5 0.05, 25.6 kHz int16 ramp, 25 dB).
  survey_cases::Case c = survey_cases::sweep_case(300, 5, 0.05, 2, 8);
  ASSERT_EQ(c.seed, 108u);
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  ASSERT_NO_FATAL_FAILURE(expect_proposed_and_found(c, "mesh", o));
  // The survey's own zeta (median over the free responses) sizes the window: within 10 % (it reads
  // 0.0502; the broadband search's ok members scattered 0.039-0.055).
  const auto j = nlohmann::json::parse(o.survey_text);
  EXPECT_NEAR(j["modes"][0]["zeta"].get<double>() / c.zeta, 1.0, 0.10);
  // `ok` is a promise: each ok zeta within 15 % (25 dB: a few % per decay; a fit drawn to the
  // 220 Hz line read 16 % high).
  for (double z : o.ok_zeta) EXPECT_NEAR(z / c.zeta, 1.0, 0.15);
}

TEST(SurveyAcceptance, SpeedWobbleDoesNotHideTheRate) {
  // 8 kHz, zeta 0.01 at 25/s under a +-5 % wobble of 1 s: the band envelope's autocorrelation peaks
  // highest near the wobble's period, and its 1/8 (120 ms) was taken for the period: 51 % of the
  // intervals regular, no proposal. The shortest sub-multiple (40 ms) passes the train test.
  // The sweep's record (bench_survey sweep 3 8000 25 0.01, 51.2 kHz float wobble, 25 dB).
  survey_cases::Case c = survey_cases::sweep_case(8000, 25, 0.01, 2, 95);
  ASSERT_EQ(c.seed, 195u);
  ASSERT_TRUE(c.wobble);
  SCOPED_TRACE(survey_cases::describe(c));
  survey_cases::Outcome o;
  ASSERT_NO_FATAL_FAILURE(expect_proposed_and_found(c, "wobble", o));
  EXPECT_NEAR(nlohmann::json::parse(o.survey_text)["impacts"]["rate_hz"].get<double>(), 25.0, 1.25);  // the mean rate, +-5 %
  // `ok` is a promise: each ok zeta within 15 % (25 dB, 2 ms decays: a few % each).
  for (double z : o.ok_zeta) EXPECT_NEAR(z / c.zeta, 1.0, 0.15);
}
#endif

TEST(SurveyControls, NoImpactsNoProposal) {
#ifdef RIDGEWATCH_SANITIZED
  const int seeds = 1;
#else
  const int seeds = 3;
#endif
  for (int s = 0; s < seeds; ++s) {
    survey_cases::Case c;
    c.impacts = false;
    c.seed = static_cast<std::uint64_t>(2000 + s);
    c.fs_hz = s % 2 ? 25600 : 48000;
    c.rate_hz = 10 + 30 * s;
    c.wobble = s % 2;
    c.snr_db = 10 + 15 * s;
    SCOPED_TRACE(survey_cases::describe(c));
    const auto o = survey_cases::run_case(c, temp_dir("ctl"));
    EXPECT_EQ(o.survey_rc, 0);
    EXPECT_FALSE(o.proposal) << o.survey_text;
    EXPECT_NE(o.survey_text.find("\"proposal\":null"), std::string::npos);
  }
}

#ifndef RIDGEWATCH_SANITIZED  // survey + analyze of a 5-hit record: 18 s optimised, ~245 s under the sanitizers
TEST(SurveyRealData, HammerHitRepeatedFiveTimes) {
  const std::string hit = std::string(RIDGEWATCH_SHARED_DIR) + "/real-data/hammer-hit/hit-1.wav";
  if (!std::filesystem::exists(hit)) GTEST_SKIP() << hit << " not present";
  // The record: survey_cases::write_hammer_record (5 copies, 0.5 s of zeros before each).
  const std::string dir = temp_dir("hammer");
  const auto h = survey_cases::write_hammer_record(hit, dir);
  const auto o = survey_cases::survey_then_analyze(h.wav, dir + "/hammer5.yaml", h.onsets, h.zetas, 0.2);
  ASSERT_TRUE(o.proposal) << o.survey_text;
  const double f = o.f_expected_hz;
  // Within 3 % of one of the structure's known modes (the data's README gives them rounded: 900,
  // 2640 and 5970 Hz the strongest, 4128 Hz a further one; the survey may ring-select any of them).
  bool near_mode = false;
  for (double known : {900.0, 2640.0, 4128.0, 5970.0}) near_mode = near_mode || std::fabs(f / known - 1) < 0.03;
  EXPECT_TRUE(near_mode) << "f_expected_hz " << f;
  EXPECT_EQ(o.found, 5u) << o.analyze_err;
  EXPECT_EQ(o.false_events, 0u);
  // Every event ok: the proposed mode must be one the analyzer reads apart from the neighbours the
  // survey found (eta0 and ridge band from them). The 5977 Hz mode, 1.7 % from one at 6077 Hz, gave
  // 5 ridge_lost events. The truth is not known beyond the data's README (damping ratios of order
  // 1e-3 and below): each ok zeta within 1e-4 .. 5e-3, and its frequency within 0.5 % of the proposal
  // (the ridge stayed on the proposed mode; its band is narrower than the distance to the neighbours).
  EXPECT_EQ(o.ok, 5u) << o.survey_text;
  for (std::size_t i = 0; i < o.ok_zeta.size(); ++i) {
    EXPECT_GT(o.ok_zeta[i], 1e-4);
    EXPECT_LT(o.ok_zeta[i], 5e-3);
    EXPECT_NEAR(o.ok_f_hz[i] / f, 1.0, 0.005);
  }
}
#endif

#ifndef RIDGEWATCH_SANITIZED  // a whole survey of an 8 s record: too slow under the sanitizers
// A mode identified only from the averages over the impacts (8 kHz 5/s zeta 0.01 at 10 dB, seed 184:
// no single free response holds it ok) is reported as such: the text names the averaging instead of
// "in 0 of N free responses", and --json gives averaged_over > 0 with segments 0.
TEST(SurveyCli, AveragedModeIsReportedAsAveraged) {
  namespace cli = ridgewatch::cli;
  const std::string dir = temp_dir("cli-avg");
  const auto c = survey_cases::sweep_case(8000, 5, 0.01, 0, 84);
  ASSERT_EQ(c.seed, 184u);
  const auto r = survey_cases::make_record(c);
  indep::write_wav_mono(dir + "/rec.wav", r.x, c.fs_hz, indep::SampleFormat::float32);
  std::ostringstream out, err, jout, jerr;
  ASSERT_EQ(cli::run_survey({dir + "/rec.wav"}, out, err), 0) << err.str();
  EXPECT_NE(out.str().find("averaged over"), std::string::npos) << out.str();
  EXPECT_EQ(out.str().find("in 0 of"), std::string::npos) << out.str();
  ASSERT_EQ(cli::run_survey({dir + "/rec.wav", "--json"}, jout, jerr), 0) << jerr.str();
  const auto m = nlohmann::json::parse(jout.str())["modes"].at(0);
  EXPECT_GT(m["averaged_over"].get<int>(), 0);
  EXPECT_EQ(m["segments"].get<int>(), 0);
  std::filesystem::remove_all(dir);
}
#endif

TEST(SurveyCli, WriteConfigMergesIntoACopyAndRefusesTheBaseItself) {
  namespace cli = ridgewatch::cli;
  namespace app = ridgewatch::app;
  const std::string dir = temp_dir("cli");
  survey_cases::Case c;
  c.duration_s = 3;
  const auto r = survey_cases::make_record(c);
  indep::write_wav_mono(dir + "/rec.wav", r.x, c.fs_hz, indep::SampleFormat::pcm16);
  // A base file with a non-default key outside the pipeline, and one inside it that the survey does
  // not set: both must survive in the copy.
  {
    std::ofstream f(dir + "/base.yaml");
    f << "output:\n  csv: \"/var/log/ridgewatch/events.csv\"\npipeline:\n  analyzer:\n    min_snr_db: 17\n";
  }
  std::ostringstream out, err;
  ASSERT_EQ(cli::run_survey({dir + "/rec.wav", "--config", dir + "/base.yaml", "--write-config", dir + "/out.yaml"}, out, err), 0)
      << err.str();
  const auto merged = app::load_config_file(dir + "/out.yaml");
  EXPECT_EQ(merged.output.csv, "/var/log/ridgewatch/events.csv");
  EXPECT_EQ(merged.pipeline.analyzer.min_snr_db, 17.0);
  EXPECT_NEAR(merged.pipeline.analyzer.f_expected_hz / c.f_hz, 1.0, 0.01);
  EXPECT_LT(merged.pipeline.detector.band_lo_hz, c.f_hz);
  EXPECT_GT(merged.pipeline.detector.band_hi_hz, c.f_hz);
  // The text report prints the same block.
  EXPECT_NE(out.str().find("pipeline:\n  detector:\n    band_lo_hz: "), std::string::npos);
  std::ostringstream o2, e2;
  EXPECT_THROW(cli::run_survey({dir + "/rec.wav", "--config", dir + "/base.yaml", "--write-config", dir + "/base.yaml"}, o2, e2),
               app::UsageError);
}

TEST(SurveyCli, WriteConfigRewritesARelativeRigPathForTheCopysFolder) {
  // `rig:` is relative to the configuration file's folder: a base in sub/ naming `rig.yaml` beside it
  // must give a copy in the parent folder that names sub/rig.yaml, and reads back with that rig.
  namespace cli = ridgewatch::cli;
  namespace fs = std::filesystem;
  const std::string dir = temp_dir("rig");
  fs::create_directories(dir + "/sub");
  fs::copy_file(std::string(RIDGEWATCH_SOURCE_DIR) + "/config/rigs/paper-rig.yaml", dir + "/sub/rig.yaml",
                fs::copy_options::overwrite_existing);
  {
    std::ofstream f(dir + "/sub/base.yaml");
    f << "rig: rig.yaml\n";
  }
  survey_cases::Case c;
  c.duration_s = 3;
  const auto r = survey_cases::make_record(c);
  indep::write_wav_mono(dir + "/rec.wav", r.x, c.fs_hz, indep::SampleFormat::pcm16);
  std::ostringstream out, err;
  ASSERT_EQ(cli::run_survey({dir + "/rec.wav", "--config", dir + "/sub/base.yaml", "--write-config", dir + "/out.yaml"}, out, err), 0)
      << err.str();
  const auto merged = cli::load_config_file(dir + "/out.yaml");  // throws (exit 2) if rig.yaml is not found
  EXPECT_EQ(fs::path(merged.rig), fs::path("sub/rig.yaml"));
  EXPECT_TRUE(fs::equivalent(merged.rig_model.path, dir + "/sub/rig.yaml"));
  // The survey's proposal wins over the rig's model values (given explicitly in the copy).
  EXPECT_NEAR(merged.pipeline.analyzer.f_expected_hz / c.f_hz, 1.0, 0.01);
}

}  // namespace
