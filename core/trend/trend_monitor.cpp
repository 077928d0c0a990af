// Damping trend and alarms; the method and its references are in trend_monitor.hpp.
#include "core/trend/trend_monitor.hpp"

#include <algorithm>
#include <bit>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace ridgewatch::trend {

namespace {



/// Consistency constant of the MAD for a normal distribution: sd = 1.4826 MAD (= 1 / Phi^-1(3/4)).
constexpr double kMadToSd = 1.4826;
/// Spread of ln zeta assumed with a configured baseline zeta and no configured spread: 5 %, the noisy
/// end of the per-impact estimator's scatter (1-3 % clean, 5-10 % noisy), so a configured baseline
/// errs towards fewer false alarms.
constexpr double kDefaultConfiguredLnSd = 0.05;
/// Each CUSUM is capped at this multiple of h (see the header).
constexpr double kCusumCapFactor = 2.0;

template <typename T>
[[noreturn]] void fail(const char* field, const char* requirement, T got) {
  std::ostringstream os;
  os << "trend." << field << ": " << requirement << " (got " << got << ")";
  throw std::invalid_argument(os.str());
}

bool positive_finite(double v) { return std::isfinite(v) && v > 0.0; }

/// Median of values[0..n) (reorders them). n >= 1.
double median_in_place(double* values, std::size_t n) {
  double* mid = values + n / 2;
  std::nth_element(values, mid, values + n);
  const double upper = *mid;
  if (n % 2 == 1) return upper;
  const double lower = *std::max_element(values, mid);  // after nth_element all of [0, n/2) <= *mid
  return 0.5 * (lower + upper);
}

int severity(AlarmLevel level) {
  switch (level) {
    case AlarmLevel::learning: return 0;
    case AlarmLevel::normal: return 1;
    case AlarmLevel::alert: return 2;
    case AlarmLevel::danger: return 3;
  }
  return 0;
}

}  // namespace

void validate(const TrendConfig& c) {
  if (c.baseline_events < 5 || c.baseline_events > kMaxBaselineEvents)
    fail("baseline_events", "must be in [5, 256]", c.baseline_events);
  if (!std::isnan(c.baseline_zeta) && !positive_finite(c.baseline_zeta))
    fail("baseline_zeta", "must be > 0 and finite, or unset to learn the baseline", c.baseline_zeta);
  if (!std::isnan(c.baseline_ln_sd) && !positive_finite(c.baseline_ln_sd))
    fail("baseline_ln_sd", "must be > 0 and finite, or unset", c.baseline_ln_sd);
  if (!positive_finite(c.min_baseline_ln_sd))
    fail("min_baseline_ln_sd", "must be > 0 and finite", c.min_baseline_ln_sd);
  if (!(c.ewma_lambda > 0.0 && c.ewma_lambda <= 1.0)) fail("ewma_lambda", "must be in (0, 1]", c.ewma_lambda);
  if (!positive_finite(c.alert_sigma)) fail("alert_sigma", "must be > 0 and finite", c.alert_sigma);
  if (!(std::isfinite(c.danger_sigma) && c.danger_sigma > c.alert_sigma))
    fail("danger_sigma", "must be finite and > alert_sigma", c.danger_sigma);
  if (!(std::isfinite(c.cusum_k) && c.cusum_k >= 0.0)) fail("cusum_k", "must be >= 0 and finite", c.cusum_k);
  if (!positive_finite(c.cusum_h)) fail("cusum_h", "must be > 0 and finite", c.cusum_h);
  if (!(c.clip_sigma > c.cusum_k)) fail("clip_sigma", "must be > cusum_k (inf: no clipping)", c.clip_sigma);
  // The EWMA of inputs clipped to +-clip_sigma never exceeds clip_sigma / sqrt(lambda / (2 - lambda))
  // of its sd: a danger limit at or above that could never be reached.
  if (std::isfinite(c.clip_sigma) && c.clip_sigma > 0.0 && c.ewma_lambda > 0.0 && c.ewma_lambda <= 1.0) {
    const double reachable = c.clip_sigma / std::sqrt(c.ewma_lambda / (2.0 - c.ewma_lambda));
    if (!(c.danger_sigma < reachable)) {
      std::ostringstream os;
      os << "must be below clip_sigma / sqrt(ewma_lambda / (2 - ewma_lambda)) = " << reachable
         << ", the largest EWMA the clipped input can reach";
      fail("danger_sigma", os.str().c_str(), c.danger_sigma);
    }
  }
  // The clear thresholds (limit - hysteresis) must stay above the baseline, else a level never clears
  // (the CUSUM is >= 0, so h - hysteresis <= 0 would hold it forever).
  if (!(std::isfinite(c.hysteresis_sigma) && c.hysteresis_sigma >= 0.0 && c.hysteresis_sigma < c.alert_sigma &&
        c.hysteresis_sigma < c.cusum_h))
    fail("hysteresis_sigma", "must be >= 0 and below alert_sigma and cusum_h", c.hysteresis_sigma);
  if (c.confirm_n < 1 || c.confirm_n > kMaxConfirmEvents) fail("confirm_n", "must be in [1, 64]", c.confirm_n);
  if (c.confirm_k < 1 || c.confirm_k > c.confirm_n) fail("confirm_k", "must be in [1, confirm_n]", c.confirm_k);
}

TrendMonitor::TrendMonitor(const TrendConfig& config) : config_(config) {
  validate(config_);
  ewma_sd_factor_ = std::sqrt(config_.ewma_lambda / (2.0 - config_.ewma_lambda));
  window_mask_ = config_.confirm_n == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << config_.confirm_n) - 1;
  reset();
}

void TrendMonitor::reset() {
  state_ = AlarmState{};
  baseline_count_ = 0;
  ewma_x_ = 0.0;
  over_alert_bits_ = over_danger_bits_ = 0;
  statistics_level_ = AlarmLevel::learning;
  if (!std::isnan(config_.baseline_zeta)) {
    const double sd = std::isnan(config_.baseline_ln_sd) ? kDefaultConfiguredLnSd : config_.baseline_ln_sd;
    start_monitoring(std::log(config_.baseline_zeta), sd);
    state_.previous = AlarmLevel::normal;  // never learned: no learning -> normal transition
  }
}

void TrendMonitor::start_monitoring(double baseline_ln_zeta, double baseline_ln_sd) {
  state_.baseline_ln_zeta = baseline_ln_zeta;
  state_.baseline_ln_sd = baseline_ln_sd;
  state_.ewma_ln_zeta = baseline_ln_zeta;
  state_.cusum_up = state_.cusum_down = 0.0;
  state_.level = statistics_level_ = AlarmLevel::normal;
}

void TrendMonitor::reset_latch() {
  state_.previous = state_.level;
  state_.latched = false;
  state_.level = statistics_level_;
}

AlarmState TrendMonitor::update(double zeta, bool trusted) {
  state_.previous = state_.level;
  if (!trusted || !std::isfinite(zeta) || !(zeta > 0.0)) return state_;
  const double ln_zeta = std::log(zeta);
  if (state_.level == AlarmLevel::learning)
    learn(ln_zeta);
  else
    monitor(ln_zeta);
  return state_;
}

// Baseline from the first baseline_events good events: median and MAD of ln zeta, robust to the odd
// wrong-but-ok estimate. The sd is floored at min_baseline_ln_sd (default 0.01 = 1 % in zeta): the
// per-impact estimator's scatter is >= 1 % even on clean signals, and a baseline learned from a
// lucky quiet stretch (or identical values, MAD = 0) would otherwise make every later event an alarm.
void TrendMonitor::learn(double ln_zeta) {
  baseline_buf_[baseline_count_++] = ln_zeta;
  const std::size_t n = baseline_count_;
  if (n < config_.baseline_events) return;
  std::copy(baseline_buf_, baseline_buf_ + n, scratch_buf_);
  const double median = median_in_place(scratch_buf_, n);
  for (std::size_t i = 0; i < n; ++i) scratch_buf_[i] = std::abs(baseline_buf_[i] - median);
  const double mad = median_in_place(scratch_buf_, n);
  start_monitoring(median, std::max(kMadToSd * mad, config_.min_baseline_ln_sd));
}

void TrendMonitor::monitor(double ln_zeta) {
  const TrendConfig& c = config_;
  const double x = std::clamp((ln_zeta - state_.baseline_ln_zeta) / state_.baseline_ln_sd, -c.clip_sigma, c.clip_sigma);

  ewma_x_ = c.ewma_lambda * x + (1.0 - c.ewma_lambda) * ewma_x_;
  const double cap = kCusumCapFactor * c.cusum_h;
  state_.cusum_up = std::min(cap, std::max(0.0, state_.cusum_up + x - c.cusum_k));
  state_.cusum_down = std::min(cap, std::max(0.0, state_.cusum_down - x - c.cusum_k));
  state_.ewma_ln_zeta = state_.baseline_ln_zeta + state_.baseline_ln_sd * ewma_x_;

  // Statistics in their own units: EWMA in EWMA sd (signed so that positive is the alarming side),
  // CUSUM in baseline sd. Falling damping only counts with alarm_on_decrease.
  const double ewma_up = ewma_x_ / ewma_sd_factor_;
  const double ewma = c.alarm_on_decrease ? std::abs(ewma_up) : ewma_up;
  const double cusum = c.alarm_on_decrease ? std::max(state_.cusum_up, state_.cusum_down) : state_.cusum_up;

  const bool over_alert = ewma > c.alert_sigma || cusum > c.cusum_h;
  const bool over_danger = ewma > c.danger_sigma;
  over_alert_bits_ = ((over_alert_bits_ << 1) | (over_alert ? 1u : 0u)) & window_mask_;
  over_danger_bits_ = ((over_danger_bits_ << 1) | (over_danger ? 1u : 0u)) & window_mask_;
  const auto k = static_cast<int>(c.confirm_k);
  const bool confirmed_alert = std::popcount(over_alert_bits_) >= k;
  const bool confirmed_danger = std::popcount(over_danger_bits_) >= k;
  const double hy = c.hysteresis_sigma;
  const bool holds_alert = ewma > c.alert_sigma - hy || cusum > c.cusum_h - hy;
  const bool holds_danger = ewma > c.danger_sigma - hy;

  const AlarmLevel was = statistics_level_;
  if (confirmed_danger || (was == AlarmLevel::danger && holds_danger))
    statistics_level_ = AlarmLevel::danger;
  else if (confirmed_alert || ((was == AlarmLevel::alert || was == AlarmLevel::danger) && holds_alert))
    statistics_level_ = AlarmLevel::alert;
  else
    statistics_level_ = AlarmLevel::normal;

  if (c.latching && state_.latched && severity(state_.level) > severity(statistics_level_)) return;  // held
  state_.level = statistics_level_;
  if (c.latching && severity(state_.level) >= severity(AlarmLevel::alert)) state_.latched = true;
}

}  // namespace ridgewatch::trend
