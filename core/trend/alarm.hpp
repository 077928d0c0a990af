// The trend's alarm state after each event: level, its transition and the statistics behind it.
// Plain value types; the trend monitor (trend_monitor.hpp) produces them, every impact event carries
// one (core/pipeline/impact_event.hpp), the sinks print them.
#pragma once

#include <cmath>
#include <cstdint>
#include <string_view>

namespace ridgewatch::trend {

/// Trend alarm level after an event. `learning` while the baseline is being learned.
enum class AlarmLevel : std::uint8_t { learning, normal, alert, danger };
std::string_view to_string(AlarmLevel level);

struct AlarmState {
  AlarmLevel level = AlarmLevel::learning;
  AlarmLevel previous = AlarmLevel::learning;  ///< level before this event (transition if different)
  bool latched = false;                        ///< held at alert/danger until reset (latching mode)
  double baseline_ln_zeta = NAN;               ///< learned or configured baseline of ln zeta
  double baseline_ln_sd = NAN;                 ///< spread of ln zeta per event at baseline
  double ewma_ln_zeta = NAN;                   ///< EWMA of ln zeta
  double cusum_up = 0.0;                       ///< upper CUSUM of standardised ln zeta
  double cusum_down = 0.0;                     ///< lower CUSUM (damping falling)
  bool transition() const { return level != previous; }
};

}  // namespace ridgewatch::trend
