// One impact event as a JSON object (one line, no trailing newline): the event-log contract shared by
// `ridgewatch analyze` and ridgewatchd (README "Event log").
//
// Keys, in this order: t_s, sample_index, source, stream (only when given: one of several streams of
// one source, e.g. "ch3" from `analyze --all-channels`), wall_time (only when given), f_hz, f_sd_hz, zeta,
// zeta_ci95 [lo, hi], snr_db, amplitude, window_s, status, alarm (level string), alarm_detail
// {ewma_ln_zeta, cusum_up, cusum_down, baseline_zeta, transition}. Non-finite numbers are null.
#pragma once

#include <string>
#include <string_view>

#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::app {

/// wall_time_iso8601: wall-clock time of the impact (live capture), omitted when empty.
std::string event_json(const pipeline::ImpactEvent& e, std::string_view source,
                       std::string_view wall_time_iso8601 = {}, std::string_view stream = {});
/// The same object appended to `out` (the daemon collects a block of lines for one write).
void append_event_json(std::string& out, const pipeline::ImpactEvent& e, std::string_view source,
                       std::string_view wall_time_iso8601 = {}, std::string_view stream = {});

}  // namespace ridgewatch::app
