// Damping trend and alarms on ln zeta: baseline (learned from the first good events, median/MAD, or
// configured), EWMA and two-sided CUSUM, alert/danger levels with hysteresis and k-of-n confirmation,
// optional latching. Pure: the caller feeds events in stream order; sample indices are the clock.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::trend {

struct TrendConfig {
  std::size_t baseline_events = 20;  ///< good events that form the learned baseline (>= 5)
  double baseline_zeta = NAN;        ///< configured baseline zeta (> 0): no learning when set
  double baseline_ln_sd = NAN;       ///< spread of ln zeta with a configured baseline (> 0); NaN: 0.05
  double ewma_lambda = 0.2;          ///< EWMA weight of the newest event, (0, 1]
  double alert_sigma = 3.0;          ///< EWMA alert limit in standard deviations of the EWMA (> 0)
  double danger_sigma = 6.0;         ///< EWMA danger limit (> alert_sigma)
  double cusum_k = 0.5;              ///< CUSUM reference value, in baseline sd (>= 0)
  double cusum_h = 8.0;              ///< CUSUM decision interval for alert, in baseline sd (> 0)
  double hysteresis_sigma = 1.0;     ///< a level clears only below (limit - hysteresis) (>= 0)
  std::size_t confirm_k = 3;         ///< a level is entered when k of the last n events exceed it
  std::size_t confirm_n = 5;         ///< (1 <= k <= n <= 64)
  bool latching = false;             ///< alert/danger stay until reset_latch()
  bool alarm_on_decrease = false;    ///< also alarm when damping falls (default: rising only)
};

/// Throws std::invalid_argument naming the field when a value is out of range.
void validate(const TrendConfig& config);

class TrendMonitor {
 public:
  explicit TrendMonitor(const TrendConfig& config);
  /// Feeds one event; only events with status ok and finite zeta move the statistics (others return
  /// the current state unchanged, with previous = level). Returns the state after the event.
  pipeline::AlarmState update(const pipeline::ImpactEvent& event);
  /// Clears a latched alarm (the level then follows the statistics again).
  void reset_latch();
  /// Forgets everything (baseline relearned unless configured).
  void reset();
  const pipeline::AlarmState& state() const { return state_; }

 private:
  TrendConfig config_;
  pipeline::AlarmState state_;
  // implementation fields as needed (fixed-size buffers: no allocation in update())
  double baseline_buf_[256] = {};
  std::size_t baseline_count_ = 0;
  std::uint64_t over_alert_bits_ = 0, over_danger_bits_ = 0;  // last n events above the limits
  std::size_t seen_ = 0;
};

}  // namespace ridgewatch::trend
