// Stage 4 of the impact detector (impact_detector.hpp): the trigger (STA against the LTA and the rise
// reference, with the start-up reference), its confirmation, and the hand-over of a confirmed trigger
// to the onset refiner (detector_onset.cpp). The test itself is fires() (detector_trigger.hpp).
#include "core/pipeline/detector_trigger.hpp"

#include <algorithm>

#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

void ImpactDetector::decide_band_sample(std::uint64_t m, double e, double mad) {
  // Trigger logic for band sample m (energy e), after band_blocks() has stored it and updated the sums
  // and the LTA (band_.m == m + 1); mad: the spike stage's scale as of m's block.

  if (confirming_) {
    ++confirm_seen_;
    if (confirm_seen_ <= confirm_d_) confirm_sum_ += e;
    if (e > th_[peak_at_ & e_mask_]) {
      peak_at_ = m;
      peak_since_ = m;
    }
    if (confirm_seen_ == confirm_d_) confirmed_ = confirms(confirm_sum_ / static_cast<double>(confirm_d_));
    if (confirm_seen_ >= confirm_d_) {
      if (!confirmed_) {
        // Rejected: re-arm at once, as if nothing had happened.
        confirming_ = false;
        holdoff_end_ = m + 1;
        lta_frozen_until_ = m + 1;
        return;
      }
      // The running maximum is final when it has not grown for a hold time, or when the onset it
      // implies lies the model's peak time + 1 ms back, or at the latest cap_d_ after the trigger.
      bool done = m - peak_since_ >= hold_d_ || m - trigger_ >= cap_d_;
      if (!done) {
        // The onset implied by the running maximum depends only on it and the search floor:
        // estimated again only when one of them has changed.
        const std::uint64_t floor_k = search_floor(trigger_);
        if (peak_at_ != est_peak_ || floor_k != est_floor_) {
          onset_estimate(trigger_, peak_at_, &est_onset_d_);
          est_peak_ = peak_at_;
          est_floor_ = floor_k;
        }
        done = static_cast<double>(dec_end_index(static_cast<double>(m))) >= est_onset_d_ + peak_samples_ + 0.001 * fs_;
      }
      if (done) {
        confirming_ = false;
        refine_and_emit(trigger_, m + 1);
      }
    }
    return;
  }
  if (m < holdoff_end_) return;
  double pre = full_pre_mean(band_.pre_sum);
  if (band_.m < sta_d_ + pre_d_) {  // pre-window not yet full: mean over what it holds
    const std::uint64_t pre_count = band_.m - std::min<std::uint64_t>(band_.m, sta_d_);
    pre = pre_count > 0 ? std::max(band_.pre_sum, 0.0) / static_cast<double>(pre_count) : 0.0;
  }
  double rise_ref = pre;
  if (startup_ && m >= warmup_d_ + lag_d_ + lagw_d_ - 1) {
    // Start-up (see the header, stage 4): the band can hold a decaying start transient (a rig that
    // rings from the start of the record, the filters' own switch-on transient). PRE lags its decay;
    // the lagged window, extrapolated with the model decay, is the level the transient can have now.
    double lag = 0.0;
    for (std::size_t k = 0; k < lagw_d_; ++k) lag += th_[(m - lag_d_ - k) & e_mask_];
    // Floored by the white-noise band power (the LTA may still be too low, see the LTA update).
    rise_ref = std::min(pre, std::max(lag / static_cast<double>(lagw_d_) * lag_decay_, white_band_power(mad)));
  }
  // Noise floor (trigger_noise_ratio): the fast paths test without it; a trigger they pass is decided
  // here, so it applies to every trigger and its confirmation.
  if (noise_floor_ > 0.0) rise_ref = std::max(rise_ref, noise_floor_ * white_band_power(mad));
  if (startup_ && m >= startup_end_d_) startup_ = false;
  if (fires(band_.sta_sum, band_.lta, rise_ref)) {
    confirming_ = true;
    trigger_ = m;
    peak_at_ = m;
    peak_since_ = m;
    est_peak_ = kNoPeak;
    trigger_ref_ = trigger_reference(band_.lta, rise_ref);
    confirm_sum_ = 0.0;
    confirm_seen_ = 0;
    confirmed_ = false;
    lta_frozen_until_ = m + std::max({holdoff_d_, confirm_d_, freeze_extra_d_}) + 1;
  }
}

double ImpactDetector::white_band_power(double mad) const {
  // The band power of white noise with the variance the spike stage measures: the interpolation
  // residual has variance (1 + 34/36) sigma^2 for white noise (stage 1), mad (mad_sum_) is its mean
  // absolute value (0.7979 sd), and a start transient or a line in or near the band leaves almost no
  // residual (theta^4 / 6 of its amplitude).
  const double sd_r = mad / 0.7979;
  return sd_r * sd_r / (1.0 + 34.0 / 36.0) * band_noise_gain_;
}

}  // namespace ridgewatch::pipeline
