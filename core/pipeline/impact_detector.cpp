// ImpactDetector: construction (sizes of blocks, runs and windows), push/finish and the run loop,
// band_power and spike_in. The stages are in detector_spike.cpp, detector_band.cpp,
// detector_trigger.hpp/.cpp and detector_onset.cpp (see impact_detector.hpp).
#include "core/pipeline/impact_detector.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>

#include "core/dsp/kernels/simd.hpp"
#include "core/pipeline/detector_trigger.hpp"

namespace ridgewatch::pipeline {

ImpactDetector::ImpactDetector(const ImpactDetectorConfig& cfg, double fs, std::size_t history_samples) {
  fs_ = fs;
  ratio_ = cfg.trigger_ratio;
  noise_floor_ = cfg.trigger_noise_ratio > 0.0 ? cfg.trigger_noise_ratio / cfg.trigger_ratio : 0.0;
  spike_k_ = cfg.spike_mad;
  const double fc = 0.5 * (cfg.band_lo_hz + cfg.band_hi_hz);
  const double bw = 0.5 * (cfg.band_hi_hz - cfg.band_lo_hz);

  // Decimation: the decimated rate stays >= 40 B (20-fold oversampling of the envelope's 2B band).
  dec_ = std::clamp<std::size_t>(static_cast<std::size_t>(std::floor(fs / (40.0 * bw))), 1, 64);
  fs_d_ = fs / static_cast<double>(dec_);
  // The spike stage works on blocks of whole decimation steps of about 0.4 ms (20 samples at 51.2 kHz),
  // one band sample per D samples inside; its scale is updated once per block. Blocks are processed
  // in runs of about 1.6 ms (4 blocks, 80 samples at 51.2 kHz: the per-call overhead is shared and the
  // loops are longer; longer runs add to the decision delay).
  blk_ = dec_ * std::max<std::size_t>(1, static_cast<std::size_t>(std::floor(kBlockS * fs / static_cast<double>(dec_))));
  inv_blk_ = 1.0 / static_cast<double>(blk_);
  subs_ = std::clamp<std::size_t>(static_cast<std::size_t>(std::floor(kRunS * fs / static_cast<double>(blk_))), 1,
                                  kMaxRunBlocks);
  run_ = subs_ * blk_;
  design_band(fc, bw);     // stage 2's FIR, phasors and low-pass (detector_band.cpp)
  set_windows(cfg, bw);    // stage 3-4 windows in band samples, time constants
  std::vector<std::complex<double>> responses;  // the chain's impulse responses (measure_fill_up())
  measure_fill_up(bw, responses);  // noise gain and fill-up of the chain (detector_band.cpp)
  set_onset_timing(fc);    // stage 5's model and the report delay (detector_onset.cpp)
  fc_hz_ = fc;
  innov_ = cfg.trigger_innovation;
  // Innovation lag k: the model's peak time + 1 ms (stage 3, innovation mode; in both modes the lag of
  // ringing_free_noise_power()).
  innov_lag_d_ = std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil((peak_samples_ + 0.001 * fs_) / static_cast<double>(dec_))));
  if (innov_) freeze_extra_d_ = 2 * innov_lag_d_;
  measure_lag_correlation(responses);
  allocate(history_samples);
  restart(0);
}

void ImpactDetector::set_windows(const ImpactDetectorConfig& cfg, double bw) {
  sta_d_ = std::max<std::size_t>(1, static_cast<std::size_t>(std::llround(cfg.sta_s * fs_d_)));
  lta_d_ = std::max<std::size_t>(sta_d_ + 1, static_cast<std::size_t>(std::llround(cfg.lta_s * fs_d_)));
  lta_alpha_ = 1.0 / static_cast<double>(lta_d_);
  lta_keep_ = 1.0 - lta_alpha_;
  lta_cap_alpha_ = kCap * lta_alpha_;
  holdoff_d_ = static_cast<std::size_t>(std::llround(cfg.holdoff_s * fs_d_));
  // Confirmation over 4 STA windows (2 ms at the defaults), rounded on the band-sample grid.
  confirm_d_ = std::max<std::size_t>(sta_d_, static_cast<std::size_t>(std::llround(4.0 * cfg.sta_s * fs_d_)));
  // Pre-window: one correlation time of the band's envelope (1/B, 8 ms at 125 Hz) and at least 4 STA
  // windows, so that neither noise nor the beat of a decaying tail with a residual line (240 Hz for
  // 860/1100 Hz) makes a rise on its own.
  pre_d_ = std::max<std::size_t>(4 * sta_d_, static_cast<std::size_t>(std::ceil(fs_d_ / bw)));
  inv_sta_d_ = 1.0 / static_cast<double>(sta_d_);
  inv_pre_d_ = 1.0 / static_cast<double>(pre_d_);
  // The spike scale's running mean keeps the per-sample time constant lta_s, applied once per block.
  const double lta_in = std::max(2.0, std::round(cfg.lta_s * fs_));
  mad_beta_ = 1.0 - std::pow(1.0 - 1.0 / lta_in, static_cast<double>(blk_));
}

void ImpactDetector::allocate(std::size_t history_samples) {
  const std::size_t hist_d = (history_samples + lookback_ + report_delay_) / dec_ + pre_d_ + sta_d_ + 64;
  const std::uint64_t esize = std::bit_ceil(std::max<std::size_t>(hist_d, 64));
  e_hist_.assign(esize, 0.0);
  e_mask_ = esize - 1;
  q_hist_.assign(innov_ ? esize : 0, 0.0);
  z_hist_.assign(esize, std::complex<double>{});
  th_ = innov_ ? q_hist_.data() : e_hist_.data();
  hist_ = taps_ + 8;
  // Room for 16 runs after the history, the run in progress with its spike delay, and slack: finish()
  // decides up to run_ + kSpikeDelay - 1 samples and clears the two residual slots past them,
  // decide_block() reads and writes a little past the run's last pushed sample; the buffer is shifted
  // before the run's end pointer leaves fewer than kReadAhead slots after it.
  buf_x_.assign(hist_ + 16 * run_ + run_ + kSpikeDelay + 8 + kSpikeDelay + kReadAhead + dec_ + 8, 0.0f);
  buf_r_.assign(buf_x_.size(), 0.0f);
  // Block of the run of each band sample of a band_blocks() call (finish() passes up to
  // run_ + kSpikeDelay - 1 samples).
  sub_of_.resize((run_ + kSpikeDelay) / dec_ + 1);
  for (std::size_t j = 0; j < sub_of_.size(); ++j)
    sub_of_[j] = static_cast<std::uint8_t>(std::min(j / (blk_ / dec_), kMaxRunBlocks - 1));
}

void ImpactDetector::restart(std::uint64_t first_index) {
  seg_start_ = next_block_ = first_index;
  base_ = first_index - hist_;  // unsigned: n - base_ is the buffer position even if first_index < hist_
  std::fill(buf_x_.begin(), buf_x_.end(), 0.0f);
  std::fill(buf_r_.begin(), buf_r_.end(), 0.0f);
  wp_ = buf_x_.data() + hist_;
  due_p_ = wp_ + run_ + kSpikeDelay;
  mad_sum_ = 0.0;
  mad_count_ = 0;
  run_clip_ready_ = false;
  band_ = BandState{};
  band_.resum_left = pre_d_;
  lta_raised_ = false;
  holdoff_end_ = lta_frozen_until_ = 0;
  confirming_ = false;
  confirmed_ = false;
  confirm_sum_ = 0.0;
  confirm_seen_ = 0;
  startup_ = true;
  innov_c_ = {0.0, 0.0};
  innov_w_ = 0.0;
}

std::uint64_t ImpactDetector::pop_onset() {
  const std::uint64_t o = onsets_[onset_head_];
  onset_head_ = (onset_head_ + 1) % kMaxOnsets;
  --onset_count_;
  return o;
}

void ImpactDetector::shift_buffer() {
  const std::uint64_t new_base = next_block_ - hist_;
  const auto from = static_cast<std::size_t>(new_base - base_);
  const auto count = static_cast<std::size_t>(next_index() - new_base);
  std::copy(buf_x_.begin() + static_cast<std::ptrdiff_t>(from), buf_x_.begin() + static_cast<std::ptrdiff_t>(from + count),
            buf_x_.begin());
  std::copy(buf_r_.begin() + static_cast<std::ptrdiff_t>(from), buf_r_.begin() + static_cast<std::ptrdiff_t>(from + count),
            buf_r_.begin());
  base_ = new_base;
  wp_ = buf_x_.data() + count;
  due_p_ = buf_x_.data() + (next_block_ + run_ + kSpikeDelay - base_);
}

void ImpactDetector::push(std::span<const float> xs) {
  const float* p = xs.data();
  std::size_t n = xs.size();
  while (n > 0) {
    const std::size_t k = std::min(n, until_block());
    // A run is short (at most a block and the spike delay): copied inline, four at a time (a
    // memcpy call costs more than the copy).
    std::size_t i = 0;
    for (; i + 4 <= k; i += 4) {
      dsp::simd::store(wp_ + i, dsp::simd::load(p + i));
    }
    for (; i < k; ++i) wp_[i] = p[i];
    wp_ += k;
    p += k;
    n -= k;
    if (wp_ == due_p_) process_block();
  }
}

void ImpactDetector::process_block() {
  // One run: the spike stage block by block (each block's scale update is seen by the next, as if
  // they ran one at a time), the scale after each block kept for the band samples in it, then the
  // trigger band over the whole run.
  const std::uint64_t b = next_block_;
  start_run_scale();
  decide_blocks(b, subs_);
  band_blocks(b, run_ / dec_);
  next_block_ += run_;
  due_p_ += run_;
  if (due_p_ + kReadAhead > buf_x_.data() + buf_x_.size()) shift_buffer();
}

void ImpactDetector::finish() {
  // The run in progress: its whole blocks whose spike delay has passed as in process_block(), then
  // the last whole decimation steps, whose right neighbours never came: no spike decisions in them.
  const auto avail = static_cast<std::size_t>(next_index() - next_block_);
  const std::uint64_t b = next_block_;
  const std::size_t k = avail >= kSpikeDelay ? (avail - kSpikeDelay) / blk_ : 0;
  start_run_scale();
  decide_blocks(b, k);
  const std::size_t rest = avail - k * blk_;
  const std::size_t len = rest / dec_ * dec_;
  if (len > 0) {
    const std::size_t n_res = rest >= len + 4 ? len : (rest > 4 ? rest - 4 : 0);  // r[i + 2] needs x[i + 4]
    decide_block(b + k * blk_, len, n_res, false);
    note_scale(k);
  }
  const std::size_t done = k * blk_ + len;
  if (done > 0) {
    band_blocks(b, done / dec_);
    next_block_ += done;
    due_p_ += done;
    if (due_p_ + kReadAhead > buf_x_.data() + buf_x_.size()) shift_buffer();  // in case pushing goes on
  }
  if (confirming_) {
    // The stream ended during confirmation or settling: judge with the energy seen so far.
    const std::size_t seen = std::min(confirm_seen_, confirm_d_);
    if (seen > 0 && confirms(confirm_sum_ / static_cast<double>(seen)))
      refine_and_emit(trigger_, band_.m);
    confirming_ = false;
  }
}

double ImpactDetector::band_power(std::uint64_t begin, std::uint64_t end) const {
  return history_power(e_hist_, begin, end);
}

double ImpactDetector::innovation_noise_power(std::uint64_t begin, std::uint64_t end) const {
  if (!innov_) return NAN;
  // The predictor as innovation() uses it now (frozen around a trigger: the one before the impact
  // that asks for its floor).
  std::complex<double> p = innov_w_ > 0.0 ? innov_c_ / innov_w_ : std::complex<double>{};
  const double mag = std::abs(p);
  if (mag > 1.0) p /= mag;
  // q = |n[m] - p n[m - k]|^2 for noise n of band power P: E q = P (1 + |p|^2 - 2 Re(conj(p) rho_k)).
  const double gain = 1.0 + std::norm(p) - 2.0 * (std::conj(p) * innov_rho_).real();
  return history_power(q_hist_, begin, end) / std::max(gain, 1e-3);
}

double ImpactDetector::ringing_free_noise_power(std::uint64_t begin, std::uint64_t end, double f_hz,
                                                double zeta) const {
  if (!(zeta > 0.0 && zeta < 1.0) || !(std::abs(f_hz - fc_hz_) < 0.5 * fs_d_)) return NAN;
  // The free decay x = A e^{-sigma t} cos(w t + phi) leaves the band as z[m] = c a^m, a =
  // e^{(-sigma + i (w - w_c)) D / fs} (the FIR passes e^{+i w n}, z is demodulated by e^{-i w_c D m};
  // the low-pass keeps an exponential an exponential), so z[m] = a^k z[m - k] and p = a^k.
  const double w = 2.0 * std::numbers::pi * f_hz;
  const double sigma = zeta * w / std::sqrt(1.0 - zeta * zeta);
  const double lag_s = static_cast<double>(innov_lag_d_ * dec_) / fs_;
  const std::complex<double> p = std::polar(std::exp(-sigma * lag_s), (w - 2.0 * std::numbers::pi * fc_hz_) * lag_s);
  const double gain = std::max(1.0 + std::norm(p) - 2.0 * (std::conj(p) * innov_rho_).real(), 1e-3);
  const std::uint64_t k = innov_lag_d_;
  auto q = [&](std::uint64_t m) {
    // Before the segment's first k band samples there is no z[m - k]: the band power stands in.
    if (m < k) return gain * e_hist_[m & e_mask_];
    return std::norm(z_hist_[m & e_mask_] - p * z_hist_[(m - k) & e_mask_]);
  };
  return history_average(q, begin, end) / gain;
}

void ImpactDetector::measure_lag_correlation(const std::vector<std::complex<double>>& responses) {
  // E[n[m] conj(n[m - k])] of the band output for white input: the impulse responses' lag products
  // summed over the D positions of a block (as measure_fill_up() sums their powers, from the same
  // responses: past their span they are below 1e-6 of the peak power).
  const std::size_t n_out = responses.size() / dec_;
  std::complex<double> lag{0.0, 0.0};
  double power = 0.0;
  for (std::size_t p = 0; p < dec_; ++p) {
    const std::complex<double>* y = responses.data() + p * n_out;
    for (std::size_t m = 0; m < n_out; ++m) {
      power += std::norm(y[m]);
      if (m >= innov_lag_d_) lag += y[m] * std::conj(y[m - innov_lag_d_]);
    }
  }
  innov_rho_ = power > 0.0 ? lag / power : std::complex<double>{};
}

double ImpactDetector::history_power(const std::vector<double>& hist, std::uint64_t begin, std::uint64_t end) const {
  return history_average([&](std::uint64_t m) { return hist[m & e_mask_]; }, begin, end);
}

template <class Value>
double ImpactDetector::history_average(const Value& value, std::uint64_t begin, std::uint64_t end) const {
  // Time average over [begin, end) of e, linearly interpolated between the band samples. Interpolating
  // matters: the in-band floor between impacts often holds the residuals of two lines (a beat in e at their difference frequency, e.g.
  // 440 Hz for 660/1100 Hz lines), which a plain mean of the few band samples in a 2 ms window
  // would sample rather than average. Only band samples after the chain's fill-up are used (before,
  // e is divided by the small fill-up factor g, and a start transient of the rig may still ring).
  begin = std::max(begin, seg_start_);
  if (end < begin + 8) return NAN;
  const std::uint64_t oldest = std::max<std::uint64_t>(band_.m > e_hist_.size() ? band_.m - e_hist_.size() : 0,
                                                       fill_.size());
  if (band_.m < oldest + 2) return NAN;
  // Band sample m is stamped at its block's end minus the FIR's group delay (D - 1), i.e. at
  // seg_start + m D: the time its e describes, like the per-sample e of a filter without the
  // decimation stage.
  const double d = static_cast<double>(dec_);
  const double t0 = static_cast<double>(seg_start_);
  // Interval in band-sample units, clamped to the stored samples [oldest, band_.m - 1].
  double u0 = (static_cast<double>(begin) - t0) / d;
  double u1 = (static_cast<double>(end) - t0) / d;
  u0 = std::max(u0, static_cast<double>(oldest));
  u1 = std::min(u1, static_cast<double>(band_.m - 1));
  if (u1 - u0 < 8.0 / d) return NAN;
  auto at = [&](double u) {
    const auto k = static_cast<std::uint64_t>(u);
    const double f = u - static_cast<double>(k);
    const double a = value(k);
    return f > 0.0 ? a + f * (value(k + 1) - a) : a;
  };
  // Trapezoids: partial first and last intervals, whole ones between.
  const double k0 = std::ceil(u0), k1 = std::floor(u1);
  if (k0 > k1) return 0.5 * (at(u0) + at(u1));
  double area = 0.5 * (at(u0) + at(k0)) * (k0 - u0) + 0.5 * (at(k1) + at(u1)) * (u1 - k1);
  for (auto k = static_cast<std::uint64_t>(k0); k < static_cast<std::uint64_t>(k1); ++k)
    area += 0.5 * (value(k) + value(k + 1));
  return area / (u1 - u0);
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
