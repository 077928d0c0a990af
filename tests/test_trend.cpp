// Trend monitor (core/trend): baseline learning, EWMA/CUSUM alarms on ln zeta, k-of-n confirmation,
// hysteresis, latching, robustness to non-ok events, configuration validation, and the acceptance
// numbers of issue 4 on synthetic event sequences:
//   ln zeta = ln 0.024 + N(0, sd) per event, sd = 0.02 (clean estimator) and 0.05 (noisy), fixed seeds.
// The statistical tests print the measured delay / rise / false-alarm figures (one "[trend]" line
// each); `build-trend/tests/test_trend --gtest_filter='*Acceptance*'` reproduces them.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "allocation_counter.hpp"
#include "core/pipeline/impact_event.hpp"  // the events the stream processor feeds
#include "core/trend/trend_monitor.hpp"

// allocation_counter.hpp lets a test assert that update() does not allocate (real-time contract in
// trend_monitor.hpp).

namespace ridgewatch::trend {
namespace {

using trend::AlarmLevel;
using trend::AlarmState;
using pipeline::ImpactEvent;
using pipeline::ImpactStatus;

constexpr double kZeta0 = 0.024;  // the paper rig's measured mean damping ratio

ImpactEvent event(double zeta, ImpactStatus status = ImpactStatus::ok) {
  ImpactEvent e;
  e.zeta = zeta;
  e.status = status;
  return e;
}

// Feeds one event as the stream processor does: its zeta, trusted when its status is ok.
AlarmState feed(TrendMonitor& m, const ImpactEvent& e) { return m.update(e.zeta, e.status == ImpactStatus::ok); }

bool alarming(AlarmLevel level) { return level == AlarmLevel::alert || level == AlarmLevel::danger; }

/// Standard normal deviates by Box-Muller on mt19937_64 (whose output the standard fixes), so the
/// sequences - and the numbers these tests print - are the same with every standard library.
class Gauss {
 public:
  explicit Gauss(std::uint64_t seed) : engine_(seed) {}
  double operator()() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u1 = 0.0;
    while (u1 <= 0.0) u1 = static_cast<double>(engine_() >> 11) * 0x1.0p-53;
    const double u2 = static_cast<double>(engine_() >> 11) * 0x1.0p-53;
    const double r = std::sqrt(-2.0 * std::log(u1));
    spare_ = r * std::sin(2.0 * std::numbers::pi * u2);
    has_spare_ = true;
    return r * std::cos(2.0 * std::numbers::pi * u2);
  }

 private:
  std::mt19937_64 engine_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

/// A config with a configured (known) baseline, so deterministic sequences need no learning phase.
TrendConfig known_baseline(double ln_sd = 0.05) {
  TrendConfig c;
  c.baseline_zeta = kZeta0;
  c.baseline_ln_sd = ln_sd;
  return c;
}

/// zeta that standardises to x baseline sd above the configured baseline.
double zeta_at(double x, double ln_sd = 0.05) { return kZeta0 * std::exp(x * ln_sd); }

double quantile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size())))];
}

// ---------------------------------------------------------------------------------------------------
// Baseline

TEST(TrendBaseline, LearningThenNormalWithMedianAndMad) {
  TrendConfig c;
  c.baseline_events = 7;
  TrendMonitor m(c);
  EXPECT_EQ(m.state().level, AlarmLevel::learning);
  // Deviations of ln zeta from ln zeta0: median 0, |deviations| sorted 0, .01, .02, .03, .04, .05, .5
  // -> MAD 0.03. The 0.5 outlier moves neither (that is why median/MAD and not mean/sd).
  const double dev[7] = {0.03, -0.01, 0.5, 0.0, -0.04, 0.02, -0.05};
  for (int i = 0; i < 6; ++i) {
    const AlarmState s = feed(m, event(kZeta0 * std::exp(dev[i])));
    EXPECT_EQ(s.level, AlarmLevel::learning) << i;
    EXPECT_FALSE(s.transition());
  }
  const AlarmState s = feed(m, event(kZeta0 * std::exp(dev[6])));
  EXPECT_EQ(s.level, AlarmLevel::normal);
  EXPECT_EQ(s.previous, AlarmLevel::learning);
  EXPECT_TRUE(s.transition());
  EXPECT_NEAR(s.baseline_ln_zeta, std::log(kZeta0), 1e-12);
  EXPECT_NEAR(s.baseline_ln_sd, 1.4826 * 0.03, 1e-12);
  // Next event: no transition any more.
  const AlarmState s2 = feed(m, event(kZeta0));
  EXPECT_EQ(s2.level, AlarmLevel::normal);
  EXPECT_FALSE(s2.transition());
}

TEST(TrendBaseline, EvenCountMedianAveragesTheMiddlePair) {
  TrendConfig c;
  c.baseline_events = 6;
  TrendMonitor m(c);
  // ln zeta0 + {-0.2, -0.1, 0, 0.1, 0.3, 0.4}: median 0.05; |dev| {.25,.15,.05,.05,.25,.35} -> MAD (.15+.25)/2 = 0.2.
  for (double d : {0.3, -0.1, 0.4, -0.2, 0.1, 0.0}) feed(m, event(kZeta0 * std::exp(d)));
  ASSERT_EQ(m.state().level, AlarmLevel::normal);
  EXPECT_NEAR(m.state().baseline_ln_zeta, std::log(kZeta0) + 0.05, 1e-12);
  EXPECT_NEAR(m.state().baseline_ln_sd, 1.4826 * 0.2, 1e-12);
}

TEST(TrendBaseline, LearnedSdIsFloored) {
  TrendConfig c;
  c.baseline_events = 5;
  c.min_baseline_ln_sd = 0.01;
  TrendMonitor m(c);
  for (int i = 0; i < 5; ++i) feed(m, event(kZeta0));  // identical estimates: MAD = 0
  ASSERT_EQ(m.state().level, AlarmLevel::normal);
  EXPECT_EQ(m.state().baseline_ln_sd, 0.01);
  // With the sd floored at 1 %, a persistent 0.5 % rise of zeta (0.5 sd: below the CUSUM reference
  // k = 1 and an EWMA of 1.3 EWMA sd) does not alarm; with sd = MAD = 0 it would be infinitely many sd.
  for (int i = 0; i < 200; ++i) EXPECT_EQ(feed(m, event(kZeta0 * 1.005)).level, AlarmLevel::normal) << i;
}

TEST(TrendBaseline, ConfiguredBaselineSkipsLearning) {
  TrendConfig c;
  c.baseline_zeta = 0.03;
  TrendMonitor m(c);
  EXPECT_EQ(m.state().level, AlarmLevel::normal);
  EXPECT_EQ(m.state().previous, AlarmLevel::normal);
  EXPECT_NEAR(m.state().baseline_ln_zeta, std::log(0.03), 1e-15);
  EXPECT_EQ(m.state().baseline_ln_sd, 0.05);  // the documented default spread
  const AlarmState s = feed(m, event(0.03));
  EXPECT_EQ(s.level, AlarmLevel::normal);
  EXPECT_FALSE(s.transition());

  c.baseline_ln_sd = 0.02;
  TrendMonitor m2(c);
  EXPECT_EQ(m2.state().baseline_ln_sd, 0.02);
}

TEST(TrendBaseline, ResetRelearns) {
  TrendConfig c;
  c.baseline_events = 5;
  TrendMonitor m(c);
  for (int i = 0; i < 5; ++i) feed(m, event(kZeta0));
  ASSERT_EQ(m.state().level, AlarmLevel::normal);
  m.reset();
  EXPECT_EQ(m.state().level, AlarmLevel::learning);
  EXPECT_TRUE(std::isnan(m.state().baseline_ln_zeta));
  for (int i = 0; i < 4; ++i) EXPECT_EQ(feed(m, event(0.05)).level, AlarmLevel::learning);
  EXPECT_EQ(feed(m, event(0.05)).level, AlarmLevel::normal);
  EXPECT_NEAR(m.state().baseline_ln_zeta, std::log(0.05), 1e-12);
}

// ---------------------------------------------------------------------------------------------------
// Events that must not move the statistics

TEST(TrendEvents, NonOkEventsDoNotMoveTheStatistics) {
  TrendConfig c;
  c.baseline_events = 5;
  TrendMonitor m(c);
  // While learning: bad events do not count towards the baseline.
  for (int i = 0; i < 4; ++i) feed(m, event(kZeta0));
  for (auto st : {ImpactStatus::low_snr, ImpactStatus::ridge_lost, ImpactStatus::window_cut, ImpactStatus::clipped,
                  ImpactStatus::spike, ImpactStatus::too_short, ImpactStatus::not_decaying, ImpactStatus::fit_failed,
                  ImpactStatus::inconsistent}) {
    EXPECT_EQ(feed(m, event(10.0 * kZeta0, st)).level, AlarmLevel::learning);
  }
  EXPECT_EQ(feed(m, event(NAN)).level, AlarmLevel::learning);   // ok but not finite
  EXPECT_EQ(feed(m, event(-0.01)).level, AlarmLevel::learning); // ok but not a damping ratio
  EXPECT_EQ(feed(m, event(0.0)).level, AlarmLevel::learning);
  EXPECT_EQ(feed(m, event(INFINITY)).level, AlarmLevel::learning);
  EXPECT_EQ(feed(m, event(kZeta0)).level, AlarmLevel::normal);
  EXPECT_NEAR(m.state().baseline_ln_zeta, std::log(kZeta0), 1e-15);

  // While monitoring: a long run of wildly high but non-ok estimates changes nothing at all.
  const AlarmState before = feed(m, event(kZeta0 * 1.01));
  for (int i = 0; i < 100; ++i) {
    const AlarmState s = feed(m, event(5.0 * kZeta0, ImpactStatus::inconsistent));
    EXPECT_EQ(s.level, AlarmLevel::normal);
    EXPECT_EQ(s.previous, AlarmLevel::normal);
    EXPECT_EQ(s.ewma_ln_zeta, before.ewma_ln_zeta);
    EXPECT_EQ(s.cusum_up, before.cusum_up);
    EXPECT_EQ(s.cusum_down, before.cusum_down);
  }
}

TEST(TrendEvents, NonOkEventDuringAlarmKeepsLevelWithPreviousEqualToLevel) {
  TrendMonitor m(known_baseline());
  AlarmState s;
  for (int i = 0; i < 10; ++i) s = feed(m, event(zeta_at(4.0)));
  ASSERT_TRUE(alarming(s.level));
  const AlarmState bad = feed(m, event(kZeta0, ImpactStatus::low_snr));
  EXPECT_EQ(bad.level, s.level);
  EXPECT_EQ(bad.previous, s.level);
  EXPECT_FALSE(bad.transition());
}

TEST(TrendEvents, UpdateDoesNotAllocate) {
  TrendConfig c;  // learned baseline: exercises the learning path (median/MAD) too
  TrendMonitor m(c);
  Gauss g(1);
  const long before = ridgewatch::test::allocations();
  for (int i = 0; i < 2000; ++i) feed(m, event(kZeta0 * std::exp(0.05 * g() + (i > 1000 ? 0.3 : 0.0))));
  const long after = ridgewatch::test::allocations();
  EXPECT_EQ(after - before, 0);
  EXPECT_TRUE(alarming(m.state().level));  // the loop did reach the alarm code
}

// ---------------------------------------------------------------------------------------------------
// Alarm logic on deterministic sequences (configured baseline, sd 0.05; x = standardised ln zeta).
// Default charts: EWMA lambda 0.25 -> EWMA sd 0.378 baseline sd; alert 5 EWMA sd = 1.89 baseline sd.

TEST(TrendLevels, ConstantShiftGivesAlertThenDangerAndEwmaTracksTheShift) {
  TrendMonitor m(known_baseline());
  // x = 4 (at the clip): EWMA -> 4 baseline sd = 10.6 EWMA sd > danger 9.
  std::vector<AlarmLevel> levels;
  for (int i = 0; i < 40; ++i) levels.push_back(feed(m, event(zeta_at(4.0))).level);
  EXPECT_EQ(levels.front(), AlarmLevel::normal);
  EXPECT_NE(std::find(levels.begin(), levels.end(), AlarmLevel::alert), levels.end());  // alert before danger
  EXPECT_EQ(levels.back(), AlarmLevel::danger);
  EXPECT_NEAR(m.state().ewma_ln_zeta, std::log(zeta_at(4.0)), 1e-3 * 0.05);  // converged to 4 sd
}

TEST(TrendLevels, CusumAloneGivesAlertNeverDanger) {
  // x = 1.5: EWMA -> 1.5 sd = 3.97 EWMA sd, below alert 5; CUSUM grows by 0.5 per event -> alert.
  // Documented decision: a CUSUM's height says how long, not how large, so it never makes danger.
  TrendMonitor m(known_baseline());
  AlarmState s;
  int first_alert = -1;
  for (int i = 0; i < 500; ++i) {
    s = feed(m, event(zeta_at(1.5)));
    if (first_alert < 0 && alarming(s.level)) first_alert = i;
    if (first_alert >= 0) {
      ASSERT_EQ(s.level, AlarmLevel::alert) << i;
    }
  }
  EXPECT_GE(first_alert, 15);  // C+ > 8 after 17 events, + 2 for 3-of-5 confirmation
  EXPECT_LE(first_alert, 20);
  EXPECT_EQ(s.cusum_up, 16.0);  // capped at 2 h
}

TEST(TrendLevels, KOfNIsolatedOutliersDoNotAlarm) {
  // Bursts of three consecutive +10 sd estimates (clipped to 4) every 50 events. One burst takes
  // the EWMA to 6.1 EWMA sd (> alert 5) and C+ to 9 (> h 8) for exactly one event, then both fall back.
  // With 3-of-5 confirmation that never alarms; with 1-of-1 it must.
  auto run = [](std::size_t k, std::size_t n) {
    TrendConfig c = known_baseline();
    c.confirm_k = k;
    c.confirm_n = n;
    TrendMonitor m(c);
    int alarms = 0;
    for (int i = 0; i < 1000; ++i) {
      const bool outlier = i % 50 >= 20 && i % 50 < 23;
      alarms += alarming(feed(m, event(zeta_at(outlier ? 10.0 : 0.0))).level) ? 1 : 0;
    }
    return alarms;
  };
  EXPECT_EQ(run(3, 5), 0);
  EXPECT_EQ(run(2, 5), 0);
  EXPECT_GT(run(1, 1), 0);  // the same sequence without confirmation alarms (the test can fail)
}

TEST(TrendLevels, KOfNNeedsKOfTheLastNEvents) {
  // Alternating above/below the alert limit of a memoryless chart (lambda 1: EWMA = x; CUSUM off):
  // 2-of-4 confirms; 3-of-4 never does.
  auto run = [](std::size_t k) {
    TrendConfig c = known_baseline();
    c.ewma_lambda = 1.0;
    c.alert_sigma = 3.0;
    c.danger_sigma = 3.5;
    c.cusum_h = 1e6;
    c.confirm_k = k;
    c.confirm_n = 4;
    TrendMonitor m(c);
    int first = -1;
    for (int i = 0; i < 40 && first < 0; ++i) {
      if (alarming(feed(m, event(zeta_at(i % 2 == 0 ? 3.2 : 0.0))).level)) first = i;
    }
    return first;
  };
  EXPECT_EQ(run(2), 2);  // events 0 and 2 beyond the limit
  EXPECT_EQ(run(3), -1);
}

TEST(TrendLevels, HysteresisStopsChatteringAtTheLimit) {
  // The EWMA hovers at the alert limit: inputs alternate around L = 5 EWMA sd = 1.890 baseline sd so
  // that the EWMA swings +-0.1 EWMA sd across the limit. CUSUM disabled (huge h) to isolate the EWMA.
  auto transitions = [](double hysteresis, int& alarm_events) {
    TrendConfig c = known_baseline();
    c.cusum_h = 1e6;
    c.hysteresis_sigma = hysteresis;
    c.confirm_k = 2;
    c.confirm_n = 3;
    TrendMonitor m(c);
    const double sd_factor = std::sqrt(0.25 / 1.75);
    const double limit_x = 5.0 * sd_factor;
    // EWMA e_i alternates limit +- d: e = 0.25 x + 0.75 e_prev -> x = (e - 0.75 e_prev) / 0.25.
    const double d = 0.1 * sd_factor;
    int count = 0;
    alarm_events = 0;
    // Ramp the EWMA up to the limit from below first.
    for (int i = 0; i < 60; ++i) feed(m, event(zeta_at(limit_x - 2.0 * d)));
    double e_prev = m.state().ewma_ln_zeta - std::log(kZeta0);
    e_prev /= 0.05;
    for (int i = 0; i < 400; ++i) {
      const double e = limit_x + (i % 2 == 0 ? d : -d);
      const double x = (e - 0.75 * e_prev) / 0.25;
      e_prev = e;
      const AlarmState s = feed(m, event(zeta_at(x)));
      count += s.transition() ? 1 : 0;
      alarm_events += alarming(s.level) ? 1 : 0;
    }
    // The statistic falls well below limit - hysteresis: the alert clears.
    AlarmState s;
    for (int i = 0; i < 60; ++i) {
      s = feed(m, event(zeta_at(0.0)));
      count += s.transition() ? 1 : 0;
    }
    EXPECT_EQ(s.level, AlarmLevel::normal);
    return count;
  };
  int alarm_events = 0;
  EXPECT_EQ(transitions(1.0, alarm_events), 2);  // normal -> alert once, alert -> normal once at the end
  EXPECT_GE(alarm_events, 398);                   // held through the hover (entered after 2 of 3)
  EXPECT_GT(transitions(0.0, alarm_events), 50);  // without hysteresis it chatters (the test can fail)
}

TEST(TrendLevels, LatchingHoldsUntilResetLatch) {
  auto excursion = [](TrendMonitor& m) {
    for (int i = 0; i < 20; ++i) feed(m, event(zeta_at(4.0)));
    for (int i = 0; i < 100; ++i) feed(m, event(zeta_at(0.0)));
  };
  {  // not latching: the level clears after the excursion
    TrendMonitor m(known_baseline());
    excursion(m);
    EXPECT_EQ(m.state().level, AlarmLevel::normal);
    EXPECT_FALSE(m.state().latched);
  }
  TrendConfig c = known_baseline();
  c.latching = true;
  TrendMonitor m(c);
  excursion(m);
  EXPECT_EQ(m.state().level, AlarmLevel::danger);  // the highest level reached is held
  EXPECT_TRUE(m.state().latched);
  m.reset_latch();
  EXPECT_EQ(m.state().level, AlarmLevel::normal);
  EXPECT_EQ(m.state().previous, AlarmLevel::danger);  // the reset is a visible transition
  EXPECT_FALSE(m.state().latched);
  EXPECT_EQ(feed(m, event(kZeta0)).level, AlarmLevel::normal);

  // Reset while the statistics still alarm: the level follows them (and latches again).
  for (int i = 0; i < 20; ++i) feed(m, event(zeta_at(4.0)));
  ASSERT_EQ(m.state().level, AlarmLevel::danger);
  m.reset_latch();
  EXPECT_EQ(m.state().level, AlarmLevel::danger);
  EXPECT_EQ(feed(m, event(zeta_at(4.0))).level, AlarmLevel::danger);
  EXPECT_TRUE(m.state().latched);

  // A latched alert still escalates to danger.
  m.reset();
  for (int i = 0; i < 40; ++i) feed(m, event(zeta_at(1.5)));  // CUSUM alert only
  ASSERT_EQ(m.state().level, AlarmLevel::alert);
  for (int i = 0; i < 20; ++i) feed(m, event(zeta_at(4.0)));
  EXPECT_EQ(m.state().level, AlarmLevel::danger);
}

TEST(TrendLevels, AlarmOnDecrease) {
  auto first_alarm_after_drop = [](bool on_decrease, std::uint64_t seed) {
    TrendConfig c;
    c.alarm_on_decrease = on_decrease;
    TrendMonitor m(c);
    Gauss g(seed);
    for (int i = 0; i < 600; ++i) {
      const double zeta = kZeta0 * (i >= 300 ? 0.75 : 1.0) * std::exp(0.05 * g());
      const AlarmState s = feed(m, event(zeta));
      if (alarming(s.level)) return i - 300;  // negative: before the drop
    }
    return 1000;
  };
  for (std::uint64_t seed = 1; seed <= 20; ++seed) {
    EXPECT_EQ(first_alarm_after_drop(false, seed), 1000) << "seed " << seed;  // rising only by default
    const int delay = first_alarm_after_drop(true, seed);
    EXPECT_GE(delay, 0) << "seed " << seed;
    EXPECT_LT(delay, 10) << "seed " << seed;
  }
  // The lower CUSUM moves and the upper does not; at x = -1.5 (EWMA -3.97 EWMA sd, inside the alert
  // limit) only the lower CUSUM can raise the alert.
  TrendConfig c = known_baseline();
  c.alarm_on_decrease = true;
  TrendMonitor m(c);
  AlarmState s;
  for (int i = 0; i < 40; ++i) s = feed(m, event(zeta_at(-1.5)));
  EXPECT_EQ(s.cusum_up, 0.0);
  EXPECT_GT(s.cusum_down, 8.0);
  EXPECT_EQ(s.level, AlarmLevel::alert);
}

// ---------------------------------------------------------------------------------------------------
// Acceptance (issue 4): +25 % damping step, slow drift, false alarms. Default configuration
// (learned baseline of 256 events). Delay = number of post-step events up to and including the first
// one whose state is alert or danger, so "within 10 impacts" is delay <= 10.

struct StepResult {
  int delay = -1;          // -1: no alarm after the step
  bool early = false;      // an alarm before the step
};

StepResult run_step(double ln_sd, std::uint64_t seed, int before = 300, int after = 100) {
  TrendMonitor m(TrendConfig{});
  Gauss g(seed);
  StepResult r;
  for (int i = 0; i < before + after; ++i) {
    const double step = i >= before ? 1.25 : 1.0;
    const AlarmState s = feed(m, event(kZeta0 * step * std::exp(ln_sd * g())));
    if (!alarming(s.level)) continue;
    if (i < before) {
      r.early = true;
    } else {
      r.delay = i - before + 1;
    }
    break;
  }
  return r;
}

TEST(TrendAcceptance, DampingStepAlarmsWithinTenImpacts) {
  // Measured with 1000 seeds (this code, defaults): delay at sd 0.02: 4-5 (the +4 sd clip and 3-of-5
  // confirmation set the floor); sd 0.05: median 5, max 6; sd 0.06: max 8; sd 0.07: p99 9,
  // max 12; sd 0.10: median 9, max 23. So the 10-impact requirement holds for sd <= 0.06.
  for (double ln_sd : {0.02, 0.05}) {
    std::vector<double> delays;
    for (std::uint64_t seed = 1; seed <= 50; ++seed) {
      const StepResult r = run_step(ln_sd, seed);
      EXPECT_FALSE(r.early) << "sd " << ln_sd << " seed " << seed;
      EXPECT_GE(r.delay, 1) << "sd " << ln_sd << " seed " << seed;
      EXPECT_LE(r.delay, 10) << "sd " << ln_sd << " seed " << seed;
      delays.push_back(r.delay);
    }
    std::printf("[trend] +25%% step, sd %.2f, 50 seeds: delay min %g median %g p90 %g max %g impacts\n", ln_sd,
                quantile(delays, 0.0), quantile(delays, 0.5), quantile(delays, 0.9), quantile(delays, 1.0));
  }
}

TEST(TrendAcceptance, SlowDriftAlarmsBeforeThirtyPercent) {
  // 10 min of 25 Hz impacts = 15000 events after 300 stationary ones; zeta rises linearly by 30 %.
  for (double ln_sd : {0.02, 0.05}) {
    std::vector<double> rises;
    for (std::uint64_t seed = 1; seed <= 20; ++seed) {
      TrendMonitor m(TrendConfig{});
      Gauss g(1000 + seed);
      double rise_at_alarm = -1.0;
      for (int i = 0; i < 15300; ++i) {
        const double rise = i < 300 ? 0.0 : 0.30 * (i - 300) / 15000.0;
        const AlarmState s = feed(m, event(kZeta0 * (1.0 + rise) * std::exp(ln_sd * g())));
        if (alarming(s.level)) {
          ASSERT_GE(i, 300) << "alarm before the drift started, sd " << ln_sd << " seed " << seed;
          rise_at_alarm = rise;
          break;
        }
      }
      ASSERT_GT(rise_at_alarm, 0.0) << "no alarm during the drift, sd " << ln_sd << " seed " << seed;
      EXPECT_LT(rise_at_alarm, 0.30);
      rises.push_back(100.0 * rise_at_alarm);
    }
    std::printf("[trend] drift +30%% over 15000 events, sd %.2f, 20 seeds: alarm at rise min %.1f%% median %.1f%% max %.1f%%\n",
                ln_sd, quantile(rises, 0.0), quantile(rises, 0.5), quantile(rises, 1.0));
  }
}

TEST(TrendAcceptance, NoFalseAlarmOnLongStationarySequences) {
  // 10 x 20 000 stationary events at sd 0.05 (learned baseline each time). The measured ARL of the
  // defaults is ~8e6 events with a learned baseline (1e8 events simulated), so the chance of any
  // alarm in these 2e5 events is ~2.5 %: zero is the expected and asserted outcome.
  long events = 0, alarms = 0;
  for (std::uint64_t seed = 1; seed <= 10; ++seed) {
    TrendMonitor m(TrendConfig{});
    Gauss g(5000 + seed);
    for (int i = 0; i < 20000; ++i) {
      const AlarmState s = feed(m, event(kZeta0 * std::exp(0.05 * g())));
      events += s.level != AlarmLevel::learning ? 1 : 0;
      alarms += alarming(s.level) && !alarming(s.previous) ? 1 : 0;
    }
  }
  std::printf("[trend] stationary sd 0.05: %ld monitored events, %ld false alarms\n", events, alarms);
  EXPECT_EQ(alarms, 0);
}

TEST(TrendAcceptance, LooseDefaultsWouldFalseAlarm) {
  // Sanity check that the stationary test above can fail: textbook limits (lambda 0.2, L = 3,
  // CUSUM k 0.5 h 4, 20-event baseline, no confirmation) alarm many times on the same sequences.
  TrendConfig c;
  c.baseline_events = 20;
  c.ewma_lambda = 0.2;
  c.alert_sigma = 3.0;
  c.danger_sigma = 6.0;
  c.cusum_k = 0.5;
  c.cusum_h = 4.0;
  c.confirm_k = 1;
  c.confirm_n = 1;
  long alarms = 0;
  for (std::uint64_t seed = 1; seed <= 10; ++seed) {
    TrendMonitor m(c);
    Gauss g(5000 + seed);
    for (int i = 0; i < 20000; ++i) {
      const AlarmState s = feed(m, event(kZeta0 * std::exp(0.05 * g())));
      alarms += alarming(s.level) && !alarming(s.previous) ? 1 : 0;
    }
  }
  EXPECT_GT(alarms, 10);
}

TEST(TrendAcceptance, DISABLED_MeasureArlAndDelays) {
  // The numbers quoted in trend_monitor.hpp (about a minute at -O2):
  //   build-trend/tests/test_trend --gtest_also_run_disabled_tests --gtest_filter='*MeasureArl*'
  // ARL0: stationary runs of 2e5 events with a fresh learned baseline each, until 1e8 monitored
  // events; alarms = entries into alert/danger. Delays: 1000 seeds, 300 events then +25 %.
  long events = 0, alarms = 0;
  for (std::uint64_t seed = 1; events < 100'000'000; ++seed) {
    TrendMonitor m(TrendConfig{});
    Gauss g(seed * 7919 + 1);
    for (int i = 0; i < 200'000; ++i) {
      const AlarmState s = feed(m, event(kZeta0 * std::exp(0.05 * g())));
      events += s.level != AlarmLevel::learning ? 1 : 0;
      alarms += alarming(s.level) && !alarming(s.previous) ? 1 : 0;
    }
  }
  std::printf("[trend] ARL0 (learned baseline): %ld events, %ld alarms -> ARL %.3g events\n", events, alarms,
              alarms > 0 ? static_cast<double>(events) / static_cast<double>(alarms) : INFINITY);
  for (double ln_sd : {0.02, 0.05, 0.06, 0.07, 0.08, 0.10}) {
    std::vector<double> delays;
    int early = 0, missed = 0;
    for (std::uint64_t seed = 1; seed <= 1000; ++seed) {
      const StepResult r = run_step(ln_sd, seed, 300, 200);
      if (r.early) ++early;
      else if (r.delay < 0) ++missed;
      else delays.push_back(r.delay);
    }
    std::printf("[trend] +25%% step sd %.2f, 1000 seeds: early %d missed %d delay median %g p90 %g p99 %g max %g\n",
                ln_sd, early, missed, quantile(delays, 0.5), quantile(delays, 0.9), quantile(delays, 0.99),
                quantile(delays, 1.0));
  }
}

// ---------------------------------------------------------------------------------------------------
// Configuration validation

std::string validation_message(const TrendConfig& c) {
  try {
    validate(c);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(TrendConfigValidation, DefaultsAreValid) { EXPECT_EQ(validation_message(TrendConfig{}), ""); }

TEST(TrendConfigValidation, MessagesNameTheField) {
  struct Case {
    void (*mutate)(TrendConfig&);
    const char* message;
  };
  const Case cases[] = {
      {[](TrendConfig& c) { c.ewma_lambda = 0.0; }, "trend.ewma_lambda: must be in (0, 1] (got 0)"},
      {[](TrendConfig& c) { c.ewma_lambda = 1.5; }, "trend.ewma_lambda: must be in (0, 1] (got 1.5)"},
      {[](TrendConfig& c) { c.ewma_lambda = NAN; }, "trend.ewma_lambda: must be in (0, 1] (got nan)"},
      {[](TrendConfig& c) { c.baseline_events = 4; }, "trend.baseline_events: must be in [5, 256] (got 4)"},
      {[](TrendConfig& c) { c.baseline_events = 257; }, "trend.baseline_events: must be in [5, 256] (got 257)"},
      {[](TrendConfig& c) { c.baseline_zeta = 0.0; }, "trend.baseline_zeta: must be > 0"},
      {[](TrendConfig& c) { c.baseline_ln_sd = -1.0; }, "trend.baseline_ln_sd: must be > 0"},
      {[](TrendConfig& c) { c.min_baseline_ln_sd = 0.0; }, "trend.min_baseline_ln_sd: must be > 0"},
      {[](TrendConfig& c) { c.alert_sigma = 0.0; }, "trend.alert_sigma: must be > 0"},
      {[](TrendConfig& c) { c.danger_sigma = 5.0; }, "trend.danger_sigma: must be finite and > alert_sigma (got 5)"},
      {[](TrendConfig& c) { c.danger_sigma = 11.0; }, "trend.danger_sigma: must be below clip_sigma"},
      {[](TrendConfig& c) { c.cusum_k = -0.1; }, "trend.cusum_k: must be >= 0"},
      {[](TrendConfig& c) { c.cusum_h = 0.0; }, "trend.cusum_h: must be > 0"},
      {[](TrendConfig& c) { c.clip_sigma = 0.5; }, "trend.clip_sigma: must be > cusum_k"},
      {[](TrendConfig& c) { c.hysteresis_sigma = -1.0; }, "trend.hysteresis_sigma: must be >= 0"},
      {[](TrendConfig& c) { c.hysteresis_sigma = 5.0; }, "trend.hysteresis_sigma: must be >= 0 and below alert_sigma"},
      {[](TrendConfig& c) { c.confirm_n = 0; }, "trend.confirm_n: must be in [1, 64] (got 0)"},
      {[](TrendConfig& c) { c.confirm_n = 65; }, "trend.confirm_n: must be in [1, 64] (got 65)"},
      {[](TrendConfig& c) { c.confirm_k = 0; }, "trend.confirm_k: must be in [1, confirm_n] (got 0)"},
      {[](TrendConfig& c) { c.confirm_k = 6; }, "trend.confirm_k: must be in [1, confirm_n] (got 6)"},
  };
  for (const Case& k : cases) {
    TrendConfig c;
    k.mutate(c);
    const std::string msg = validation_message(c);
    EXPECT_EQ(msg.rfind(k.message, 0), 0u) << "got: " << msg << "\nwant prefix: " << k.message;
    EXPECT_THROW(TrendMonitor{c}, std::invalid_argument) << k.message;
  }
  // Unclipped input makes any danger limit reachable.
  TrendConfig c;
  c.clip_sigma = INFINITY;
  c.danger_sigma = 50.0;
  EXPECT_EQ(validation_message(c), "");
}

}  // namespace
}  // namespace ridgewatch::trend
