// Stage 5 of the impact detector (impact_detector.hpp): the onset model (the trigger band's envelope
// response to a step-started decay, calibrated at construction), the timing it implies (look-back,
// hold and report delay), and the onset of each confirmed trigger: the last 50 % crossing of the
// envelope maximum before it, minus the model's 50 % rise time.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

void ImpactDetector::set_onset_timing(double fc) {
  calibrate(fc);
  // Start-up rise reference (stage 4): a window of 2 ms ending one model peak time before the newest
  // band sample (an impact's rise from onset to peak lies after it), its mean scaled by the model's
  // energy decay over the distance between the window's centre and now.
  lag_d_ = static_cast<std::size_t>(std::llround(peak_samples_ / static_cast<double>(dec_)));
  lagw_d_ = std::max<std::size_t>(sta_d_, static_cast<std::size_t>(std::ceil(0.002 * fs_d_)));
  const double sigma0 = kModelZeta * 2.0 * std::numbers::pi * fc;
  lag_decay_ = std::exp(-2.0 * sigma0 * (static_cast<double>(lag_d_) + 0.5 * static_cast<double>(lagw_d_ - 1)) / fs_d_);
  startup_end_d_ = warmup_d_ + lta_d_;
  // A running maximum that has not grown for 1 ms is past the envelope's smooth peak.
  hold_d_ = std::max<std::size_t>(2, static_cast<std::size_t>(std::ceil(0.001 * fs_d_)));
  // Onset search floor: an impact triggers at the latest at its envelope peak plus one STA window (after
  // that the STA falls while the references do not), and the 50 % crossing lies (peak - t50) before the
  // peak; + one band sample for the block rounding. The onset (crossing - t50) then lies at most
  // lookback_ before the trigger.
  search_back_d_ = static_cast<std::size_t>(std::ceil((peak_samples_ - t50_samples_) / static_cast<double>(dec_))) +
                   sta_d_ + 1;
  lookback_ = search_back_d_ * dec_ + static_cast<std::size_t>(std::ceil(t50_samples_)) + 1;
  // Decision at the latest this long after the trigger (never reached by impacts like the model: the
  // rules below decide first).
  cap_d_ = search_back_d_ + static_cast<std::size_t>(std::ceil(peak_samples_ / static_cast<double>(dec_))) + hold_d_;
  // Bound on (report - onset) in input samples. The decision comes at the first band sample at or past
  // onset + peak + 1 ms (the provisional onset is the final one), or, for a weak impact triggered
  // near its peak, when the confirmation after a trigger at most lookback_ after the onset is
  // complete; + one run (band-sample grid) and the spike delay before a run is processed.
  const double by_peak = peak_samples_ + 0.001 * fs_;
  const double by_confirm = static_cast<double>(lookback_ + confirm_d_ * dec_);
  report_delay_ = static_cast<std::size_t>(std::ceil(std::max(by_peak, by_confirm))) + run_ + kSpikeDelay + 1;
}

void ImpactDetector::calibrate(double fc) {
  // The trigger chain's envelope for x = exp(-sigma0 t) cos(2 pi fc t), t >= 0, sigma0 for
  // zeta = 0.024 (the paper rig), started at each position p of the block grid: the 50 % crossing of
  // its maximum and the time of the maximum, in input samples after the start.
  const double sigma0 = kModelZeta * 2.0 * std::numbers::pi * fc;
  const auto n_len = static_cast<std::size_t>(std::ceil(0.1 * fs_)) + 2 * dec_;  // 100 ms is past any peak
  // The decay started at sample 0; started at p it is the same samples p later (t = (n - p) / fs is
  // exact in double for these integers), so the exponentials are evaluated once, not once per p.
  std::vector<double> decay(n_len);
  for (std::size_t n = 0; n < n_len; ++n) {
    const double t = static_cast<double>(n) / fs_;
    decay[n] = std::exp(-sigma0 * t) * std::cos(2.0 * std::numbers::pi * fc * t);
  }
  std::vector<double> x(n_len, 0.0);
  std::vector<std::complex<double>> y;
  double t50_sum = 0.0, t50_min = 1e300, t50_max = -1e300, peak_max = 0.0;
  for (std::size_t p = 0; p < dec_; ++p) {
    std::fill(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(p), 0.0);
    std::copy(decay.begin(), decay.end() - static_cast<std::ptrdiff_t>(p), x.begin() + static_cast<std::ptrdiff_t>(p));
    run_chain(x, y);
    std::size_t m_peak = 0;
    for (std::size_t m = 0; m < y.size(); ++m)
      if (std::abs(y[m]) > std::abs(y[m_peak])) m_peak = m;
    const double half = 0.5 * std::abs(y[m_peak]);
    double u = 0.0;
    for (std::size_t m = m_peak; m > 0; --m) {
      const double lo = std::abs(y[m - 1]);
      if (lo < half) {
        u = static_cast<double>(m - 1) + (half - lo) / (std::abs(y[m]) - lo);
        break;
      }
    }
    const double d = static_cast<double>(dec_);
    const double t50 = (u + 1.0) * d - 1.0 - static_cast<double>(p);
    const double tpk = static_cast<double>(m_peak + 1) * d - 1.0 - static_cast<double>(p);
    t50_sum += t50;
    t50_min = std::min(t50_min, t50);
    t50_max = std::max(t50_max, t50);
    peak_max = std::max(peak_max, tpk);
  }
  t50_samples_ = t50_sum / static_cast<double>(dec_);
  t50_spread_ = t50_max - t50_min;
  peak_samples_ = peak_max;
}

std::uint64_t ImpactDetector::dec_end_index(double m) const {
  return seg_start_ + static_cast<std::uint64_t>(std::llround((m + 1.0) * static_cast<double>(dec_) - 1.0));
}

std::uint64_t ImpactDetector::search_floor(std::uint64_t trigger) const {
  const std::uint64_t oldest = band_.m > e_hist_.size() ? band_.m - e_hist_.size() + 1 : 0;
  return std::max(oldest, trigger > search_back_d_ ? trigger - search_back_d_ : 0);
}

std::uint64_t ImpactDetector::onset_estimate(std::uint64_t trigger, std::uint64_t k_peak, double* onset_d) const {
  // The last crossing of half the envelope maximum before it (not further back than the search
  // window), in fractional band samples, minus the model's 50 % rise time.
  const double half = 0.5 * std::sqrt(th_[k_peak & e_mask_]);
  const std::uint64_t floor_k = search_floor(trigger);
  double crossing = static_cast<double>(floor_k);
  for (std::uint64_t k = k_peak; k > floor_k; --k) {
    const double lo = std::sqrt(th_[(k - 1) & e_mask_]);
    if (lo < half) {
      const double hi = std::sqrt(th_[k & e_mask_]);
      crossing = static_cast<double>(k - 1) + (hi > lo ? (half - lo) / (hi - lo) : 0.0);
      break;
    }
  }
  const double at = static_cast<double>(seg_start_) + (crossing + 1.0) * static_cast<double>(dec_) - 1.0 - t50_samples_;
  *onset_d = std::max(at, static_cast<double>(seg_start_));
  return static_cast<std::uint64_t>(std::llround(*onset_d));
}

void ImpactDetector::refine_and_emit(std::uint64_t trigger, std::uint64_t end) {
  std::uint64_t k_peak = trigger;
  for (std::uint64_t k = trigger; k < end; ++k)
    if (th_[k & e_mask_] > th_[k_peak & e_mask_]) k_peak = k;
  double onset_d = 0.0;
  const std::uint64_t onset = onset_estimate(trigger, k_peak, &onset_d);
  holdoff_end_ = std::max<std::uint64_t>(trigger + holdoff_d_, end);
  startup_ = false;
  lta_frozen_until_ = std::max(lta_frozen_until_, holdoff_end_);
  // An onset that falls at or before the segment's first sample (onset_estimate clamps it there) is
  // no onset: the rise began with the segment -- the filters' switch-on on the lines and hum the
  // stream starts in, or a decay already under way. Not emitted; the hold-off above still applies.
  if (onset_d <= static_cast<double>(seg_start_)) return;
  // Nor is one whose envelope maximum is not final at `end`: decide_band_sample() emits only once the
  // maximum has not grown for hold_d_, or cap_d_ after the trigger, or when the onset it implies lies
  // the model's peak time + 1 ms back (so this always holds there), but finish() resolves a trigger
  // when the stream ends, and a maximum still growing then is truncated: the last crossing of half of
  // it lies early, and so would the onset (300 Hz, B = 45 Hz, model peak time 17.6 ms: an impact 10 ms
  // before the end was put 2.7 ms early). Not emitted; its decay is cut by the end of the stream too.
  const std::uint64_t last = end - 1;
  if (last - k_peak < hold_d_ && last - trigger < cap_d_ &&
      static_cast<double>(dec_end_index(static_cast<double>(last))) < onset_d + peak_samples_ + 0.001 * fs_)
    return;
  if (onset_count_ < kMaxOnsets) {
    onsets_[(onset_head_ + onset_count_) % kMaxOnsets] = onset;
    ++onset_count_;
  }
}

}  // namespace ridgewatch::pipeline
