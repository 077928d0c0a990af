// Stage 3's LTA update and stage 4's trigger test of the impact detector (impact_detector.hpp), each
// written once: band_blocks() (detector_band.cpp) and decide_band_sample() (detector_trigger.cpp) use
// these. Inline: they run once per band sample.
#pragma once

#include <algorithm>

#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

/// The LTA after a band sample of energy e, its count-th: the cumulative mean over the first STA
/// window, the capped cumulative mean of min(e, 3 LTA) up to lta_d_ band samples, then the capped
/// exponential mean LTA + alpha (min(e, 3 LTA) - LTA), written as (1 - alpha) LTA + min(alpha e,
/// 3 alpha LTA) so that the dependency chain through the LTA is short (alpha e off the chain).
/// Not bias-corrected (lta() divides by kCapBias).
inline double ImpactDetector::lta_next(double lta, double e, std::uint64_t count) const {
  if (count > lta_d_) return lta_keep_ * lta + std::min(lta_alpha_ * e, lta_cap_alpha_ * lta);
  if (count <= sta_d_) return lta + (e - lta) / static_cast<double>(count);
  return lta + (std::min(e, kCap * lta) - lta) / static_cast<double>(count);
}

/// The mean of e over a full pre-window from its running sum (a running sum can be slightly negative
/// by rounding after the energy fell to ~0: clamped).
inline double ImpactDetector::full_pre_mean(double pre_sum) const { return std::max(pre_sum, 0.0) * inv_pre_d_; }

/// Stage 4's reference level: max(LTA (bias-corrected), rise reference), floored at 1e-30 (digital
/// silence never triggers).
inline double ImpactDetector::trigger_reference(double lta, double rise_ref) const {
  return std::max({lta * (1.0 / kCapBias), rise_ref, 1e-30});
}

/// Stage 4's trigger test: STA > trigger_ratio * reference. sta_sum: the STA window's running sum
/// (clamped at 0 like the pre-window's).
inline bool ImpactDetector::fires(double sta_sum, double lta, double rise_ref) const {
  return std::max(sta_sum, 0.0) * inv_sta_d_ > ratio_ * trigger_reference(lta, rise_ref);
}

/// Stage 4's confirmation test: the mean energy after the trigger against the same ratio and the
/// trigger's reference.
inline bool ImpactDetector::confirms(double mean_e) const { return mean_e > ratio_ * trigger_ref_; }

}  // namespace ridgewatch::pipeline
