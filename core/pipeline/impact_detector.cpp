#include "core/pipeline/impact_detector.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>

#include "core/pipeline/stream_processor.hpp"

namespace ridgewatch::pipeline {

namespace {

// RBJ audio-EQ cookbook biquads (bilinear transform with frequency pre-warping).
Biquad make_biquad(double f_hz, double q, double fs, bool high) {
  const double w0 = 2.0 * std::numbers::pi * f_hz / fs;
  const double c = std::cos(w0), alpha = std::sin(w0) / (2.0 * q);
  const double a0 = 1.0 + alpha;
  Biquad b;
  if (high) {
    b.b0 = (1.0 + c) / 2.0 / a0;
    b.b1 = -(1.0 + c) / a0;
    b.b2 = b.b0;
  } else {
    b.b0 = (1.0 - c) / 2.0 / a0;
    b.b1 = (1.0 - c) / a0;
    b.b2 = b.b0;
  }
  b.a1 = -2.0 * c / a0;
  b.a2 = (1.0 - alpha) / a0;
  return b;
}

std::uint64_t pow2_at_least(std::size_t n) { return std::bit_ceil(std::max<std::size_t>(n, 16)); }

}  // namespace

void Biquad::settle(double x) {
  const double gain = (b0 + b1 + b2) / (1.0 + a1 + a2);  // H(z = 1)
  const double y = gain * x;
  s2 = b2 * x - a2 * y;
  s1 = b1 * x - a1 * y + s2;
}

Biquad Biquad::highpass(double f_hz, double q, double fs) { return make_biquad(f_hz, q, fs, true); }
Biquad Biquad::lowpass(double f_hz, double q, double fs) { return make_biquad(f_hz, q, fs, false); }

double LowPass4::energy_gain() const {
  LowPass4 f = *this;
  f.reset();
  double sum = 0.0, y = f.step(1.0);
  sum += y * y;
  // Stops when the states are negligible (the slowest pole pair decays like
  // exp(-2 pi B sin(22.5 deg) t), e.g. 1e-12 after ~0.1 s at B = 125 Hz); capped at 10^6 samples.
  for (int n = 1; n < 1000000; ++n) {
    y = f.step(0.0);
    sum += y * y;
    if (n > 64 && std::abs(f.s1.s1) + std::abs(f.s1.s2) + std::abs(f.s2.s1) + std::abs(f.s2.s2) < 1e-12 * std::sqrt(sum))
      break;
  }
  return sum;
}

ImpactDetector::ImpactDetector(const ImpactDetectorConfig& cfg, double fs, std::size_t history_samples) {
  fs_ = fs;
  ratio_ = cfg.trigger_ratio;
  spike_k_ = cfg.spike_mad;
  sta_n_ = std::max<std::size_t>(1, static_cast<std::size_t>(std::llround(cfg.sta_s * fs)));
  lta_n_ = std::max<std::size_t>(sta_n_ + 1, static_cast<std::size_t>(std::llround(cfg.lta_s * fs)));
  lta_alpha_ = 1.0 / static_cast<double>(lta_n_);
  holdoff_ = static_cast<std::size_t>(std::llround(cfg.holdoff_s * fs));
  confirm_ = 4 * sta_n_;
  const double fc = 0.5 * (cfg.band_lo_hz + cfg.band_hi_hz);
  const double bw = 0.5 * (cfg.band_hi_hz - cfg.band_lo_hz);
  proto_.s1 = Biquad::lowpass(bw, 0.54119610014619698, fs);  // 1 / (2 cos(pi/8))
  proto_.s2 = Biquad::lowpass(bw, 1.3065629648763766, fs);   // 1 / (2 cos(3 pi/8))
  rot_ = std::polar(1.0, -2.0 * std::numbers::pi * fc / fs);
  band_noise_gain_ = proto_.energy_gain();
  calibrate(fc);
  // Pre-window: one correlation time of the band's envelope (1/B, 8 ms at 125 Hz) and at least 4 STA
  // windows, so that neither noise nor the beat of a decaying tail with a residual line (240 Hz for
  // 860/1100 Hz) makes a rise on its own.
  pre_n_ = std::max<std::size_t>(4 * sta_n_, static_cast<std::size_t>(std::ceil(fs / bw)));
  inv_sta_n_ = 1.0 / static_cast<double>(sta_n_);
  inv_pre_n_ = 1.0 / static_cast<double>(pre_n_);
  {
    // Fill-up of the low-pass for stationary input: g(k) = sum_{j<=k} h_j^2 / sum h^2, until 0.999.
    LowPass4 f = proto_;
    f.reset();
    double acc = 0.0;
    for (std::size_t k = 0; k < 1000000; ++k) {
      const double h = f.step(k == 0 ? 1.0 : 0.0);
      acc += h * h;
      const double g = acc / band_noise_gain_;
      if (g >= 0.999) break;
      fill_.push_back(std::max(g, 1e-3));
    }
    // No trigger before the STA window is full and the low-pass has reached a quarter of its
    // stationary output power (before that, 1/g amplifies the start too much).
    warmup_ = sta_n_;
    while (warmup_ < fill_.size() && fill_[warmup_] < 0.25) ++warmup_;
  }
  // Look-back of the onset search: the trigger comes at most about two group delays of the
  // low-pass (2.6 / (2 pi B) for a 4th-order Butterworth at DC) plus two STA windows after the onset.
  lookback_ = 2 * sta_n_ + static_cast<std::size_t>(std::ceil(2.0 * 2.6 / (2.0 * std::numbers::pi * bw) * fs));
  const std::uint64_t ysize = pow2_at_least(history_samples + lookback_ + settle_ + confirm_ + pre_n_ + sta_n_ + 64);
  e_hist_.assign(ysize, 0.0);
  y_mask_ = ysize - 1;
  restart(0);
}

void ImpactDetector::restart(std::uint64_t first_index) {
  seg_start_ = next_raw_ = next_decide_ = first_index;
  raw_.fill(0.0);
  res_.fill(0.0);
  mad_sum_ = 0.0;
  mad_count_ = 0;
  lp_i_ = proto_;
  lp_q_ = proto_;
  phasor_ = {1.0, 0.0};
  sta_sum_ = pre_sum_ = 0.0;
  band_count_ = 0;
  resum_left_ = pre_n_;
  lta_ = 0.0;
  holdoff_end_ = lta_frozen_until_ = first_index;
  confirming_ = false;
  confirmed_ = false;
  confirm_sum_ = 0.0;
  confirm_seen_ = 0;
}

void ImpactDetector::calibrate(double fc) {
  // The trigger chain's envelope for x = exp(-sigma0 t) cos(2 pi fc t), t >= 0, sigma0 for
  // zeta = 0.024 (the paper rig): its maximum, the time of the maximum, and the 50 % crossing.
  const double sigma0 = 0.024 * 2.0 * std::numbers::pi * fc;
  LowPass4 li = proto_, lq = proto_;
  std::complex<double> ph{1.0, 0.0};
  const auto n_max = static_cast<std::size_t>(std::ceil(0.1 * fs_));  // 100 ms is past any peak
  double peak = 0.0, prev = 0.0, t50 = 0.0;
  std::size_t peak_at = 0;
  std::vector<double> env(n_max);
  for (std::size_t n = 0; n < n_max; ++n) {
    const double t = static_cast<double>(n) / fs_;
    const double x = std::exp(-sigma0 * t) * std::cos(2.0 * std::numbers::pi * fc * t);
    const double i = li.step(x * ph.real()), q = lq.step(x * ph.imag());
    ph *= rot_;
    env[n] = std::hypot(i, q);
    if (env[n] > peak) {
      peak = env[n];
      peak_at = n;
    }
  }
  for (std::size_t n = peak_at; n > 0; --n) {
    if (env[n - 1] < 0.5 * peak) {
      prev = env[n - 1];
      t50 = static_cast<double>(n - 1) + (0.5 * peak - prev) / (env[n] - prev);
      break;
    }
  }
  t50_samples_ = t50;
  settle_ = peak_at + 1;
}

std::uint64_t ImpactDetector::pop_onset() {
  const std::uint64_t o = onsets_[onset_head_];
  onset_head_ = (onset_head_ + 1) % kMaxOnsets;
  --onset_count_;
  return o;
}

void ImpactDetector::push_raw(double x) {
  const std::uint64_t i = next_raw_++;
  raw_[i & 7] = x;
  // Residual of sample m = i - 2 (needs m-2 .. m+2 inside the segment).
  if (i >= seg_start_ + 4) {
    const std::uint64_t m = i - 2;
    // Multiplication by 1/6 instead of a division (divisions were ~4 of the ~14 ns per sample).
    constexpr double kSixth = 1.0 / 6.0;
    const double pred = (-raw_[(m - 2) & 7] + 4.0 * raw_[(m - 1) & 7] + 4.0 * raw_[(m + 1) & 7] - raw_[(m + 2) & 7]) * kSixth;
    res_[m & 7] = raw_[m & 7] - pred;
  } else if (i >= seg_start_ + 2) {
    res_[(i - 2) & 7] = 0.0;  // first two samples of a segment: no left neighbours, never spikes
  }
  if (i >= seg_start_ + kSpikeDelay) decide(i - kSpikeDelay, true);
}

void ImpactDetector::finish() {
  // Samples whose right neighbours never came: no spike decision (they cannot be shown isolated).
  while (next_decide_ < next_raw_) decide(next_decide_, false);
  if (confirming_) {
    // The stream ended during confirmation or settling: judge with the energy seen so far.
    const std::size_t seen = std::min(confirm_seen_, confirm_);
    if (seen > 0 && confirm_sum_ / static_cast<double>(seen) > ratio_ * trigger_ref_)
      refine_and_emit(trigger_, next_decide_);
    confirming_ = false;
  }
}

void ImpactDetector::decide(std::uint64_t n, bool have_right) {
  next_decide_ = n + 1;
  double clean = raw_[n & 7];
  const bool have_left = n >= seg_start_ + 2;
  // Robust scale: MAD from the winsorised mean |r| (Gaussian: E|r| = 0.7979 sd, MAD = 0.6745 sd).
  // The absolute floor keeps float32 rounding of an otherwise noise-free signal from looking noisy
  // or, with digital silence, everything from looking like a spike.
  constexpr std::uint64_t kWarmup = 32;
  const double mean_abs = mad_count_ > 0 ? mad_sum_ : 0.0;
  const double mad = std::max(0.6745 / 0.7979 * mean_abs, 1e-9);
  // A spike must also stand out against the signal itself: at least a quarter of the neighbours'
  // magnitude. The interpolation residual of a sharp but genuine feature (the kink of a 0.15 ms force
  // pulse sampled at 25.6 kHz leaves ~5 % of the amplitude) would otherwise pass 12 MAD at low noise;
  // sensor spikes are large (the simulator's 0.75-2 x the impact peak).
  const double neighbours = std::max({std::abs(raw_[(n - 1) & 7]), std::abs(raw_[(n + 1) & 7]),
                                      std::abs(raw_[(n - 2) & 7]), std::abs(raw_[(n + 2) & 7])});
  const double limit = std::max(spike_k_ * mad, 0.25 * neighbours);
  const double r = have_left && have_right ? res_[n & 7] : 0.0;
  if (mad_count_ >= kWarmup && have_left && have_right && std::abs(r) > limit) {
    const double r_m1 = res_[(n - 1) & 7] + 2.0 / 3.0 * r, r_p1 = res_[(n + 1) & 7] + 2.0 / 3.0 * r;
    const double r_m2 = res_[(n - 2) & 7] - r / 6.0, r_p2 = res_[(n + 2) & 7] - r / 6.0;
    if (std::abs(r_m1) <= limit && std::abs(r_p1) <= limit && std::abs(r_m2) <= limit && std::abs(r_p2) <= limit) {
      clean = raw_[n & 7] - r;  // the interpolation
      raw_[n & 7] = clean;
      res_[n & 7] = 0.0;
      res_[(n - 1) & 7] = r_m1;
      res_[(n + 1) & 7] = r_p1;
      res_[(n - 2) & 7] = r_m2;
      res_[(n + 2) & 7] = r_p2;
      ++spikes_;
      spike_idx_[spike_head_] = n;
      spike_head_ = (spike_head_ + 1) % kSpikeRing;
      spike_count_ = std::min(spike_count_ + 1, kSpikeRing);
    }
  }
  if (have_left && have_right) {
    const double a = std::abs(res_[n & 7]);
    if (mad_count_ < kWarmup) {
      ++mad_count_;
      mad_sum_ += (a - mad_sum_) / static_cast<double>(mad_count_);
    } else {
      mad_sum_ += lta_alpha_ * (std::min(a, 3.0 * mad_sum_ + 1e-30) - mad_sum_);
    }
  }
  band_sample(n, clean);
}

void ImpactDetector::band_sample(std::uint64_t n, double clean) {
  // Complex demodulation: the phasor advances by rot_ per sample; renormalised every 256 samples
  // (Newton step on |p|^2 = 1) so rounding cannot make it drift.
  const double i_part = lp_i_.step(clean * phasor_.real());
  const double q_part = lp_q_.step(clean * phasor_.imag());
  phasor_ *= rot_;
  if ((n & 255) == 0) phasor_ *= 0.5 * (3.0 - std::norm(phasor_));
  double e = i_part * i_part + q_part * q_part;
  // While the low-pass fills up after a (re)start, stationary input gives E[e] = E_inf g(k):
  // divide by g so the start of a record is not a rising edge.
  if (band_count_ < fill_.size()) e /= fill_[static_cast<std::size_t>(band_count_)];
  e_hist_[n & y_mask_] = e;
  ++band_count_;
  // Running sums of the STA window [n - sta + 1, n] and the pre-window before it; re-summed once
  // per pre-window so rounding cannot accumulate.
  sta_sum_ += e;
  if (band_count_ > sta_n_) {
    const double moved = e_hist_[(n - sta_n_) & y_mask_];
    sta_sum_ -= moved;
    pre_sum_ += moved;
    if (band_count_ > sta_n_ + pre_n_) pre_sum_ -= e_hist_[(n - sta_n_ - pre_n_) & y_mask_];
  }
  // Countdown instead of band_count_ % pre_n_ == 0: a 64-bit division per sample cost more than
  // the rest of this function's arithmetic.
  if (--resum_left_ == 0) {
    resum_left_ = pre_n_;
    sta_sum_ = pre_sum_ = 0.0;
    const std::uint64_t have = band_count_;
    for (std::uint64_t k = 0; k < std::min<std::uint64_t>(sta_n_, have); ++k) sta_sum_ += e_hist_[(n - k) & y_mask_];
    for (std::uint64_t k = sta_n_; k < std::min<std::uint64_t>(sta_n_ + pre_n_, have); ++k) pre_sum_ += e_hist_[(n - k) & y_mask_];
  }
  // LTA: cumulative mean at first, then the capped exponential mean; frozen around triggers.
  if (n >= lta_frozen_until_) {
    if (band_count_ <= sta_n_) {
      lta_ += (e - lta_) / static_cast<double>(band_count_);
    } else if (band_count_ <= lta_n_) {
      lta_ += (std::min(e, kCap * lta_) - lta_) / static_cast<double>(band_count_);
    } else {
      lta_ += lta_alpha_ * (std::min(e, kCap * lta_) - lta_);
    }
  }
  if (band_count_ < warmup_) return;  // STA not yet full, or the low-pass has not filled enough
  const double sta = std::max(sta_sum_, 0.0) * inv_sta_n_;

  if (confirming_) {
    ++confirm_seen_;
    if (confirm_seen_ <= confirm_) confirm_sum_ += e;
    if (confirm_seen_ == confirm_) {
      confirmed_ = confirm_sum_ / static_cast<double>(confirm_) > ratio_ * trigger_ref_;
    }
    if (confirm_seen_ >= std::max(confirm_, settle_)) {
      confirming_ = false;
      if (confirmed_) {
        refine_and_emit(trigger_, n + 1);
      } else {
        // Rejected: re-arm at once, as if nothing had happened.
        holdoff_end_ = n + 1;
        lta_frozen_until_ = n + 1;
      }
    }
    return;
  }
  if (n < holdoff_end_) return;
  const std::uint64_t pre_count = std::min<std::uint64_t>(pre_n_, band_count_ - sta_n_);
  const double inv_pre = pre_count == pre_n_ ? inv_pre_n_ : 1.0 / static_cast<double>(pre_count);
  const double pre = pre_count > 0 ? std::max(pre_sum_, 0.0) * inv_pre : 0.0;
  const double ref = std::max({lta_ * (1.0 / kCapBias), pre, 1e-30});
  if (sta > ratio_ * ref) {
    confirming_ = true;
    trigger_ = n;
    trigger_ref_ = ref;
    confirm_sum_ = 0.0;
    confirm_seen_ = 0;
    confirmed_ = false;
    lta_frozen_until_ = n + std::max<std::size_t>(holdoff_, confirm_) + 1;
  }
}

void ImpactDetector::refine_and_emit(std::uint64_t trigger, std::uint64_t end) {
  // Envelope maximum over [trigger, end), then the last crossing of half of it before the maximum
  // (not further back than the look-back), minus the model's 50 % rise time.
  const std::uint64_t oldest = std::max<std::uint64_t>(seg_start_, end > e_hist_.size() ? end - e_hist_.size() + 1 : 0);
  std::uint64_t k_peak = trigger;
  for (std::uint64_t k = trigger; k < end; ++k)
    if (e_hist_[k & y_mask_] > e_hist_[k_peak & y_mask_]) k_peak = k;
  const double half = 0.5 * std::sqrt(e_hist_[k_peak & y_mask_]);
  const std::uint64_t floor_k = std::max(oldest, trigger > lookback_ ? trigger - lookback_ : 0);
  double crossing = static_cast<double>(floor_k);
  for (std::uint64_t k = k_peak; k > floor_k; --k) {
    const double lo = std::sqrt(e_hist_[(k - 1) & y_mask_]);
    if (lo < half) {
      const double hi = std::sqrt(e_hist_[k & y_mask_]);
      crossing = static_cast<double>(k - 1) + (hi > lo ? (half - lo) / (hi - lo) : 0.0);
      break;
    }
  }
  const double onset_d = std::max(crossing - t50_samples_, static_cast<double>(oldest));
  const auto onset = static_cast<std::uint64_t>(std::llround(onset_d));
  holdoff_end_ = std::max<std::uint64_t>(trigger + holdoff_, end);
  lta_frozen_until_ = std::max(lta_frozen_until_, holdoff_end_);
  if (onset_count_ < kMaxOnsets) {
    onsets_[(onset_head_ + onset_count_) % kMaxOnsets] = onset;
    ++onset_count_;
  }
}

double ImpactDetector::band_power(std::uint64_t begin, std::uint64_t end) const {
  const std::uint64_t oldest = std::max<std::uint64_t>(seg_start_, next_decide_ > e_hist_.size() ? next_decide_ - e_hist_.size() : 0);
  begin = std::max(begin, oldest);
  end = std::min(end, next_decide_);
  if (end < begin + 8) return NAN;
  double sum = 0.0;
  for (std::uint64_t k = begin; k < end; ++k) sum += e_hist_[k & y_mask_];
  return sum / static_cast<double>(end - begin);
}

bool ImpactDetector::spike_in(std::uint64_t begin, std::uint64_t end) const {
  for (std::size_t k = 0; k < spike_count_; ++k) {
    const std::uint64_t s = spike_idx_[(spike_head_ + kSpikeRing - 1 - k) % kSpikeRing];
    if (s >= begin && s < end) return true;
    if (s < begin) break;  // newest first: the rest are older
  }
  return false;
}

}  // namespace ridgewatch::pipeline
