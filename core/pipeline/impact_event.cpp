#include "core/pipeline/impact_event.hpp"

namespace ridgewatch::pipeline {

std::string_view to_string(ImpactStatus status) {
  switch (status) {
    case ImpactStatus::ok: return "ok";
    case ImpactStatus::low_snr: return "low_snr";
    case ImpactStatus::ridge_lost: return "ridge_lost";
    case ImpactStatus::window_cut: return "window_cut";
    case ImpactStatus::clipped: return "clipped";
    case ImpactStatus::spike: return "spike";
    case ImpactStatus::too_short: return "too_short";
    case ImpactStatus::not_decaying: return "not_decaying";
    case ImpactStatus::fit_failed: return "fit_failed";
    case ImpactStatus::inconsistent: return "inconsistent";
  }
  return "?";
}

}  // namespace ridgewatch::pipeline
