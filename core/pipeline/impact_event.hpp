// One event per detected impact: the contract the daemon's event log and `ridgewatch analyze` print
// (JSON Lines, see README "Event log"). Plain value type, no allocation when copied.
#pragma once

#include <cmath>
#include <cstdint>
#include <string_view>

#include "core/trend/alarm.hpp"

namespace ridgewatch::pipeline {

/// Why an impact's estimate is not trustworthy; `ok` when it is.
enum class ImpactStatus : std::uint8_t {
  ok,
  low_snr,       ///< the free response does not stand far enough above the noise
  ridge_lost,    ///< no ridge near the expected natural frequency (or it wanders off)
  window_cut,    ///< the next impact (or a data gap / end of stream) cut the decay window short
  clipped,       ///< samples at the converter's full scale inside the window
  spike,         ///< an isolated outlier (sensor spike/dropout) inside the window
  too_short,     ///< not enough decay left for an estimate
  not_decaying,  ///< the envelope does not decay
  fit_failed,    ///< the estimator did not converge
  inconsistent,  ///< independent estimators disagree beyond their uncertainties
};
std::string_view to_string(ImpactStatus status);

struct ImpactEvent {
  std::uint64_t sample_index = 0;  ///< impact onset, samples from stream start
  double t_s = 0.0;                ///< sample_index / sample rate
  double f_hz = NAN;               ///< damped natural frequency of the free response
  double f_sd_hz = NAN;
  double zeta = NAN;               ///< damping ratio
  double zeta_ci95_lo = NAN;
  double zeta_ci95_hi = NAN;
  double snr_db = NAN;             ///< envelope peak power over noise power in the analysis band
  double amplitude = NAN;          ///< envelope amplitude at the start of the fit (signal units)
  double window_s = NAN;           ///< length of the decay window analysed, seconds
  /// End (exclusive, absolute sample index) of the samples the analysis read: the decay window's end
  /// (where the decay reached the floor, the next impact, a gap or window_s). 0 when not set. Not in
  /// the event log; the daemon's capture and latency use it.
  std::uint64_t window_end_index = 0;
  ImpactStatus status = ImpactStatus::ok;
  trend::AlarmState alarm;  ///< the trend after this event
};

}  // namespace ridgewatch::pipeline
