#include "cli/event_json.hpp"

#include <cmath>
#include <nlohmann/json.hpp>

namespace ridgewatch::cli {

namespace {

using Json = nlohmann::ordered_json;

Json num(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

}  // namespace

std::string event_json(const pipeline::ImpactEvent& e, std::string_view source, std::string_view wall_time) {
  Json j;
  j["t_s"] = num(e.t_s);
  j["sample_index"] = e.sample_index;
  j["source"] = std::string(source);
  if (!wall_time.empty()) j["wall_time"] = std::string(wall_time);
  j["f_hz"] = num(e.f_hz);
  j["f_sd_hz"] = num(e.f_sd_hz);
  j["zeta"] = num(e.zeta);
  j["zeta_ci95"] = Json::array({num(e.zeta_ci95_lo), num(e.zeta_ci95_hi)});
  j["snr_db"] = num(e.snr_db);
  j["amplitude"] = num(e.amplitude);
  j["window_s"] = num(e.window_s);
  j["status"] = std::string(pipeline::to_string(e.status));
  j["alarm"] = std::string(pipeline::to_string(e.alarm.level));
  j["alarm_detail"] = {{"ewma_ln_zeta", num(e.alarm.ewma_ln_zeta)},
                       {"cusum_up", num(e.alarm.cusum_up)},
                       {"cusum_down", num(e.alarm.cusum_down)},
                       {"baseline_zeta", num(std::exp(e.alarm.baseline_ln_zeta))},
                       {"transition", e.alarm.transition()}};
  // A source name that is not valid UTF-8 (a file name) is replaced, never aborts the log line.
  return j.dump(-1, ' ', false, Json::error_handler_t::replace);
}

}  // namespace ridgewatch::cli
