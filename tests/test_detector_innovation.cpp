// The impact detector's innovation trigger (detector.trigger_innovation, core/pipeline/impact_detector.hpp
// stage 3) on records of the independent generator (tests/support/indep_signals.hpp): impacts whose
// decays overlap the previous impact's ringing must be found, and records without impacts (mesh
// lines, hum, an in-band line, spikes, noise) must give none.
#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdint>
#include <iostream>
#include <span>
#include <vector>

#include "core/pipeline/impact_detector.hpp"
#include "support/indep_signals.hpp"

namespace ridgewatch::pipeline {
namespace {


// The survey's proposal for such a record (bench_survey sweep 3 854 25 0.002): band f (1 +- 0.15),
// hold-off half the shortest interval, the default ratio 8, the innovation trigger.
ImpactDetectorConfig overlap_config(bool innovation) {
  ImpactDetectorConfig c;
  c.band_lo_hz = 726.0;
  c.band_hi_hz = 982.0;
  c.holdoff_s = 0.019;
  c.trigger_innovation = innovation;
  return c;
}

// 854 Hz, zeta 0.002, 25 impacts/s with a +-5 % speed wobble: exp(-2 pi f zeta T) = 65 % of the
// amplitude is left at the next impact, and the wobble (+-2 ms per period, +-1.7 cycles) puts each
// impact at a random phase against that ringing. Mesh lines at 22 x 25 = 550 and 1100 Hz, hum,
// spikes, white noise at 2 % of the impact amplitude.
indep::RigSpec overlap_rig(double impact_amplitude) {
  indep::RigSpec s;
  s.fs_hz = 25600.0;
  s.duration_s = 4.0;
  s.rev_hz = 25.0;
  s.wobble_rel = 0.05;
  s.wobble_period_s = 1.3;
  s.mesh_amp = {0.25, 0.15};
  s.hum_amp = {0.05, 0.02};
  s.noise_sd = 0.02;
  s.spike_rate_hz = 2.0;
  s.spike_amp = 3.0;
  s.response.f_hz = 854.0;
  s.response.zeta = 0.002;
  s.response.amplitude = impact_amplitude;
  s.seed = 19;
  return s;
}

std::vector<std::uint64_t> detect(const ImpactDetectorConfig& cfg, const std::vector<double>& x, double fs,
                                  std::size_t span = 256) {
  ImpactDetector d(cfg, fs, 4096);
  std::vector<float> xf(x.begin(), x.end());
  std::vector<std::uint64_t> onsets;
  for (std::size_t i = 0; i < xf.size(); i += span) {
    d.push(std::span<const float>(xf.data() + i, std::min<std::size_t>(span, xf.size() - i)));
    while (d.has_onset()) onsets.push_back(d.pop_onset());
  }
  d.finish();
  while (d.has_onset()) onsets.push_back(d.pop_onset());
  return onsets;
}

struct Score {
  std::size_t found = 0, false_onsets = 0;
};

// An onset within 3 ms of a true one finds it (each true onset once); the others are false. 3 ms: the
// detector's onsets lie within ~0.3 ms of the truth (impact_detector.hpp, stage 5), and a tenth of the
// 40 ms period keeps neighbours apart.
Score score(const std::vector<std::uint64_t>& onsets, const std::vector<double>& truth_s, double fs) {
  Score s;
  std::vector<bool> used(truth_s.size(), false);
  for (std::uint64_t o : onsets) {
    const double t = static_cast<double>(o) / fs;
    bool hit = false;
    for (std::size_t i = 0; i < truth_s.size() && !hit; ++i)
      if (!used[i] && std::abs(t - truth_s[i]) <= 0.003) used[i] = hit = true;
    if (hit) ++s.found;
    else ++s.false_onsets;
  }
  return s;
}

TEST(DetectorInnovation, FindsImpactsOnTheRingingOfThePreviousOne) {
  const auto rec = indep::make_rig_record(overlap_rig(1.0));
  ASSERT_GE(rec.onset_s.size(), 95u);
  const Score s = score(detect(overlap_config(true), rec.x, rec.fs_hz), rec.onset_s, rec.fs_hz);
  // The acceptance figures of `survey` (README "First run on your own rig"): >= 97 % found, 0 false.
  EXPECT_GE(static_cast<double>(s.found), 0.97 * static_cast<double>(rec.onset_s.size()))
      << s.found << " of " << rec.onset_s.size();
  EXPECT_EQ(s.false_onsets, 0u);
}

TEST(DetectorInnovation, OutputDoesNotDependOnPushPattern) {
  // As the energy trigger (impact_detector.hpp): blocks and runs are aligned to the segment start.
  const auto rec = indep::make_rig_record(overlap_rig(1.0));
  const auto a = detect(overlap_config(true), rec.x, rec.fs_hz, 256);
  EXPECT_EQ(a, detect(overlap_config(true), rec.x, rec.fs_hz, 1));
  EXPECT_EQ(a, detect(overlap_config(true), rec.x, rec.fs_hz, 997));
  EXPECT_FALSE(a.empty());
}

TEST(DetectorInnovation, EnergyTriggerMissesTheSameImpacts) {
  // The reason for the mode, kept as a measured fact: on the same record the energy trigger, even at
  // the survey's lowest ratio 3, finds few impacts (an impact raises the band energy ~1.5x on average).
  const auto rec = indep::make_rig_record(overlap_rig(1.0));
  ImpactDetectorConfig c = overlap_config(false);
  c.trigger_ratio = 3.0;
  const Score s = score(detect(c, rec.x, rec.fs_hz), rec.onset_s, rec.fs_hz);
  EXPECT_LT(static_cast<double>(s.found), 0.5 * static_cast<double>(rec.onset_s.size())) << s.found;
}

TEST(DetectorInnovation, NoImpactsNoOnsetsWithLinesHumSpikesAndNoise) {
  // The same rig without impacts, with a steady line inside the band (860 Hz, a tenth of the impact
  // amplitude: the predictor follows it): nothing may trigger.
  auto s = overlap_rig(0.0);
  s.hum_hz = 430.0;
  s.hum_amp = {0.05, 0.1};
  const auto steady = indep::make_rig_record(s);
  EXPECT_TRUE(detect(overlap_config(true), steady.x, steady.fs_hz).empty());
  // A mesh line swept through the band by the wobble (34 teeth: 850 Hz +- 5 %) at 5-30 % of the impact
  // amplitude: nothing after the start-up. The generator switches its lines on at the first sample, a
  // step in the band; at 10 % of the amplitude that step gives one onset at sample 0 in both triggers
  // (energy, ratio 8: the same onset), which is not this mode's business.
  s.teeth = 34;
  for (double amp : {0.05, 0.1, 0.3}) {
    s.mesh_amp = {amp};
    const auto swept = indep::make_rig_record(s);
    for (std::uint64_t o : detect(overlap_config(true), swept.x, swept.fs_hz))
      EXPECT_LT(static_cast<double>(o), 0.001 * swept.fs_hz) << "line amplitude " << amp;
  }
}

}  // namespace
}  // namespace ridgewatch::pipeline

namespace ridgewatch::pipeline {
namespace {

// innovation_noise_power(): between overlapping decays the band power holds the previous impact's
// ringing, the innovation's power only the noise. The record above without lines, hum and spikes
// (noise sd 0.02, impacts of amplitude 1: ~65 % of the amplitude rings on at the next impact). Over the
// pre-trigger spans the analysis reads (StreamProcessor: 2 ms ending 0.25 ms before each true onset,
// read 15 ms after it), averaged over the impacts from the third on (each 2 ms span holds about one
// degree of freedom of a band a few hundred Hz wide), against the noise's band power
// sigma^2 band_noise_gain(). Bounds: the ringing stands 20-30 dB over the noise here, so band_power()
// >= 10x; the innovation within [0.75, 1.35] of the noise (~85 spans of ~1-2 degrees of freedom:
// their mean's sd ~10 %, plus the one-pole prediction's error).
TEST(DetectorInnovation, InnovationNoisePowerIsTheNoiseBetweenOverlappingDecays) {
  indep::RigSpec s = overlap_rig(1.0);
  s.mesh_amp.clear();
  s.hum_amp.clear();
  s.spike_rate_hz = 0.0;
  const auto rec = indep::make_rig_record(s);
  ImpactDetector d(overlap_config(true), rec.fs_hz, 4096);
  ASSERT_TRUE(d.innovation_mode());
  std::vector<float> xf(rec.x.begin(), rec.x.end());
  const auto at = [&](double t) { return static_cast<std::uint64_t>(std::llround(t * rec.fs_hz)); };
  double band = 0.0, innov = 0.0;
  std::size_t n = 0, pushed = 0;
  for (std::size_t i = 2; i < rec.onset_s.size(); ++i) {
    const std::size_t until = std::min<std::size_t>(xf.size(), at(rec.onset_s[i] + 0.015));
    if (until <= pushed) continue;
    d.push(std::span<const float>(xf.data() + pushed, until - pushed));
    pushed = until;
    while (d.has_onset()) d.pop_onset();
    const std::uint64_t end = at(rec.onset_s[i] - 0.00025), begin = end - at(0.002);
    const double b = d.band_power(begin, end), q = d.innovation_noise_power(begin, end);
    if (!std::isfinite(b) || !std::isfinite(q)) continue;
    band += b;
    innov += q;
    ++n;
  }
  ASSERT_GE(n, 80u);
  const double noise = s.noise_sd * s.noise_sd * d.band_noise_gain();
  const double band_ratio = band / static_cast<double>(n) / noise, innov_ratio = innov / static_cast<double>(n) / noise;
  std::cout << "pre-trigger power / noise band power: band " << band_ratio << ", innovation " << innov_ratio << "\n";
  EXPECT_GE(band_ratio, 10.0);
  EXPECT_GE(innov_ratio, 0.75);
  EXPECT_LE(innov_ratio, 1.35);
  // Energy mode: no innovation, NaN.
  ImpactDetector e(overlap_config(false), rec.fs_hz, 4096);
  EXPECT_FALSE(e.innovation_mode());
  EXPECT_TRUE(std::isnan(e.innovation_noise_power(0, 1000)));
}

// ringing_free_noise_power(): the same spans in energy mode, the ringing removed with the pole of the
// generator's mode (854 Hz, zeta 0.002; StreamProcessor takes it from the analysed impacts). Bounds as
// above. A pole 2 Hz off leaves part of the ringing (the prediction over the lag k, the onset model's
// peak time + 1 ms, about 5 ms here, turns by 2 pi 2 Hz k ~ 0.06 rad: |p - a^k|^2 ~ 4e-3 of the
// ringing, which stands over 40 dB above the noise in these spans), so the same average must then
// exceed 2x the noise: the test sees a wrong pole. A pole outside the band, or no damping, gives NaN.
TEST(DetectorInnovation, RingingFreeNoisePowerIsTheNoiseInEnergyMode) {
  indep::RigSpec s = overlap_rig(1.0);
  s.mesh_amp.clear();
  s.hum_amp.clear();
  s.spike_rate_hz = 0.0;
  const auto rec = indep::make_rig_record(s);
  ImpactDetector d(overlap_config(false), rec.fs_hz, 4096);
  ASSERT_FALSE(d.innovation_mode());
  std::vector<float> xf(rec.x.begin(), rec.x.end());
  const auto at = [&](double t) { return static_cast<std::uint64_t>(std::llround(t * rec.fs_hz)); };
  double band = 0.0, right = 0.0, off = 0.0;
  std::size_t n = 0, pushed = 0;
  for (std::size_t i = 2; i < rec.onset_s.size(); ++i) {
    const std::size_t until = std::min<std::size_t>(xf.size(), at(rec.onset_s[i] + 0.015));
    if (until <= pushed) continue;
    d.push(std::span<const float>(xf.data() + pushed, until - pushed));
    pushed = until;
    while (d.has_onset()) d.pop_onset();
    const std::uint64_t end = at(rec.onset_s[i] - 0.00025), begin = end - at(0.002);
    const double b = d.band_power(begin, end);
    const double q = d.ringing_free_noise_power(begin, end, s.response.f_hz, s.response.zeta);
    const double q_off = d.ringing_free_noise_power(begin, end, s.response.f_hz + 2.0, s.response.zeta);
    if (!std::isfinite(b) || !std::isfinite(q) || !std::isfinite(q_off)) continue;
    band += b;
    right += q;
    off += q_off;
    ++n;
  }
  ASSERT_GE(n, 80u);
  const double noise = s.noise_sd * s.noise_sd * d.band_noise_gain() * static_cast<double>(n);
  std::cout << "pre-trigger power / noise band power: band " << band / noise << ", ringing-free " << right / noise
            << ", with the pole 2 Hz off " << off / noise << "\n";
  EXPECT_GE(band / noise, 10.0);
  EXPECT_GE(right / noise, 0.75);
  EXPECT_LE(right / noise, 1.35);
  EXPECT_GE(off / noise, 2.0);
  EXPECT_TRUE(std::isnan(d.ringing_free_noise_power(at(1.0), at(1.002), 2000.0, 0.002)));
  EXPECT_TRUE(std::isnan(d.ringing_free_noise_power(at(1.0), at(1.002), 854.0, 0.0)));
}

}  // namespace
}  // namespace ridgewatch::pipeline
