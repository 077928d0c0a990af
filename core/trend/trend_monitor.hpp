// Damping trend and alarms on ln zeta: baseline (learned from the first good events, median/MAD, or
// configured), EWMA and two-sided CUSUM, alert/danger levels with hysteresis and k-of-n confirmation,
// optional latching. Pure: the caller feeds events in stream order; sample indices are the clock.
//
// Statistic. Only events with status ok and finite zeta > 0 count ("good" events). For those,
//   x = (ln zeta - mu0) / sigma0,   clipped to [-clip_sigma, +clip_sigma]
// where mu0, sigma0 are the baseline mean and per-event sd of ln zeta. The log makes a relative
// change of zeta an additive shift (+25 % zeta -> +ln 1.25 = +0.223) whatever the baseline zeta is,
// and the per-impact estimator's scatter is close to constant in relative terms.
//
// Charts (both on the clipped x):
//  - EWMA  z_i = lambda x_i + (1 - lambda) z_{i-1}, z_0 = 0, compared with limits in units of its
//    own asymptotic sd sqrt(lambda / (2 - lambda)) (Roberts 1959; Montgomery, Introduction to
//    Statistical Quality Control, 6th ed., Eq. 9.22-9.25; Lucas & Saccucci 1990, Technometrics 32).
//    alert: |z| > alert_sigma sd, danger: |z| > danger_sigma sd. The EWMA converges to the shift
//    itself, so it measures severity: it is the only source of `danger`.
//  - Tabular CUSUM (Page 1954, Biometrika 41; Montgomery Eq. 9.2-9.3):
//    C+_i = max(0, C+_{i-1} + x_i - k),  C-_i = max(0, C-_{i-1} - x_i - k); alert when C > h.
//    C+ watches rising damping (crack growth and wear raise damping), C- falling damping
//    (alarm_on_decrease). A CUSUM's height grows with the duration of a shift, not its size, so a
//    larger multiple of h would say "the alert has lasted longer", not "it is worse": the CUSUM
//    raises alert only. Each CUSUM is capped at 2 h so it clears within about (h + hysteresis) / k
//    events after the damping has returned to baseline.
//  - Clipping x (winsorisation, Hawkins 1993, J. Quality Technology 25:248-261) bounds what one
//    wrong-but-ok estimate can do: lambda * clip_sigma < alert_sigma * sqrt(lambda / (2 - lambda))
//    and clip_sigma - k < h mean a single outlier can never cross a limit.
//
// Levels. An event "exceeds alert" when the EWMA or a CUSUM is beyond its alert limit, "exceeds
// danger" when the EWMA is beyond the danger limit. A level is entered when at least confirm_k of
// the last confirm_n good events exceeded it (k-of-n), and left only when every statistic is back
// below (limit - hysteresis_sigma) (hysteresis, in each chart's own sd units). With latching,
// alert/danger are held (and can still escalate) until reset_latch().
//
// Defaults and the trade-off they make (synthetic ln zeta = ln 0.024 + N(0, sd), sd = 0.05, the noisy
// end of the per-impact estimator's scatter; ARL0 = average run length in events to a false alarm
// over 1e8 stationary events, each run with its own learned baseline; delay = impacts after a +25 %
// step until alert/danger, 1000 seeds; reproduce the default row with tests/test_trend's
// DISABLED_MeasureArlAndDelays):
//
//   baseline  EWMA lambda/alert  CUSUM k/h  clip  k-of-n |  ARL0 events   | step delay median / max
//   20        0.20 / 3           0.5 / 8    4     3/5    |  5.7e2 (23 s)  | 4 / 6
//   200       0.20 / 4           1.0 / 6    4     3/5    |  1.5e5 (1.6 h) | 4 / 6
//   256       0.25 / 5           1.0 / 8    4     3/5    |  7.7e6 (3.5 d) | 5 / 6   <- defaults
//   256       0.25 / 5           1.0 / 8    4     1/1    |  5.3e5 (5.9 h) | 3 / 4
//   256       0.25 / 5           1.0 / 8    off   3/5    |  6.3e6         | 4 / 6
//   256       0.25 / 5.5         1.0 / 9    4     3/5    |  ~5e7 (2 alarms in 1e8) | 5 / 8
// (times at 25 impacts/s). With the baseline known exactly the defaults' ARL0 is ~5e7 events: most
// false alarms of a learned baseline come from the runs whose 256-event baseline came out narrow.
// The defaults spend part of the 10-impact budget (3-of-5 confirmation, +4 sd clip: the delay is >= 4
// even for a huge step) on robustness, and buy an ARL0 of days. Delay at other scatter (defaults):
// sd 0.02: 5 / 5; sd 0.06: 5 / 8; sd 0.07: 6 / 12 (p99 9); sd 0.10: 9 / 23. The 10-impact target is
// met for every seed up to sd ~ 0.06; beyond that the shift is < 3.7 sd per event and no chart with an
// ARL0 of days can confirm it in 10 events. Slow drift (+30 % linear over 15000 events): alarm at a
// rise of 1.3-2.7 % (sd 0.02) and 3-7 % (sd 0.05). Danger at 9 EWMA sd = 3.4 baseline sd (+19 % zeta
// at sd 0.05, +7 % at sd 0.02): danger, like alert, is in units of the scatter, not of zeta.
//
// Real-time: update() does not allocate and does not throw; everything lives in fixed-size members.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "core/trend/alarm.hpp"

namespace ridgewatch::trend {

/// Largest baseline_events (the learning buffer is a fixed-size member).
inline constexpr std::size_t kMaxBaselineEvents = 256;
/// Largest confirm_n (the k-of-n history is a 64-bit word).
inline constexpr std::size_t kMaxConfirmEvents = 64;

struct TrendConfig {
  std::size_t baseline_events = 256; ///< good events that form the learned baseline, [5, 256]
  double baseline_zeta = NAN;        ///< configured baseline zeta (> 0): no learning when set
  double baseline_ln_sd = NAN;       ///< spread of ln zeta with a configured baseline (> 0); NaN: 0.05
  double min_baseline_ln_sd = 0.01;  ///< floor of a learned sd of ln zeta (> 0), see trend_monitor.cpp
  double ewma_lambda = 0.25;         ///< EWMA weight of the newest event, (0, 1]
  double alert_sigma = 5.0;          ///< EWMA alert limit in standard deviations of the EWMA (> 0)
  double danger_sigma = 9.0;         ///< EWMA danger limit (> alert_sigma, < clip_sigma / sqrt(lambda/(2-lambda)))
  double cusum_k = 1.0;              ///< CUSUM reference value, in baseline sd (>= 0)
  double cusum_h = 8.0;              ///< CUSUM decision interval for alert, in baseline sd (> 0)
  double clip_sigma = 4.0;           ///< standardised ln zeta clipped to +-clip_sigma (> cusum_k; inf: off)
  double hysteresis_sigma = 1.0;     ///< a level clears only below (limit - hysteresis), [0, alert_sigma)
  std::size_t confirm_k = 3;         ///< a level is entered when k of the last n events exceed it
  std::size_t confirm_n = 5;         ///< (1 <= k <= n <= 64)
  bool latching = false;             ///< alert/danger stay until reset_latch()
  bool alarm_on_decrease = false;    ///< also alarm when damping falls (default: rising only)
};

/// Throws std::invalid_argument naming the field when a value is out of range,
/// e.g. "trend.ewma_lambda: must be in (0, 1] (got 0)".
void validate(const TrendConfig& config);

class TrendMonitor {
 public:
  /// Validates the configuration (throws std::invalid_argument, see validate()).
  explicit TrendMonitor(const TrendConfig& config);
  /// Feeds one event's damping ratio. Only a trusted estimate (the event's status is ok) with a finite
  /// zeta > 0 moves the statistics; any other returns the current state unchanged, with
  /// previous = level. Returns the state after the event. Does not allocate or throw.
  AlarmState update(double zeta, bool trusted);
  /// Clears a latched alarm (the level then follows the statistics again).
  void reset_latch();
  /// Forgets everything (baseline relearned unless configured).
  void reset();
  const AlarmState& state() const { return state_; }

 private:
  void start_monitoring(double baseline_ln_zeta, double baseline_ln_sd);
  void learn(double ln_zeta);
  void monitor(double ln_zeta);

  TrendConfig config_;
  AlarmState state_;
  double baseline_buf_[kMaxBaselineEvents] = {};  // ln zeta of the good events seen while learning
  double scratch_buf_[kMaxBaselineEvents] = {};   // absolute deviations for the MAD
  std::size_t baseline_count_ = 0;
  double ewma_sd_factor_ = 1.0;   // sqrt(lambda / (2 - lambda)): EWMA sd in baseline sd units
  double ewma_x_ = 0.0;           // EWMA of the clipped standardised ln zeta
  std::uint64_t window_mask_ = 0; // low confirm_n bits set
  std::uint64_t over_alert_bits_ = 0, over_danger_bits_ = 0;  // last n events beyond the limits
  AlarmLevel statistics_level_ = AlarmLevel::learning;  // level without latching
};

}  // namespace ridgewatch::trend
