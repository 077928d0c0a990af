// Stage 2 of the impact detector (impact_detector.hpp): the trigger band by complex demodulation,
// anti-alias FIR with decimation and a 4th-order Butterworth low-pass on I and Q; e = I^2 + Q^2 per
// band sample; and stage 3's bookkeeping per band sample (energy history, STA and pre-window sums,
// LTA), handing each band sample that may trigger to stage 4 (detector_trigger.cpp).
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>

#include "core/dsp/kernels/fir_steps.hpp"
#include "core/dsp/kernels/iq_lowpass.hpp"
#include "core/dsp/kernels/phasor_rotate.hpp"
#include "core/dsp/kernels/ring_sum.hpp"
#include "core/pipeline/detector_trigger.hpp"
#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

namespace {

namespace kernels = dsp::kernels;

// RBJ audio-EQ cookbook low-pass biquad (bilinear transform with frequency pre-warping), a0 = 1.
// Its numerator is (1, 2, 1) b0 exactly: b0 = ((1 - c) / 2) / a0 is (1 - c) / a0 halved, and binary
// scaling commutes with rounding (kernel iq_lowpass relies on it; checked in design_band()).
kernels::BiquadCoefs lowpass_biquad(double f_hz, double q, double fs) {
  const double w0 = 2.0 * std::numbers::pi * f_hz / fs;
  const double c = std::cos(w0), alpha = std::sin(w0) / (2.0 * q);
  const double a0 = 1.0 + alpha;
  kernels::BiquadCoefs b;
  b.b0 = (1.0 - c) / 2.0 / a0;
  b.b1 = (1.0 - c) / a0;
  b.b2 = b.b0;
  b.a1 = -2.0 * c / a0;
  b.a2 = (1.0 - alpha) / a0;
  return b;
}

// p / |p| to first order (one Newton step on |p|^2 = 1): keeps a phasor advanced by products on the
// unit circle.
std::complex<double> renormalised(std::complex<double> p) {
  const double g = 0.5 * (3.0 - (p.real() * p.real() + p.imag() * p.imag()));
  return {p.real() * g, p.imag() * g};
}

}  // namespace

void ImpactDetector::design_band(double fc, double bw) {
  // Triangular anti-alias FIR (two boxcars of D, 2D - 1 taps, unit DC gain) on the demodulated signal;
  // with D = 1 a single unit tap. Stored oldest-sample first as h[k] e^{+i w k}, k = L - 1 - i.
  const std::size_t n_taps = 2 * dec_ - 1;
  taps_ = (n_taps + 3) / 4 * 4;  // zero-padded (oldest end) to a multiple of 4 for fir_steps
  const double w = 2.0 * std::numbers::pi * fc / fs_;
  g_re_.assign(taps_, 0.0f);
  g_im_.assign(taps_, 0.0f);
  const double d2 = static_cast<double>(dec_) * static_cast<double>(dec_);
  for (std::size_t k = 0; k < n_taps; ++k) {
    const double dist = std::abs(static_cast<double>(k) - static_cast<double>(dec_ - 1));
    const double h = (static_cast<double>(dec_) - dist) / d2;
    g_re_[taps_ - 1 - k] = static_cast<float>(h * std::cos(w * static_cast<double>(k)));
    g_im_[taps_ - 1 - k] = static_cast<float>(h * std::sin(w * static_cast<double>(k)));
  }
  rot_d_ = std::polar(1.0, -w * static_cast<double>(dec_));
  // Demodulation phasors: e^{-i w D m} = base(m / kGroup) e^{-i w D (m mod kGroup)}, the second factor
  // from a float table, the base advanced in double by e^{-i w D kGroup} and renormalised per group.
  pw_re_.fill(0.0f);
  pw_im_.fill(0.0f);
  for (std::size_t k = 0; k < kGroup; ++k) {
    const std::complex<double> p = std::polar(1.0, -w * static_cast<double>(dec_ * k));
    pw_re_[k] = static_cast<float>(p.real());
    pw_im_[k] = static_cast<float>(p.imag());
  }
  rot_g_ = std::polar(1.0, -w * static_cast<double>(dec_ * kGroup));
  lp1_ = lowpass_biquad(bw, 0.54119610014619698, fs_d_);  // Q = 1 / (2 cos(pi/8))
  lp2_ = lowpass_biquad(bw, 1.3065629648763766, fs_d_);   // Q = 1 / (2 cos(3 pi/8))
  for (const kernels::BiquadCoefs* c : {&lp1_, &lp2_})
    if (c->b1 != 2.0 * c->b0 || c->b2 != c->b0) throw std::logic_error("ImpactDetector: low-pass numerator not (1, 2, 1) b0");
}

void ImpactDetector::measure_fill_up(double bw, std::vector<std::complex<double>>& responses) {
  // Noise gain and fill-up of the whole chain for white input: the squared responses of the band
  // samples to a unit impulse at each of the D positions of a block, S[m] summed over the
  // positions. E[e] after m band samples of a segment = sum_{j <= m} S[j] (impulses in later blocks
  // act like earlier ones on earlier band samples), the stationary value is sum S. Summed over
  // 0.25 s, or longer for narrow bands: the slowest pole pair of the low-pass decays like
  // exp(-2 pi B sin(22.5 deg) t), its squared response like exp(-4.81 B t), which is < 1e-6 after
  // 2.9 / B s (0.25 s covered only 6 % of the sum at B = 1 Hz and 67 % at 2 Hz).
  const double sum_s = std::max(0.25, 3.0 / bw);
  const std::size_t n_out = static_cast<std::size_t>(std::ceil(sum_s * fs_d_)) + 8;
  std::vector<double> s(n_out, 0.0), x(n_out * dec_, 0.0);
  std::vector<std::complex<double>> y;
  responses.assign(dec_ * n_out, {});  // kept for measure_lag_correlation()
  for (std::size_t p = 0; p < dec_; ++p) {
    if (p > 0) x[p - 1] = 0.0;  // the previous position's impulse
    x[p] = 1.0;
    run_chain(x, y);
    for (std::size_t m = 0; m < n_out; ++m) s[m] += std::norm(y[m]);
    std::copy(y.begin(), y.begin() + static_cast<std::ptrdiff_t>(n_out), responses.begin() + static_cast<std::ptrdiff_t>(p * n_out));
  }
  band_noise_gain_ = 0.0;
  for (double v : s) band_noise_gain_ += v;
  double acc = 0.0;
  fill_.clear();
  for (std::size_t m = 0; m < n_out; ++m) {
    acc += s[m];
    const double g = acc / band_noise_gain_;
    if (g >= 0.999) break;
    fill_.push_back(std::max(g, 1e-3));
  }
  // No trigger before the STA window is full and the chain has reached a quarter of its stationary
  // output power (before that, 1/g amplifies the start too much).
  warmup_d_ = sta_d_;
  while (warmup_d_ < fill_.size() && fill_[warmup_d_] < 0.25) ++warmup_d_;
}

void ImpactDetector::run_chain(const std::vector<double>& x, std::vector<std::complex<double>>& y) const {
  // The trigger band of a record x starting at rest, block grid at x[0], with the kernels' scalar
  // references (bit-identical to band_blocks()).
  kernels::IqLowPass4State lp;
  std::complex<double> ph{1.0, 0.0};
  std::size_t k_ph = 0;
  y.clear();
  std::vector<float> padded(taps_ - 1 + x.size(), 0.0f);
  std::transform(x.begin(), x.end(), padded.begin() + static_cast<std::ptrdiff_t>(taps_ - 1),
                 [](double v) { return static_cast<float>(v); });
  // Past the last non-zero sample (an impulse response) the FIR windows hold only zeros, whose
  // output is +0 (fir_steps_generic's sums of +-0 products from +0), so they are not summed.
  std::size_t zero_from = x.size();  // FIR windows ending at or after this index are all zero
  while (zero_from > 0 && padded[taps_ - 2 + zero_from] == 0.0f) --zero_from;
  zero_from += taps_ - 1;
  for (std::size_t j = dec_ - 1; j < x.size(); j += dec_) {
    float fr = 0.0f, fi = 0.0f, zr = 0.0f, zi = 0.0f;
    if (j < zero_from)
      kernels::fir_steps_generic(padded.data() + j, dec_, 1, g_re_.data(), g_im_.data(), taps_, &fr, &fi);
    kernels::phasor_rotate_generic(&fr, &fi, &pw_re_[k_ph], &pw_im_[k_ph], static_cast<float>(ph.real()),
                                   static_cast<float>(ph.imag()), 1, &zr, &zi);
    if (++k_ph == kGroup) {
      k_ph = 0;
      ph = renormalised(ph * rot_g_);
    }
    const dsp::simd::f64x2 out =
        kernels::iq_lowpass4_step_generic(lp1_, lp2_, lp, dsp::simd::f64x2{static_cast<double>(zr), static_cast<double>(zi)});
    y.emplace_back(out[0], out[1]);
  }
}

void ImpactDetector::demodulate(const float* x, std::size_t n, std::size_t i0, std::complex<double>& ph) {
  // FIR outputs of n band samples (x: the first step's FIR window), demodulated by the phasors of band
  // samples i0 .. i0 + n - 1 of the current group (in float, as run_chain()); the base advances at the
  // group's end.
  kernels::fir_steps(x, dec_, n, g_re_.data(), g_im_.data(), taps_, fir_re_.data(), fir_im_.data());
  kernels::phasor_rotate(fir_re_.data(), fir_im_.data(), pw_re_.data() + i0, pw_im_.data() + i0,
                         static_cast<float>(ph.real()), static_cast<float>(ph.imag()), n, z_re_.data(), z_im_.data());
  if (i0 + n == kGroup) ph = renormalised(ph * rot_g_);
}

void ImpactDetector::resum(BandState& s) const {
  // The STA/PRE sums from the history of the band samples before s.m (their rounding cannot accumulate).
  s.resum_left = pre_d_;
  const std::uint64_t have = s.m;
  const std::uint64_t pre_lo = have - std::min<std::uint64_t>(sta_d_ + pre_d_, have);
  const std::uint64_t sta_lo = have - std::min<std::uint64_t>(sta_d_, have);
  s.sta_sum = kernels::ring_sum(th_, e_mask_, sta_lo, have);
  s.pre_sum = kernels::ring_sum(th_, e_mask_, pre_lo, sta_lo);
}

inline void ImpactDetector::push_energy(BandState& s, double e) {
  // Band sample m = s.m into the history; running sums of the STA window [m - sta + 1, m] and the
  // pre-window before it, re-summed once per pre-window.
  const std::uint64_t m = s.m;
  double* const eh = th_;
  eh[m & e_mask_] = e;
  s.sta_sum += e;
  if (m >= sta_d_) {
    const double moved = eh[(m - sta_d_) & e_mask_];
    s.sta_sum -= moved;
    s.pre_sum += moved;
    if (m >= sta_d_ + pre_d_) s.pre_sum -= eh[(m - sta_d_ - pre_d_) & e_mask_];
  }
  s.m = m + 1;
  if (--s.resum_left == 0) resum(s);
}

double ImpactDetector::innovation(const BandState& s, std::complex<double> z, double e) {
  // Innovation mode (stage 3): stores band sample m = s.m's energy e for band_power() (divided by the
  // fill-up like the energy path's) and z, and returns the trigger statistic q = |z - p z[m - k]|^2,
  // p from the sums before this sample; then updates the sums unless frozen (as the LTA).
  const std::uint64_t m = s.m;
  e_hist_[m & e_mask_] = m < fill_.size() ? e / fill_[static_cast<std::size_t>(m)] : e;
  z_hist_[m & e_mask_] = z;
  if (m < innov_lag_d_) return e;  // nothing to predict from yet
  const std::complex<double> zk = z_hist_[(m - innov_lag_d_) & e_mask_];
  std::complex<double> p = innov_w_ > 0.0 ? innov_c_ / innov_w_ : std::complex<double>{};
  const double mag = std::abs(p);
  if (mag > 1.0) p /= mag;  // a free decay never grows
  const double q = std::norm(z - p * zk);
  if (m >= lta_frozen_until_) {
    innov_c_ += lta_alpha_ * (z * std::conj(zk) - innov_c_);
    innov_w_ += lta_alpha_ * (std::norm(zk) - innov_w_);
  }
  return q;
}

bool ImpactDetector::steady(const BandState& s) const {
  // Past the fill-up, full windows, the LTA raised, running (not frozen, past its cumulative start)
  // and armed (no confirmation, hold-off or start-up rule): band_sample_general() would do exactly
  // what band_sample_steady() does. Only decide_band_sample() changes these conditions.
  const std::uint64_t m = s.m;
  return m >= fill_.size() && m >= sta_d_ + pre_d_ && lta_raised_ && m >= lta_frozen_until_ &&
         s.lta_count > lta_d_ && m + 1 >= warmup_d_ && !confirming_ && m >= holdoff_end_ && !startup_;
}

inline bool ImpactDetector::band_sample_steady(BandState& s, double e) {
  // The steady state's path: returns whether stage 4 must look at the band sample (it triggers).
  push_energy(s, e);
  s.lta = lta_next(s.lta, e, ++s.lta_count);
  return fires(s.sta_sum, s.lta, full_pre_mean(s.pre_sum));
}

inline bool ImpactDetector::band_sample_general(BandState& s, double& e, std::size_t sub) {
  // Any band sample: returns whether stage 4 must look at it (confirming, or armed and it may trigger).
  const std::uint64_t m = s.m;
  // While the chain fills up after a (re)start, stationary input gives E[e] = E_inf g(m): divide by
  // g so the start of a record is not a rising edge.
  if (m < fill_.size()) e /= fill_[static_cast<std::size_t>(m)];
  push_energy(s, e);
  // LTA: cumulative mean at first, then the capped exponential mean; frozen around triggers. The
  // fill-up samples before the warm-up are divided by a tiny g and are unreliable; since the capped
  // mean may grow by at most (1 + 2/n) per sample, a start far too low would take ~100 ms to recover
  // and leave only PRE as the reference. So at the end of the warm-up the LTA is raised to the
  // white-noise band power measured by the spike stage (see white_band_power()), or, when that scale
  // is not ready yet (it needs kMadWarmup samples: at 8 kHz with D = 1 the warm-up ends after ~24),
  // at the first band sample after the warm-up where it is. Once per segment.
  if (!lta_raised_ && m + 1 >= warmup_d_ && scale_ready_[sub]) {
    s.lta = std::max(s.lta, kCapBias * white_band_power(scale_at_[sub]));
    lta_raised_ = true;
  }
  if (m >= lta_frozen_until_) s.lta = lta_next(s.lta, e, ++s.lta_count);
  if (m + 1 < warmup_d_) return false;  // STA not yet full, or the chain has not filled enough
  if (confirming_) return true;
  if (m < holdoff_end_) return false;  // as in decide_band_sample()
  // Armed with full windows after the start-up: stage 4's test decides here already.
  if (!startup_ && m >= sta_d_ + pre_d_) return fires(s.sta_sum, s.lta, full_pre_mean(s.pre_sum));
  return true;
}

void ImpactDetector::band_blocks(std::uint64_t b, std::size_t count) {
  // count band samples from the run starting at b: one per D samples, at the last index of each. The
  // FIR outputs of a chunk of up to kGroup band samples are computed first in one pass (the taps stay
  // in registers), the recursive part then runs over them.
  const float* x = buf_x_.data() + (b - base_) + dec_ - taps_;  // the first step's FIR window
  const kernels::IqLowPass4Coefs lp(lp1_, lp2_);
  BandState& s = band_;
  for (std::size_t j0 = 0; j0 < count;) {
    // Chunks end at the phasor groups' boundaries (m a multiple of kGroup): the phasor of band sample
    // m depends on m only.
    const auto i0 = static_cast<std::size_t>(s.m % kGroup);
    const std::size_t n_chunk = std::min(kGroup - i0, count - j0);
    demodulate(x + j0 * dec_, n_chunk, i0, s.phasor);
    bool fast = !innov_ && steady(s);  // innovation mode: the general path only
    for (std::size_t j = 0; j < n_chunk; ++j) {
      const dsp::simd::f64x2 y =
          kernels::iq_lowpass4_step(lp, s.lp, dsp::simd::f64x2{static_cast<double>(z_re_[j]), static_cast<double>(z_im_[j])});
      double e = y[0] * y[0] + y[1] * y[1];
      if (innov_) e = innovation(s, {y[0], y[1]}, e);
      else z_hist_[s.m & e_mask_] = {y[0], y[1]};  // for ringing_free_noise_power()
      const std::size_t sub = sub_of_[j0 + j];
      if (!(fast ? band_sample_steady(s, e) : band_sample_general(s, e, sub))) continue;
      fast = false;
      decide_band_sample(s.m - 1, e, scale_at_[sub]);
    }
    j0 += n_chunk;
  }
}

}  // namespace ridgewatch::pipeline
