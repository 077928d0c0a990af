// ImpactDetector on its own (core/pipeline/impact_detector.hpp): bit-identical output for any push
// pattern, no allocation while pushing, onset accuracy at every position of an onset relative to the
// detector's block grid, spikes at every block position, the first impact of a record that starts with
// steady mesh lines (synthetic lines and the simulator's mesh_stiffness_variation / transmission_error),
// and the decision delay (samples from an impact's onset until it is reported).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iostream>
#include <numbers>
#include <random>
#include <span>
#include <vector>

#include "allocation_counter.hpp"
#include "core/model/simulator.hpp"
#include "core/pipeline/impact_detector.hpp"
#include "core/pipeline/stream_processor.hpp"

namespace ridgewatch::pipeline {
namespace {

constexpr double kF = 860.0;     // damped frequency of the synthetic free responses, Hz
constexpr double kZeta = 0.024;  // their damping ratio (the paper rig's)

struct Signal {
  std::vector<float> x;
  std::vector<std::uint64_t> onsets;
};

struct Options {
  double fs = 51200.0;
  double seconds = 1.0;
  std::vector<double> onset_s;  // impact onsets
  double amplitude = 0.5;
  double noise_sd = 0.005;  // 1 % of the impact peak
  double line_550 = 0.0, line_1100 = 0.0;
  std::vector<double> spike_s;
  unsigned seed = 1;
};

// x(t) = A exp(-sigma (t - t0)) sin(omega_d (t - t0)) after each onset t0 (Eq. 16 with phi = 0), plus
// steady lines switched on with the record, white noise and single-sample spikes of twice the peak.
Signal make(const Options& o) {
  const auto n = static_cast<std::size_t>(o.seconds * o.fs);
  std::vector<double> acc(n, 0.0);
  Signal s;
  const double omega = 2.0 * std::numbers::pi * kF;
  const double sigma = kZeta * omega / std::sqrt(1.0 - kZeta * kZeta);
  for (double t0 : o.onset_s) {
    const auto k0 = static_cast<std::size_t>(std::ceil(t0 * o.fs));
    s.onsets.push_back(k0);
    const double tk0 = static_cast<double>(k0) / o.fs;  // onset on the sample grid
    for (std::size_t k = k0; k < n; ++k) {
      const double t = static_cast<double>(k) / o.fs - tk0;
      if (sigma * t > 40) break;
      acc[k] += o.amplitude * std::exp(-sigma * t) * std::sin(omega * t);
    }
  }
  std::mt19937_64 rng(o.seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  for (std::size_t k = 0; k < n; ++k) {
    const double t = static_cast<double>(k) / o.fs;
    acc[k] += o.line_550 * std::sin(2 * std::numbers::pi * 550 * t + 0.3) +
              o.line_1100 * std::sin(2 * std::numbers::pi * 1100 * t + 1.1) + o.noise_sd * gauss(rng);
  }
  for (double ts : o.spike_s) acc[static_cast<std::size_t>(ts * o.fs)] += 2.0 * o.amplitude;
  s.x.assign(acc.begin(), acc.end());
  return s;
}

std::vector<std::uint64_t> detect(ImpactDetector& d, const std::vector<float>& x, std::size_t block) {
  std::vector<std::uint64_t> out;
  d.restart(0);
  for (std::size_t i = 0; i < x.size(); i += block) {
    const std::size_t len = std::min(block, x.size() - i);
    if (block == 1) {
      d.push(x[i]);
    } else {
      d.push(std::span<const float>(x.data() + i, len));
    }
    while (d.has_onset()) out.push_back(d.pop_onset());
  }
  d.finish();
  while (d.has_onset()) out.push_back(d.pop_onset());
  return out;
}

// Every true onset has exactly one detection within tol samples, nothing else.
void expect_onsets(const std::vector<std::uint64_t>& got, const std::vector<std::uint64_t>& truth, double tol,
                   const char* what) {
  ASSERT_EQ(got.size(), truth.size()) << what;
  for (std::size_t i = 0; i < truth.size(); ++i)
    EXPECT_LE(std::abs(static_cast<double>(got[i]) - static_cast<double>(truth[i])), tol)
        << what << ": impact " << i << " at " << truth[i] << " detected at " << got[i];
}

// At 51.2, 25.6 and 8 kHz (processing runs of 80, 40 and 12 samples: 4 blocks of 2, 2 and 3 band
// samples), pushes of 1, 3, 37, 81 (a run and one), 1000 and 4096 samples: the onsets, the spike count
// and a band power from the end of the record (band_power() reads the stored history: 0.2 s at
// 51.2 kHz).
TEST(ImpactDetector, OutputDoesNotDependOnPushPattern) {
  for (double fs : {51200.0, 25600.0, 8000.0}) {
    Options o;
    o.fs = fs;
    o.seconds = 1.0;
    for (double t = 0.0123; t < 1.0; t += 0.04) o.onset_s.push_back(t);
    o.line_550 = 0.1;
    o.spike_s = {0.3001, 0.5109, 0.7777};
    const Signal s = make(o);
    const ImpactDetectorConfig cfg;
    ImpactDetector ref(cfg, o.fs, 4096);
    const auto a = detect(ref, s.x, 4096);
    ASSERT_EQ(a.size(), s.onsets.size()) << fs;
    const auto at = [&](double t) { return static_cast<std::uint64_t>(t * fs); };
    const double p_ref = ref.band_power(at(0.906), at(0.925));
    ASSERT_TRUE(std::isfinite(p_ref)) << fs;
    for (std::size_t block : {std::size_t{1}, std::size_t{3}, std::size_t{37}, std::size_t{81}, std::size_t{1000}}) {
      ImpactDetector d(cfg, o.fs, 4096);
      EXPECT_EQ(detect(d, s.x, block), a) << fs << " " << block;
      EXPECT_EQ(d.spikes_seen(), ref.spikes_seen()) << fs << " " << block;
      const double p = d.band_power(at(0.906), at(0.925));
      EXPECT_EQ(std::memcmp(&p, &p_ref, sizeof p), 0) << fs << " " << block;
    }
  }
}

TEST(ImpactDetector, PushDoesNotAllocate) {
  Options o;
  for (double t = 0.0123; t < 1.0; t += 0.04) o.onset_s.push_back(t);
  o.line_550 = 0.1;
  o.spike_s = {0.3001};
  const Signal s = make(o);
  ImpactDetector d(ImpactDetectorConfig{}, o.fs, 4096);
  std::size_t found = 0;
  const long before = test::allocations();
  for (int pass = 0; pass < 2; ++pass) {
    d.restart(static_cast<std::uint64_t>(pass) * 1000000);
    for (float v : s.x) {
      d.push(v);
      while (d.has_onset()) found += d.pop_onset() > 0 ? 1 : 0;
    }
    d.finish();
    found += d.has_onset() ? 1 : 0;
  }
  EXPECT_EQ(test::allocations() - before, 0) << "allocations while pushing";
  EXPECT_EQ(found, 2 * s.onsets.size());
}

// Onsets at every position relative to the block grid (D consecutive sample offsets), at both
// common rates. Tolerance 0.1 ms: the accuracy target on the simulated rig (the detector's
// t50 calibration uses the same model shape, so the residual error is the interpolation between band
// samples and the noise; measured max |error| is printed).
TEST(ImpactDetector, OnsetWithinTenthOfAMillisecondAtEveryBlockPosition) {
  for (double fs : {25600.0, 51200.0}) {
    const ImpactDetectorConfig cfg;
    ImpactDetector d(cfg, fs, 4096);
    Options o;
    o.fs = fs;
    o.seconds = 0.05 * static_cast<double>(d.decimation()) + 0.1;
    for (std::size_t p = 0; p < d.decimation(); ++p)
      o.onset_s.push_back(0.0203 + 0.05 * static_cast<double>(p) + static_cast<double>(p) / fs);
    const Signal s = make(o);
    const auto got = detect(d, s.x, 4096);
    expect_onsets(got, s.onsets, 0.0001 * fs, "block positions");
    double worst = 0.0;
    for (std::size_t i = 0; i < std::min(got.size(), s.onsets.size()); ++i)
      worst = std::max(worst, std::abs(static_cast<double>(got[i]) - static_cast<double>(s.onsets[i])));
    std::cout << "fs " << fs << " D " << d.decimation() << ": max |onset error| " << worst / fs * 1e3
              << " ms, model t50 spread over block positions " << d.t50_spread_samples() << " samples\n";
  }
}

TEST(ImpactDetector, SpikesAtEveryBlockPositionAreRemoved) {
  const ImpactDetectorConfig cfg;
  const double fs = 51200.0;
  ImpactDetector d(cfg, fs, 4096);
  Options o;
  o.seconds = 1.0;
  o.line_550 = 0.1;
  o.line_1100 = 0.05;
  for (std::size_t p = 0; p < 2 * d.decimation(); ++p)
    o.spike_s.push_back((0.1 + 0.02 * static_cast<double>(p)) + (static_cast<double>(p) + 0.5) / fs);
  const Signal s = make(o);
  EXPECT_TRUE(detect(d, s.x, 512).empty());
  EXPECT_EQ(d.spikes_seen(), o.spike_s.size());
}

// Issue: the first impact was missed when steady lines start with the record. Lines as strong as
// sim-nuisance's (25 % and 18 % of the impact peak), first impact 2.5-40 ms after the start.
// Mesh lines at 550 and 1100 Hz from the first sample, impacts every 40 ms from `first` on; every
// onset within `tol_s`.
void expect_first_impacts_under_lines(double fs, double first, double tol_s, const char* what) {
  Options o;
  o.fs = fs;
  o.seconds = 0.3;
  o.line_550 = 0.125;
  o.line_1100 = 0.09;
  for (double t = first; t < 0.28; t += 0.04) o.onset_s.push_back(t);
  const Signal s = make(o);
  ImpactDetector d(ImpactDetectorConfig{}, fs, 4096);
  const auto got = detect(d, s.x, 4096);
  expect_onsets(got, s.onsets, tol_s * fs, what);
}

TEST(ImpactDetector, FirstImpactWithLinesFromTheStart) {
  for (double fs : {25600.0, 51200.0})
    for (double first : {0.0025, 0.005, 0.0064, 0.010, 0.020, 0.030, 0.040})
      expect_first_impacts_under_lines(fs, first, 0.0002, "lines from the start");
}

// The same with the simulator: mesh_stiffness_variation and transmission_error run from t = 0, the
// crack angle puts the first impact at 6.4, 20 or 30 ms. Tolerance 0.2 ms from the start of the
// 0.15 ms force pulse (the onset accuracy on the simulated rig).
TEST(ImpactDetector, FirstImpactOfSimulatedRecordWithMeshLines) {
  for (const char* effect : {"mesh_stiffness_variation", "transmission_error"}) {
    for (double crack : {1.0, std::numbers::pi, 1.5 * std::numbers::pi}) {
      model::RigParameters rig;
      rig.crack_angle_rad = crack;
      model::SimulationSettings st;
      st.duration_s = 0.25;
      st.sample_rate_hz = 25600.0;
      const auto r = model::simulate(rig, {{effect, {}}, {"noise", {{"std_rel", 0.005}}}}, st);
      std::vector<float> x(r.output.begin(), r.output.end());
      std::vector<std::uint64_t> truth;
      for (const auto& imp : r.impacts)
        if (imp.t_s < 0.2) truth.push_back(static_cast<std::uint64_t>(std::ceil(imp.t_s * st.sample_rate_hz)));
      ImpactDetector d(ImpactDetectorConfig{}, st.sample_rate_hz, 4096);
      std::vector<std::uint64_t> got;
      for (std::uint64_t o : detect(d, x, 4096))
        if (static_cast<double>(o) < 0.201 * st.sample_rate_hz) got.push_back(o);  // the compared span
      ASSERT_EQ(got.size(), truth.size()) << effect << " crack " << crack;
      // The simulated rig starts at rest and rings at its natural frequency when the mesh excitation
      // switches on with the record (about 40 % of an impact's amplitude, decaying with the same
      // zeta): an impact within the first ~10 ms sits on that ring and interferes with it coherently,
      // which moves the 50 % crossing of the envelope. Measured up to 0.31 ms at 6.4 ms; allowed
      // 0.5 ms there (the requirement is +-1 ms), 0.2 ms for the later impacts.
      for (std::size_t i = 0; i < truth.size(); ++i) {
        const double tol = (static_cast<double>(truth[i]) < 0.012 * st.sample_rate_hz ? 0.0005 : 0.0002) * st.sample_rate_hz;
        EXPECT_LE(std::abs(static_cast<double>(got[i]) - static_cast<double>(truth[i])), tol)
            << effect << " crack " << crack << ": impact " << i << " at " << truth[i] << " detected at " << got[i];
      }
    }
  }
}

// Decision delay: samples from the true onset until the detection is reported, for strong and
// barely detectable impacts at every block position; it never exceeds report_delay_samples(), which
// is lookback_samples() + decision_delay_samples() (what StreamProcessor waits after a window's end).
TEST(ImpactDetector, DecisionDelayIsBoundedAndMeasured) {
  for (double fs : {25600.0, 51200.0}) {
    const ImpactDetectorConfig cfg;
    ImpactDetector d(cfg, fs, 4096);
    EXPECT_EQ(d.report_delay_samples(), d.lookback_samples() + d.decision_delay_samples());
    std::size_t worst = 0;
    for (double amplitude : {0.5, 0.05, 0.02, 0.012}) {
      Options o;
      o.fs = fs;
      o.amplitude = amplitude;
      o.noise_sd = 0.001;  // weakest impact: peak 12x the noise sd, near the trigger ratio
      o.seconds = 0.05 * static_cast<double>(d.decimation()) + 0.1;
      for (std::size_t p = 0; p < d.decimation(); ++p)
        o.onset_s.push_back(0.0603 + 0.05 * static_cast<double>(p) + static_cast<double>(p) / fs);
      const Signal s = make(o);
      d.restart(0);
      std::size_t next = 0;
      for (std::size_t i = 0; i < s.x.size(); ++i) {
        d.push(s.x[i]);
        while (d.has_onset()) {
          const std::uint64_t onset = d.pop_onset();
          ASSERT_LT(next, s.onsets.size()) << "amplitude " << amplitude << ": extra onset " << onset;
          ASSERT_GE(i, s.onsets[next]) << "amplitude " << amplitude << ": onset " << onset << " reported early";
          const std::size_t delay = i - s.onsets[next];
          EXPECT_LE(delay, d.report_delay_samples()) << "amplitude " << amplitude;
          worst = std::max(worst, delay);
          ++next;
        }
      }
      EXPECT_EQ(next, s.onsets.size()) << "amplitude " << amplitude;
    }
    std::cout << "fs " << fs << ": measured max report delay " << worst << " samples ("
              << 1e3 * static_cast<double>(worst) / fs << " ms); bound report_delay_samples() "
              << d.report_delay_samples() << " (" << 1e3 * static_cast<double>(d.report_delay_samples()) / fs
              << " ms) = lookback " << d.lookback_samples() << " + decision " << d.decision_delay_samples() << "\n";
    // The per-sample design's bound was 13.9 ms (look-back 7.6 ms + refinement 6.3 ms) at the defaults;
    // this one: max(peak 6.6 ms + 1 ms, look-back 7.7 ms + confirmation 1.6 ms) + run (1.6 ms) and
    // spike delay (12 samples since the spike test also looks 10 samples right of a candidate: +8
    // samples, 0.16-0.31 ms, against 11.0 ms before).
    EXPECT_LE(static_cast<double>(d.report_delay_samples()) / fs, 0.0113);
  }
}

// finish() right when the block pointer reaches the end of the input buffer: with D = 1 and a block
// of 8 or 4 samples (band 500-1500 Hz at 22050 and 11025 Hz; runs of 4 blocks) finish() decides up to
// run + 3 samples and clears the residual slot past them, which once lay one float beyond the buffer
// (and the vectorised spike stage reads and writes a few slots past a run). Every (block count,
// leftover) pair around the buffer's length (64 blocks: 16 runs), so every position relative to the
// run grid, a fresh detector each time; an overflow shows under AddressSanitizer (build-asan), the
// results must be sane everywhere.
TEST(ImpactDetector, FinishAtEveryOffsetNearTheBufferEnd) {
  ImpactDetectorConfig cfg;
  cfg.band_lo_hz = 500.0;
  cfg.band_hi_hz = 1500.0;
  for (double fs : {22050.0, 11025.0}) {
    std::mt19937_64 rng(7);
    std::normal_distribution<double> gauss(0.0, 0.01);
    std::vector<float> x(80 * 64);
    for (float& v : x) v = static_cast<float>(gauss(rng));
    std::size_t blk = 0;
    {
      ImpactDetector probe(cfg, fs, 4096);
      ASSERT_EQ(probe.decimation(), 1u) << fs;
      blk = static_cast<std::size_t>(std::floor(0.0004 * fs));  // the detector's block (D = 1)
    }
    for (std::size_t count = 56; count <= 74; ++count) {
      for (std::size_t offset = 0; offset <= blk + 3; ++offset) {
        ImpactDetector d(cfg, fs, 4096);
        d.restart(0);
        const std::size_t n = count * blk + offset;
        ASSERT_LE(n, x.size());
        d.push(std::span<const float>(x.data(), n));
        d.finish();
        EXPECT_EQ(d.next_index(), n) << fs << " " << count << " " << offset;
        EXPECT_FALSE(d.has_onset()) << fs << " " << count << " " << offset;
        // Pushing may go on after finish() (the buffer shifts if needed).
        d.push(std::span<const float>(x.data() + n, 2 * blk + 5));
        d.finish();
        EXPECT_EQ(d.next_index(), n + 2 * blk + 5);
      }
    }
  }
}

// An impact shortly before the end of the stream: finish() resolves its trigger with the envelope
// seen so far. While the envelope is still rising (the model peaks 6.6 ms after the onset at the
// default 730-980 Hz band), half of the truncated maximum is crossed early, and an onset from it would
// be early (measured without the rule: 2.3 ms early at 1.5 ms before the end, 0.6 ms at 4 ms, 0.16 ms
// at 5 ms); no onset is emitted then. Every onset reported must lie within 0.1 ms of its impact (as at every block
// position above), and an impact whose maximum is final before the end (>= the model's peak time +
// 2 ms before it) must be found.
TEST(ImpactDetector, NoOnsetFromAMaximumTruncatedByTheEndOfTheStream) {
  const double fs = 51200.0;
  const ImpactDetectorConfig cfg;
  std::size_t found_late = 0, cases = 0;
  for (double before_end_ms = 1.0; before_end_ms <= 12.0; before_end_ms += 0.5) {
    ImpactDetector d(cfg, fs, 4096);
    Options o;
    o.fs = fs;
    o.seconds = 0.2;
    o.onset_s = {0.05, 0.2 - 1e-3 * before_end_ms};
    const Signal s = make(o);
    const auto got = detect(d, s.x, 4096);
    ASSERT_GE(got.size(), 1u) << before_end_ms;
    ASSERT_LE(got.size(), 2u) << before_end_ms;
    EXPECT_LE(std::abs(static_cast<double>(got[0]) - static_cast<double>(s.onsets[0])), 0.0001 * fs);
    if (got.size() == 2) {
      EXPECT_LE(std::abs(static_cast<double>(got[1]) - static_cast<double>(s.onsets[1])), 0.0001 * fs)
          << "impact " << before_end_ms << " ms before the end: onset "
          << (static_cast<double>(got[1]) - static_cast<double>(s.onsets[1])) / fs * 1e3 << " ms off";
    }
    if (1e-3 * before_end_ms * fs >= d.peak_samples() + 0.002 * fs) {
      ++cases;
      found_late += got.size() == 2;
    }
  }
  EXPECT_GT(cases, 0u);
  EXPECT_EQ(found_late, cases);
}

// At 8 kHz (D = 1, 3-sample blocks) the spike stage's scale is not yet ready at the last warm-up band
// sample; the LTA must still be raised to the white-noise band power once it is. A quiet start (the
// first 1.5 ms of the record hold 1 % of the noise) leaves the cumulative LTA ~1e-4 of the noise
// power, and its capped growth (at most (1 + 2/n) per band sample) lifts it only ~400-fold by 30 ms.
// The raise sets it to the white band power measured by the residual MAD over the first 32 samples,
// of which ~20 hold the full noise: ~(20/32)^2 = 0.4 of sigma^2 band_noise_gain(), growing from there.
// Checked at 30 ms: between 0.25 and 2 times the white band power (lta() divides out the capped
// mean's bias).
TEST(ImpactDetector, StartUpLtaRaiseAtLowSampleRate) {
  const double fs = 8000.0;
  const double sd = 0.01;
  std::mt19937_64 rng(3);
  std::normal_distribution<double> gauss(0.0, sd);
  ImpactDetector d(ImpactDetectorConfig{}, fs, 4096);
  ASSERT_EQ(d.decimation(), 1u);
  d.restart(0);
  const auto n = static_cast<std::size_t>(0.030 * fs);
  for (std::size_t i = 0; i < n; ++i) d.push(static_cast<float>(gauss(rng) * (i < 12 ? 0.01 : 1.0)));
  const double white = sd * sd * d.band_noise_gain();
  std::cout << "8 kHz, quiet start: LTA at 30 ms / white band power = " << d.lta() / white << "\n";
  EXPECT_GT(d.lta(), 0.25 * white);
  EXPECT_LT(d.lta(), 2.0 * white);
}

// The first impact under steady lines (as FirstImpactWithLinesFromTheStart) at 8 kHz.
TEST(ImpactDetector, FirstImpactWithLinesFromTheStartAtEightKilohertz) {
  // 0.25 ms: two samples at 8 kHz (the 0.2 ms of the higher rates is below 2 samples here).
  for (double first : {0.0064, 0.010, 0.020, 0.030, 0.040})
    expect_first_impacts_under_lines(8000.0, first, 0.00025, "lines from the start, 8 kHz");
}

// band_noise_gain() (E[e] for unit white input) against the analytic value for narrow and default
// bands: complex demodulation puts the +-B band at baseband with density 1/fs, and the 4th-order
// Butterworth low-pass (cut-off B) passes its equivalent noise bandwidth 2 B (pi/8) / sin(pi/8) =
// 2.0523 B, so E[e] = 2.0523 B / fs. Tolerance 1 %: the bilinear warping at fs_d >= 40 B changes the
// cut-off by < 0.2 %, the triangular FIR's droop within +-2 B is < 0.1 % at fs_d >= 40 B. (Summed
// over a fixed 0.25 s the gain was 6 % of this for a 2 Hz wide band and 67 % at 4 Hz.)
TEST(ImpactDetector, BandNoiseGainOfNarrowBands) {
  for (double fs : {25600.0, 51200.0}) {
    for (double width : {2.0, 4.0, 10.0, 40.0, 250.0}) {
      ImpactDetectorConfig cfg;
      cfg.band_lo_hz = 855.0 - 0.5 * width;
      cfg.band_hi_hz = 855.0 + 0.5 * width;
      const ImpactDetector d(cfg, fs, 4096);
      const double b = 0.5 * width;
      const double expected = 2.0 * (std::numbers::pi / 8.0) / std::sin(std::numbers::pi / 8.0) * b / fs;
      EXPECT_NEAR(d.band_noise_gain() / expected, 1.0, 0.01) << "fs " << fs << " width " << width;
    }
  }
}

// trigger_noise_ratio (stage 4's noise floor): with trigger_ratio lowered to 3 (as the survey proposes
// when decays fill the interval), a band that holds white noise only triggers on the noise's own
// exponential tail (P(e > 3 x mean) = e^-3 per correlation time ~1/B = 8 ms: dozens in 5 s). With
// the floor at 12 x the white-noise band power (P = e^-12 = 6e-6 per correlation time, 4e-3 in 5 s)
// none; impacts that stand far above the noise (peak 100 x the noise sd, the band's energy ~1e4 x
// its noise power) are all found, at the same onsets as without the floor.
TEST(ImpactDetector, NoiseFloorKeepsBandNoiseFromALoweredTriggerRatio) {
  Options o;
  o.seconds = 5.0;
  o.noise_sd = 0.005;
  o.amplitude = 0.5;
  ImpactDetectorConfig cfg;
  cfg.trigger_ratio = 3.0;
  const Signal noise = make(o);
  {
    ImpactDetector d(cfg, o.fs, 4096);
    const auto got = detect(d, noise.x, 4096);
    std::cout << "white noise only, trigger_ratio 3: " << got.size() << " events in 5 s\n";
    EXPECT_GE(got.size(), 10u);  // the condition the floor is for (expected ~40)
  }
  cfg.trigger_noise_ratio = 12.0;
  {
    ImpactDetector d(cfg, o.fs, 4096);
    EXPECT_TRUE(detect(d, noise.x, 4096).empty());
  }
  o.onset_s = {0.30, 1.10, 2.05, 3.30, 4.40};
  const Signal impacts = make(o);
  ImpactDetectorConfig plain;
  plain.trigger_ratio = 3.0;
  ImpactDetector d0(plain, o.fs, 4096), d1(cfg, o.fs, 4096);
  const auto without = detect(d0, impacts.x, 4096);
  const auto with = detect(d1, impacts.x, 4096);
  // 0.1 ms: the onset accuracy of OnsetWithinTenthOfAMillisecondAtEveryBlockPosition.
  expect_onsets(with, impacts.onsets, 0.0001 * o.fs, "noise floor 12");
  EXPECT_GT(without.size(), impacts.onsets.size());  // the same record without the floor: noise events too
}

}  // namespace
}  // namespace ridgewatch::pipeline
