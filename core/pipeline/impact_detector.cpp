#include "core/pipeline/impact_detector.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>
#include <stdexcept>

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

constexpr double kSixth = 1.0 / 6.0;
// The interpolation residual (stage 1) in float as x[n] + (x[n-2] + x[n+2]) / 6 - (x[n-1] + x[n+1]) 2/3.
constexpr float kSixthF = 1.0f / 6.0f, kTwoThirdsF = 2.0f / 3.0f;

// Four floats in one register (SSE2 on x86-64, NEON on AArch64), with GCC/Clang vector extensions:
// the four partial sums below are four independent lanes. Written as plain loops over four scalar
// partial sums, GCC 12 vectorises across the groups of four instead and then adds the lanes in order,
// one scalar add per element (the sums must keep their order: float addition is not associative and
// the results are bit-identical to the scalar definition). Lane j of a sum holds the elements
// k = j (mod 4) in order; the lanes are combined as (s0 + s1) + (s2 + s3).
using F4 = float __attribute__((vector_size(16)));
using I4 = std::int32_t __attribute__((vector_size(16)));
using V2d = double __attribute__((vector_size(16)));  // I and Q lanes of the trigger band's low-pass

// Unaligned loads and stores of four floats. Through a vector type of float (an access of the element
// type for the compiler's alias analysis; memcpy would count as a store that may alias anything and
// make the compiler reload members after it).
using F4u = float __attribute__((vector_size(16), aligned(4)));

inline F4 load4(const float* p) { return *reinterpret_cast<const F4u*>(p); }
inline void store4(float* p, F4 v) { *reinterpret_cast<F4u*>(p) = v; }

inline float lanes_sum(F4 s) { return (s[0] + s[1]) + (s[2] + s[3]); }

// {lanes_sum(a[0]), ..., lanes_sum(a[3])}, the same additions in the same order: pairs of lanes
// summed in one add for two vectors at a time, then the pairs of pairs.
// __builtin_shufflevector (constant lane indices) is understood by both GCC (>= 12) and Clang; the
// libFuzzer build uses Clang.
inline F4 lanes_sum4(const F4 (&a)[4]) {
  const F4 p = __builtin_shufflevector(a[0], a[1], 0, 2, 4, 6) +
               __builtin_shufflevector(a[0], a[1], 1, 3, 5, 7);  // a0 01 23, a1 01 23
  const F4 q = __builtin_shufflevector(a[2], a[3], 0, 2, 4, 6) + __builtin_shufflevector(a[2], a[3], 1, 3, 5, 7);
  return __builtin_shufflevector(p, q, 0, 2, 4, 6) + __builtin_shufflevector(p, q, 1, 3, 5, 7);
}

// Dot products of the samples with the real and imaginary FIR taps (float, see the header: stage 2a),
// n a multiple of 4.
inline void fir_dot(const float* x, const float* g_re, const float* g_im, std::size_t n, double& re, double& im) {
  F4 a_re = {0, 0, 0, 0}, a_im = {0, 0, 0, 0};
  for (std::size_t k = 0; k < n; k += 4) {
    const F4 xv = load4(x + k);
    a_re += load4(g_re + k) * xv;
    a_im += load4(g_im + k) * xv;
  }
  re = static_cast<double>(lanes_sum(a_re));
  im = static_cast<double>(lanes_sum(a_im));
}

// fir_dot() for count windows step samples apart (x: the first), with the NV tap vectors held in
// registers; re[j], im[j] as floats (fir_dot() widens them to double).
template <std::size_t NV>
void fir_steps(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im, float* re,
               float* im) {
  F4 gr[NV], gi[NV];
  for (std::size_t v = 0; v < NV; ++v) {
    gr[v] = load4(g_re + 4 * v);
    gi[v] = load4(g_im + 4 * v);
  }
  std::size_t j = 0;
  for (; j + 4 <= count; j += 4, x += 4 * step) {
    // Four windows at once, their lane sums by a transposition (the same sums as lanes_sum()).
    F4 a_re[4], a_im[4];
    for (std::size_t u = 0; u < 4; ++u) {
      a_re[u] = F4{0, 0, 0, 0};
      a_im[u] = F4{0, 0, 0, 0};
      for (std::size_t v = 0; v < NV; ++v) {
        const F4 xv = load4(x + u * step + 4 * v);
        a_re[u] += gr[v] * xv;
        a_im[u] += gi[v] * xv;
      }
    }
    store4(re + j, lanes_sum4(a_re));
    store4(im + j, lanes_sum4(a_im));
  }
  for (; j < count; ++j, x += step) {
    F4 a_re = {0, 0, 0, 0}, a_im = {0, 0, 0, 0};
    for (std::size_t v = 0; v < NV; ++v) {
      const F4 xv = load4(x + 4 * v);
      a_re += gr[v] * xv;
      a_im += gi[v] * xv;
    }
    re[j] = lanes_sum(a_re);
    im[j] = lanes_sum(a_im);
  }
}

void fir_steps_any(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
                   std::size_t n_taps, float* re, float* im) {
  switch (n_taps / 4) {
    case 1: return fir_steps<1>(x, step, count, g_re, g_im, re, im);
    case 2: return fir_steps<2>(x, step, count, g_re, g_im, re, im);
    case 3: return fir_steps<3>(x, step, count, g_re, g_im, re, im);
    case 4: return fir_steps<4>(x, step, count, g_re, g_im, re, im);
    case 5: return fir_steps<5>(x, step, count, g_re, g_im, re, im);
    case 6: return fir_steps<6>(x, step, count, g_re, g_im, re, im);
    default:
      for (std::size_t j = 0; j < count; ++j, x += step) {
        double dr = 0.0, di = 0.0;
        fir_dot(x, g_re, g_im, n_taps, dr, di);
        re[j] = static_cast<float>(dr);  // exact: fir_dot widened a float
        im[j] = static_cast<float>(di);
      }
  }
}

// Sum of min(|r|, clip) and whether any |r| > above (the remainder of n mod 4 goes to lane 0).
inline bool clipped_sum_any_above(const float* r, std::size_t n, float clip, float above, double& sum) {
  const F4 vclip = {clip, clip, clip, clip}, vabove = {above, above, above, above};
  constexpr std::int32_t kNoSign = 0x7fffffff;
  const I4 no_sign = {kNoSign, kNoSign, kNoSign, kNoSign};
  F4 s = {0, 0, 0, 0};
  I4 any = {0, 0, 0, 0};
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) {
    const F4 a = reinterpret_cast<F4>(reinterpret_cast<I4>(load4(r + k)) & no_sign);  // |r|
    s += vclip < a ? vclip : a;  // std::min(a, clip)
    any |= a > vabove;
  }
  float s0 = s[0];
  bool above_any = (any[0] | any[1] | any[2] | any[3]) != 0;
  for (; k < n; ++k) {
    const float a = std::abs(r[k]);
    s0 += std::min(a, clip);
    above_any |= a > above;
  }
  sum = static_cast<double>((s0 + s[1]) + (s[2] + s[3]));
  return above_any;
}

// p / |p| to first order (one Newton step on |p|^2 = 1): keeps a phasor advanced by products on the
// unit circle.
std::complex<double> renormalised(std::complex<double> p) {
  const double g = 0.5 * (3.0 - (p.real() * p.real() + p.imag() * p.imag()));
  return {p.real() * g, p.imag() * g};
}

// Sum of the ring entries eh[i & mask], i in [lo, hi), in four interleaved partial sums (two
// two-double vectors: a short dependency chain).
double ring_sum(const double* eh, std::uint64_t mask, std::uint64_t lo, std::uint64_t hi) {
  using V2du = double __attribute__((vector_size(16), aligned(8)));
  V2d a = {0.0, 0.0}, c = {0.0, 0.0};
  for (std::uint64_t i = lo; i < hi;) {
    const std::uint64_t p = i & mask;
    const std::uint64_t n = std::min(hi - i, mask + 1 - p);  // contiguous up to the ring's end
    const double* q = eh + p;
    std::uint64_t k = 0;
    for (; k + 4 <= n; k += 4) {
      a += *reinterpret_cast<const V2du*>(q + k);
      c += *reinterpret_cast<const V2du*>(q + k + 2);
    }
    for (; k < n; ++k) a[0] += q[k];
    i += n;
  }
  const V2d s = a + c;
  return s[0] + s[1];
}

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
  // Triangular anti-alias FIR (two boxcars of D, 2D - 1 taps, unit DC gain) on the demodulated signal;
  // with D = 1 a single unit tap. Stored oldest-sample first as h[k] e^{+i w k}, k = L - 1 - i.
  const std::size_t n_taps = 2 * dec_ - 1;
  taps_ = (n_taps + 3) / 4 * 4;  // zero-padded (oldest end) to a multiple of 4 for fir_dot
  const double w = 2.0 * std::numbers::pi * fc / fs;
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
  proto_.s1 = Biquad::lowpass(bw, 0.54119610014619698, fs_d_);  // 1 / (2 cos(pi/8))
  proto_.s2 = Biquad::lowpass(bw, 1.3065629648763766, fs_d_);   // 1 / (2 cos(3 pi/8))
  // band_blocks() relies on b1 = 2 b0 and b2 = b0 exactly (see there).
  for (const Biquad* c : {&proto_.s1, &proto_.s2})
    if (c->b1 != 2.0 * c->b0 || c->b2 != c->b0) throw std::logic_error("ImpactDetector: low-pass numerator not (1, 2, 1) b0");

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
  const double lta_in = std::max(2.0, std::round(cfg.lta_s * fs));
  mad_beta_ = 1.0 - std::pow(1.0 - 1.0 / lta_in, static_cast<double>(blk_));

  {
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
    for (std::size_t p = 0; p < dec_; ++p) {
      std::fill(x.begin(), x.end(), 0.0);
      x[p] = 1.0;
      run_chain(x, y);
      for (std::size_t m = 0; m < n_out; ++m) s[m] += std::norm(y[m]);
    }
    band_noise_gain_ = 0.0;
    for (double v : s) band_noise_gain_ += v;
    double acc = 0.0;
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
  calibrate(fc);
  {
    // Start-up rise reference: a window of 2 ms ending one model peak time before the newest band
    // sample (an impact's rise from onset to peak lies after it), its mean scaled by the model's
    // energy decay over the distance between the window's centre and now.
    lag_d_ = static_cast<std::size_t>(std::llround(peak_samples_ / static_cast<double>(dec_)));
    lagw_d_ = std::max<std::size_t>(sta_d_, static_cast<std::size_t>(std::ceil(0.002 * fs_d_)));
    const double sigma0 = kModelZeta * 2.0 * std::numbers::pi * fc;
    lag_decay_ = std::exp(-2.0 * sigma0 * (static_cast<double>(lag_d_) + 0.5 * static_cast<double>(lagw_d_ - 1)) / fs_d_);
    startup_end_d_ = warmup_d_ + lta_d_;
  }
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
  {
    // Bound on (report - onset) in input samples. The decision comes at the first band sample at or past
    // onset + peak + 1 ms (the provisional onset is the final one), or, for a weak impact triggered
    // near its peak, when the confirmation after a trigger at most lookback_ after the onset is
    // complete; + one run (band-sample grid) and the spike delay before a run is processed.
    const double by_peak = peak_samples_ + 0.001 * fs;
    const double by_confirm = static_cast<double>(lookback_ + confirm_d_ * dec_);
    report_delay_ = static_cast<std::size_t>(std::ceil(std::max(by_peak, by_confirm))) + run_ + kSpikeDelay + 1;
  }

  const std::size_t hist_d = (history_samples + lookback_ + report_delay_) / dec_ + pre_d_ + sta_d_ + 64;
  const std::uint64_t esize = std::bit_ceil(std::max<std::size_t>(hist_d, 64));
  e_hist_.assign(esize, 0.0);
  e_mask_ = esize - 1;
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
  restart(0);
}

void ImpactDetector::run_chain(const std::vector<double>& x, std::vector<std::complex<double>>& y) const {
  // The trigger band of a record x starting at rest, block grid at x[0]: as process_block().
  LowPass4 li = proto_, lq = proto_;
  std::complex<double> ph{1.0, 0.0};
  std::size_t k_ph = 0;
  y.clear();
  std::vector<float> padded(taps_ - 1, 0.0f);
  for (double v : x) padded.push_back(static_cast<float>(v));
  for (std::size_t j = dec_ - 1; j < x.size(); j += dec_) {
    double re = 0.0, im = 0.0;
    fir_dot(padded.data() + j, g_re_.data(), g_im_.data(), taps_, re, im);  // x[j - L + 1 .. j]
    // As band_blocks(): float products with the phasor base(m) table(m mod kGroup).
    const auto br = static_cast<float>(ph.real()), bi = static_cast<float>(ph.imag());
    const float pr = br * pw_re_[k_ph] - bi * pw_im_[k_ph], pi = br * pw_im_[k_ph] + bi * pw_re_[k_ph];
    const auto fr = static_cast<float>(re), fi = static_cast<float>(im);
    const std::complex<double> z(static_cast<double>(fr * pr - fi * pi), static_cast<double>(fr * pi + fi * pr));
    if (++k_ph == kGroup) {
      k_ph = 0;
      ph = renormalised(ph * rot_g_);
    }
    y.emplace_back(li.step(z.real()), lq.step(z.imag()));
  }
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
  lp_i_ = proto_;
  lp_q_ = proto_;
  phasor_ = {1.0, 0.0};
  sta_sum_ = pre_sum_ = 0.0;
  band_count_ = 0;
  resum_left_ = pre_d_;
  lta_ = 0.0;
  lta_count_ = 0;
  lta_raised_ = false;
  holdoff_end_ = lta_frozen_until_ = 0;
  confirming_ = false;
  confirmed_ = false;
  confirm_sum_ = 0.0;
  confirm_seen_ = 0;
  startup_ = true;
}

void ImpactDetector::calibrate(double fc) {
  // The trigger chain's envelope for x = exp(-sigma0 t) cos(2 pi fc t), t >= 0, sigma0 for
  // zeta = 0.024 (the paper rig), started at each position p of the block grid: the 50 % crossing of
  // its maximum and the time of the maximum, in input samples after the start.
  const double sigma0 = kModelZeta * 2.0 * std::numbers::pi * fc;
  const auto n_len = static_cast<std::size_t>(std::ceil(0.1 * fs_)) + 2 * dec_;  // 100 ms is past any peak
  std::vector<double> x(n_len, 0.0);
  std::vector<std::complex<double>> y;
  double t50_sum = 0.0, t50_min = 1e300, t50_max = -1e300, peak_max = 0.0;
  for (std::size_t p = 0; p < dec_; ++p) {
    for (std::size_t n = 0; n < n_len; ++n) {
      const double t = (static_cast<double>(n) - static_cast<double>(p)) / fs_;
      x[n] = n < p ? 0.0 : std::exp(-sigma0 * t) * std::cos(2.0 * std::numbers::pi * fc * t);
    }
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

void ImpactDetector::spike_test(std::uint64_t n, double t_mad) {
  float* x = buf_x_.data() + (n - base_);
  float* r = buf_r_.data() + (n - base_);
  // A spike must also stand out against the signal itself: at least a quarter of the neighbours'
  // magnitude. The interpolation residual of a sharp but genuine feature (the kink of a 0.15 ms force
  // pulse sampled at 25.6 kHz leaves ~5 % of the amplitude) would otherwise pass 12 MAD at low noise;
  // sensor spikes are large (the simulator's 0.75-2 x the impact peak).
  const double neighbours = std::max({std::abs(x[-1]), std::abs(x[1]), std::abs(x[-2]), std::abs(x[2])});
  const double limit = std::max(t_mad, 0.25 * neighbours);
  const double rr = r[0];
  if (!(std::abs(rr) > limit)) return;
  // Broadband and isolated in time: a strong mode high in the band leaves an interpolation residual
  // at every sample of its ring, up to 2.1 times its amplitude near 0.39 fs (the residual filter's gain
  // 1 + cos(2 theta) / 3 - 4 cos(theta) / 3 at theta = 2 pi f / fs), so single samples of a multi-mode
  // response (a real hammer hit with modes up to 10 kHz at 25.6 kHz) passed the tests above and its
  // impacts were all marked spike. A spike must also exceed 3 times the largest residual of the
  // samples n-10 .. n-3 and n+3 .. n+10 (outside the +-2 samples its own residual reaches; the left
  // ones already decided, the right ones computed here from the samples, which the decision delay
  // of 12 samples provides). For a mode with a period of up to 16 samples (f >= fs / 16) each side's
  // 8 samples hold its residual's peak to within cos(pi / 16) = 0.98; slower modes leave
  // < theta^4 / 6 = 0.4 % of their amplitude. A mode that starts abruptly (an ideal impulse's
  // response) has no residual on the left but a ringing one on the right. For white noise the 16
  // samples' largest residual is ~2.2 residual sds, a third of a spike at the 12-MAD limit: a few %
  // of the spikes just at that limit are kept as signal (larger ones never).
  {
    const auto at = [&](std::ptrdiff_t k) { return static_cast<double>(std::abs(r[k])); };
    const std::uint64_t lo = std::max<std::uint64_t>({n > 10 ? n - 10 : 0, seg_start_ + 2, base_});
    double around = 0.0;
    for (std::uint64_t k = lo; k + 3 <= n; ++k) around = std::max(around, at(static_cast<std::ptrdiff_t>(k) - static_cast<std::ptrdiff_t>(n)));
    for (std::ptrdiff_t k = 3; k <= 10; ++k) {
      const double rk = static_cast<double>(x[k]) + static_cast<double>(x[k - 2] + x[k + 2]) / 6.0 -
                        static_cast<double>(x[k - 1] + x[k + 1]) * (2.0 / 3.0);
      around = std::max(around, std::abs(rk));
    }
    if (!(std::abs(rr) > 3.0 * around)) return;
  }
  const double r_m1 = r[-1] + 2.0 / 3.0 * rr, r_p1 = r[1] + 2.0 / 3.0 * rr;
  const double r_m2 = r[-2] - rr * kSixth, r_p2 = r[2] - rr * kSixth;
  if (std::abs(r_m1) <= limit && std::abs(r_p1) <= limit && std::abs(r_m2) <= limit && std::abs(r_p2) <= limit) {
    x[0] = static_cast<float>(x[0] - rr);  // the interpolation
    r[0] = 0.0f;
    r[-1] = static_cast<float>(r_m1);
    r[1] = static_cast<float>(r_p1);
    r[-2] = static_cast<float>(r_m2);
    r[2] = static_cast<float>(r_p2);
    ++spikes_;
    spike_idx_[spike_head_] = n;
    spike_head_ = (spike_head_ + 1) % kSpikeRing;
    spike_count_ = std::min(spike_count_ + 1, kSpikeRing);
  }
}

void ImpactDetector::decide_block(std::uint64_t b, std::size_t len, std::size_t n_res, bool test_spikes) {
  // Samples [b, b + len). Residuals of [b + 2, b + 2 + n_res) (those of b, b + 1 came with the previous
  // block; the first two samples of a segment have no left neighbours: 0, never spikes).
  const std::size_t d = len;
  const float* x = buf_x_.data() + (b - base_);
  float* r = buf_r_.data() + (b - base_);
  // Robust scale: MAD from the winsorised mean |r| (Gaussian: E|r| = 0.7979 sd, MAD = 0.6745 sd).
  // The absolute floor keeps float32 rounding of an otherwise noise-free signal from looking noisy
  // or, with digital silence, everything from looking like a spike.
  const std::size_t first = b == seg_start_ ? 2 : 0;
  const float clip = block_clip();
  const bool scan = test_spikes && mad_count_ >= kMadWarmup;
  const double t_mad = spike_k_ * std::max(0.6745 / 0.7979 * mad_sum_, 1e-9);
  if (b == seg_start_) r[0] = r[1] = 0.0f;
  {
    // Separate buffers: __restrict lets the loop vectorise without a run-time overlap check.
    const float* __restrict xs = x;
    float* __restrict rs = r;
    for (std::size_t i = 2; i < 2 + n_res; ++i)
      rs[i] = (xs[i] + (xs[i - 2] + xs[i + 2]) * kSixthF) - (xs[i - 1] + xs[i + 1]) * kTwoThirdsF;
  }
  for (std::size_t i = 2 + n_res; i < d + 2; ++i) r[i] = 0.0f;  // end of segment: no right neighbours
  if (scan) {
    // Vectorisable pre-test (and the scale update's clipped sum, valid when nothing is removed);
    // only a block with a candidate runs the sequential isolation test (a corrected neighbour can
    // become a candidate, so the scan re-reads r).
    double s = 0.0;
    if (!clipped_sum_any_above(r + first, d - first, clip, static_cast<float>(t_mad), s)) {
      mad_sum_ += mad_beta_ * (s * inv_blk_ - mad_sum_);  // first == 0 and d == blk_ here
      return;
    }
    const std::size_t last = std::min(d, n_res);  // n needs residuals up to n + 2
    for (std::size_t i = 0; i < last; ++i)
      if (std::abs(r[i]) > t_mad) spike_test(b + i, t_mad);
  }
  // Update the scale with the block's residuals (after spike removal).
  if (mad_count_ < kMadWarmup) {
    for (std::size_t i = first; i < d; ++i) {
      const double a = std::abs(static_cast<double>(r[i]));
      if (mad_count_ < kMadWarmup) {
        ++mad_count_;
        mad_sum_ += (a - mad_sum_) / static_cast<double>(mad_count_);
      } else {
        mad_sum_ += mad_beta_ * inv_blk_ * (std::min(a, 3.0 * mad_sum_ + 1e-30) - mad_sum_);
      }
    }
  } else if (d > first) {
    double s = 0.0;
    clipped_sum_any_above(r + first, d - first, clip, 3e38f, s);
    mad_sum_ += mad_beta_ * static_cast<double>(d - first) * inv_blk_ * (s / static_cast<double>(d - first) - mad_sum_);
  }
}

void ImpactDetector::decide_blocks(std::uint64_t b, std::size_t count) {
  // count whole blocks from b whose spike delay has passed, one after the other (each block's scale
  // update is seen by the next); the scale after each is kept for the band samples in it. A block
  // with a warm scale, not at the segment start, first takes the fast path: residuals, their clipped
  // sum and the candidate pre-test in one pass over vectors of four at [4i, 4i + 4) from the block
  // start, the lanes of clipped_sum_any_above() (the same sums, bit for bit; the clipped sum reads the
  // residuals from registers, not back from memory). The first vector keeps r[0], r[1] (from the
  // previous block, possibly corrected by its spike test); the last one also writes up to two
  // residuals past b + blk + 1 from samples not yet pushed, which the next block recomputes before
  // anything reads them (the buffer has room). A block with a candidate is decided again by
  // decide_block() (the same residuals, then the isolation test).
  const F4 sixth = {kSixthF, kSixthF, kSixthF, kSixthF}, two_thirds = {kTwoThirdsF, kTwoThirdsF, kTwoThirdsF, kTwoThirdsF};
  constexpr std::int32_t kNoSign = 0x7fffffff;
  const I4 no_sign = {kNoSign, kNoSign, kNoSign, kNoSign};
  const std::size_t d = blk_, n_vec = (d + 2 + 3) / 4, n_sum = d / 4;
  std::size_t k0 = 0;  // blocks before k0 are decided
  if (d % 4 == 0 && count > 1 && mad_count_ >= kMadWarmup && b != seg_start_) {
    // Blocks of whole vectors with a warm scale (and so one winsorisation limit for the run): the
    // residuals, clipped sums and maxima of all count blocks in one pass (the vectors of the
    // per-block path below, the same sums), then the blocks' pre-tests and scale updates in order.
    // The first block with a candidate is decided by decide_block(), which may correct r[0], r[1] of
    // the next one: the blocks after it take the per-block path.
    const float* x = buf_x_.data() + (b - base_);
    float* r = buf_r_.data() + (b - base_);
    const float clip = block_clip();
    const F4 vclip = {clip, clip, clip, clip};
    const std::size_t nv = d / 4;
    auto residuals = [&](std::size_t v) {
      const float* xv = x + 4 * v;
      return (load4(xv) + (load4(xv - 2) + load4(xv + 2)) * sixth) - (load4(xv - 1) + load4(xv + 1)) * two_thirds;  // as decide_block()
    };
    std::array<F4, kMaxRunBlocks> sums, tops;
    F4 rv = residuals(0);
    rv[0] = r[0];  // from the previous run
    rv[1] = r[1];
    for (std::size_t k = 0; k < count; ++k) {
      F4 sum = {0, 0, 0, 0}, top = {0, 0, 0, 0};
      for (std::size_t v = 0; v < nv; ++v) {
        const std::size_t i = k * nv + v;
        if (i > 0) rv = residuals(i);
        store4(r + 4 * i, rv);
        const F4 a = reinterpret_cast<F4>(reinterpret_cast<I4>(rv) & no_sign);  // |r|
        sum += vclip < a ? vclip : a;                                            // std::min(a, clip)
        top = top < a ? a : top;                                                 // std::max(top, a)
      }
      sums[k] = sum;
      tops[k] = top;
    }
    store4(r + count * d, residuals(count * nv));  // r[0], r[1] of the next run (and two slots past)
    for (; k0 < count; ++k0) {
      const auto above = static_cast<float>(spike_k_ * std::max(0.6745 / 0.7979 * mad_sum_, 1e-9));
      const F4 top = tops[k0], sum = sums[k0];
      if (std::max(std::max(top[0], top[1]), std::max(top[2], top[3])) > above) {
        decide_block(b + k0 * d, d, d, true);
        note_scale(k0);
        ++k0;
        break;
      }
      const auto sm = static_cast<double>((sum[0] + sum[1]) + (sum[2] + sum[3]));
      mad_sum_ += mad_beta_ * (sm * inv_blk_ - mad_sum_);  // as in decide_block()
      note_scale(k0);
    }
  }
  for (std::size_t k = k0; k < count; ++k) {
    const std::uint64_t bk = b + k * d;
    if (mad_count_ < kMadWarmup || bk == seg_start_) {
      decide_block(bk, d, d, true);
      note_scale(k);
      continue;
    }
    const float* x = buf_x_.data() + (bk - base_);
    float* r = buf_r_.data() + (bk - base_);
    const float clip = block_clip();  // as in decide_block()
    const auto above = static_cast<float>(spike_k_ * std::max(0.6745 / 0.7979 * mad_sum_, 1e-9));
    const F4 vclip = {clip, clip, clip, clip};
    auto residuals = [&](std::size_t v) {
      const float* xv = x + 4 * v;
      return (load4(xv) + (load4(xv - 2) + load4(xv + 2)) * sixth) - (load4(xv - 1) + load4(xv + 1)) * two_thirds;  // as decide_block()
    };
    F4 sum = {0, 0, 0, 0}, top = {0, 0, 0, 0};  // top: lane-wise max |r| for the candidate test
    F4 rv = residuals(0);
    rv[0] = r[0];
    rv[1] = r[1];
    store4(r, rv);
    std::size_t v = 1;
    for (; v <= n_sum; ++v) {
      const F4 a = reinterpret_cast<F4>(reinterpret_cast<I4>(rv) & no_sign);  // |r| of vector v - 1
      sum += vclip < a ? vclip : a;                                            // std::min(a, clip)
      top = top < a ? a : top;                                                 // std::max(top, a)
      rv = residuals(v);
      store4(r + 4 * v, rv);
    }
    for (; v < n_vec; ++v) {
      rv = residuals(v);
      store4(r + 4 * v, rv);
    }
    float s0 = sum[0];
    bool candidate = std::max(std::max(top[0], top[1]), std::max(top[2], top[3])) > above;
    for (std::size_t i = 4 * n_sum; i < d; ++i) {  // d mod 4 left: lane 0, in order
      const float a = std::abs(r[i]);
      s0 += std::min(a, clip);
      candidate |= a > above;
    }
    if (candidate) {
      decide_block(bk, d, d, true);
    } else {
      const auto sm = static_cast<double>((s0 + sum[1]) + (sum[2] + sum[3]));
      mad_sum_ += mad_beta_ * (sm * inv_blk_ - mad_sum_);  // as in decide_block()
    }
    note_scale(k);
  }
}

void ImpactDetector::band_blocks(std::uint64_t b, std::size_t count) {
  // Complex demodulation + anti-alias FIR + decimation: one band sample per D samples, at the last
  // index of each; then the I/Q low-pass, the energy history, the STA/PRE sums and the LTA. The FIR
  // outputs of up to 16 band samples are computed first in one pass (the taps stay in registers), the
  // recursive part then runs over them. Its hot state lives in locals for the whole run (the stores
  // into the energy history could otherwise alias the members, which the compiler would then reload
  // for every band sample); the members are written back before the trigger logic runs. I and Q
  // share the low-pass: one lane each of a two-double vector, with the arithmetic of Biquad::step per
  // lane.
  const float* x = buf_x_.data() + (b - base_) + dec_ - taps_;  // the first step's FIR window
  const float* const g_re = g_re_.data();
  const float* const g_im = g_im_.data();
  const std::size_t taps = taps_;
  double* const eh = e_hist_.data();
  const std::uint64_t mask = e_mask_;
  const std::uint64_t n_fill = fill_.size();
  const std::uint64_t sta_d = sta_d_, full_d = sta_d_ + pre_d_;
  const double keep = lta_keep_, alpha = lta_alpha_, cap_alpha = lta_cap_alpha_;
  auto splat = [](double v) { return V2d{v, v}; };
  const Biquad& c1 = proto_.s1;
  const Biquad& c2 = proto_.s2;
  // Low-pass biquads: b1 = 2 b0 and b2 = b0 exactly (make_biquad: b0 = ((1 - c) / 2) / a0 is
  // (1 - c) / a0 halved, binary scaling commutes with rounding), so b1 x = b0 x + b0 x and b2 x = b0 x,
  // bit for bit: one product instead of three.
  const V2d b0_1 = splat(c1.b0), a1_1 = splat(c1.a1), a2_1 = splat(c1.a2);
  const V2d b0_2 = splat(c2.b0), a1_2 = splat(c2.a1), a2_2 = splat(c2.a2);
  V2d s1_1 = {lp_i_.s1.s1, lp_q_.s1.s1}, s2_1 = {lp_i_.s1.s2, lp_q_.s1.s2};
  V2d s1_2 = {lp_i_.s2.s1, lp_q_.s2.s1}, s2_2 = {lp_i_.s2.s2, lp_q_.s2.s2};
  std::complex<double> ph = phasor_;
  double sta_sum = sta_sum_, pre_sum = pre_sum_, lta = lta_;
  std::uint64_t m = band_count_;
  const std::uint8_t* const sub_of = sub_of_.data();  // block of the run (its scale: scale_at_[sub_of[j0 + j]])
  std::size_t resum_left = resum_left_;
  std::uint64_t lta_count = lta_count_;
  const double k_sta = inv_sta_d_ * (1.0 + 1e-9), k_lta = ratio_ / kCapBias, k_pre = ratio_ * inv_pre_d_;
  // The STA/PRE sums from the history of the band samples before `have`.
  auto resum = [&](std::uint64_t have) {
    resum_left = pre_d_;
    const std::uint64_t pre_lo = have - std::min<std::uint64_t>(full_d, have);
    const std::uint64_t sta_lo = have - std::min<std::uint64_t>(sta_d, have);
    sta_sum = ring_sum(eh, mask, sta_lo, have);
    pre_sum = ring_sum(eh, mask, pre_lo, sta_lo);
  };
  // FIR outputs and demodulated values of up to kGroup band samples (padded for the vectors of four).
  // (Members, zeroed once: the vectors of four read past a chunk's end.)
  float* const fir_re = fir_re_.data();
  float* const fir_im = fir_im_.data();
  float* const z_re = z_re_.data();
  float* const z_im = z_im_.data();
  const float* const pw_re = pw_re_.data();
  const float* const pw_im = pw_im_.data();
  for (std::size_t j0 = 0; j0 < count;) {
    // Chunks end at the phasor groups' boundaries (m a multiple of kGroup): the phasor of band sample
    // m depends on m only.
    const auto i0 = static_cast<std::size_t>(m % kGroup);
    const std::size_t n_chunk = std::min(kGroup - i0, count - j0);
    fir_steps_any(x + j0 * dec_, dec_, n_chunk, g_re, g_im, taps, fir_re, fir_im);
    {
      // z = (re + i im) e^{-i w D m}, in float (as run_chain()).
      const auto br = static_cast<float>(ph.real()), bi = static_cast<float>(ph.imag());
      const F4 vbr = {br, br, br, br}, vbi = {bi, bi, bi, bi};
      for (std::size_t v = 0; v < n_chunk; v += 4) {
        const F4 tr = load4(pw_re + i0 + v), ti = load4(pw_im + i0 + v);
        const F4 pr = vbr * tr - vbi * ti, pi = vbr * ti + vbi * tr;
        const F4 fr = load4(fir_re + v), fi = load4(fir_im + v);
        store4(z_re + v, fr * pr - fi * pi);
        store4(z_im + v, fr * pi + fi * pr);
      }
    }
    if (i0 + n_chunk == kGroup) ph = renormalised(ph * rot_g_);
    // Steady: past the fill-up, full windows, the LTA raised, running (not frozen, past its cumulative
    // start) and armed (no confirmation, hold-off or start-up rule). The chunk's band samples then take
    // the short path below (the same operations as the general path in this state) until one triggers;
    // only decide_band_sample() changes these conditions.
    bool steady = m >= n_fill && m >= full_d && lta_raised_ && m >= lta_frozen_until_ && lta_count > lta_d_ &&
                  m + 1 >= warmup_d_ && !confirming_ && m >= holdoff_end_ && !startup_;
    for (std::size_t j = 0; j < n_chunk; ++j, ++m) {
      const V2d z = {static_cast<double>(z_re[j]), static_cast<double>(z_im[j])};
      // 4th-order low-pass on I and Q (Biquad::step, two stages).
      const V2d bz_1 = b0_1 * z;
      const V2d y1 = bz_1 + s1_1;
      s1_1 = ((bz_1 + bz_1) + s2_1) - a1_1 * y1;
      s2_1 = bz_1 - a2_1 * y1;
      const V2d bz_2 = b0_2 * y1;
      const V2d y = bz_2 + s1_2;
      s1_2 = ((bz_2 + bz_2) + s2_2) - a1_2 * y;
      s2_2 = bz_2 - a2_2 * y;
      double e = y[0] * y[0] + y[1] * y[1];
      if (steady) {
        eh[m & mask] = e;
        sta_sum += e;
        const double moved = eh[(m - sta_d) & mask];
        sta_sum -= moved;
        pre_sum += moved;
        pre_sum -= eh[(m - full_d) & mask];
        if (--resum_left == 0) resum(m + 1);
        ++lta_count;
        lta = keep * lta + std::min(alpha * e, cap_alpha * lta);
        // The trigger test of decide_band_sample() with the constants folded, and by a margin of 1e-9
        // more permissive than its rounding can make a difference (negative sums, the floor 1e-30:
        // see there): decide_band_sample() decides whenever that test can fire.
        if (!(sta_sum * k_sta > std::max(lta * k_lta, pre_sum * k_pre))) continue;
        steady = false;
        band_count_ = m + 1;
        sta_sum_ = sta_sum;
        pre_sum_ = pre_sum;
        lta_ = lta;
        decide_band_sample(m, e, scale_at_[sub_of[j0 + j]]);
        continue;
      }
      // While the chain fills up after a (re)start, stationary input gives E[e] = E_inf g(m): divide by
      // g so the start of a record is not a rising edge.
      if (m < n_fill) e /= fill_[static_cast<std::size_t>(m)];
      eh[m & mask] = e;
      // Running sums of the STA window [m - sta + 1, m] and the pre-window before it; re-summed once
      // per pre-window so rounding cannot accumulate.
      sta_sum += e;
      if (m >= sta_d) {
        const double moved = eh[(m - sta_d) & mask];
        sta_sum -= moved;
        pre_sum += moved;
        if (m >= full_d) pre_sum -= eh[(m - full_d) & mask];
      }
      if (--resum_left == 0) resum(m + 1);
      // LTA: cumulative mean at first, then the capped exponential mean; frozen around triggers. The
      // fill-up samples before the warm-up are divided by a tiny g and are unreliable; since the capped
      // mean may grow by at most (1 + 2/n) per sample, a start far too low would take ~100 ms to recover
      // and leave only PRE as the reference. So at the end of the warm-up the LTA is raised to the
      // white-noise band power measured by the spike stage (see white_band_power()), or, when that scale
      // is not ready yet (it needs kMadWarmup samples: at 8 kHz with D = 1 the warm-up ends after ~24),
      // at the first band sample after the warm-up where it is. Once per segment.
      if (!lta_raised_ && m + 1 >= warmup_d_ && scale_ready_[sub_of[j0 + j]]) {
        lta = std::max(lta, kCapBias * white_band_power(scale_at_[sub_of[j0 + j]]));
        lta_raised_ = true;
      }
      if (m >= lta_frozen_until_) {
        ++lta_count;
        if (lta_count > lta_d_) {
          // = lta + alpha (min(e, 3 lta) - lta), arranged so that the dependency chain through lta is
          // short (alpha e off the chain).
          lta = keep * lta + std::min(alpha * e, cap_alpha * lta);
        } else if (lta_count <= sta_d) {
          lta += (e - lta) / static_cast<double>(lta_count);
        } else {
          lta += (std::min(e, kCap * lta) - lta) / static_cast<double>(lta_count);
        }
      }
      if (m + 1 < warmup_d_) continue;  // STA not yet full, or the chain has not filled enough
      if (!confirming_) {
        if (m < holdoff_end_) continue;  // as in decide_band_sample()
        if (!startup_ && m >= full_d) {
          // Armed, past the start-up and with full windows (the common case): the trigger test of
          // decide_band_sample(), which runs only when it fires.
          const double sta = std::max(sta_sum, 0.0) * inv_sta_d_;
          const double pre = std::max(pre_sum, 0.0) * inv_pre_d_;
          const double ref = std::max({lta * (1.0 / kCapBias), pre, 1e-30});
          if (!(sta > ratio_ * ref)) continue;
        }
      }
      band_count_ = m + 1;
      sta_sum_ = sta_sum;
      pre_sum_ = pre_sum;
      lta_ = lta;
      decide_band_sample(m, e, scale_at_[sub_of[j0 + j]]);
    }
    j0 += n_chunk;
  }
  resum_left_ = resum_left;
  lta_count_ = lta_count;
  band_count_ = m;
  sta_sum_ = sta_sum;
  pre_sum_ = pre_sum;
  lta_ = lta;
  phasor_ = ph;
  lp_i_.s1.s1 = s1_1[0];
  lp_q_.s1.s1 = s1_1[1];
  lp_i_.s1.s2 = s2_1[0];
  lp_q_.s1.s2 = s2_1[1];
  lp_i_.s2.s1 = s1_2[0];
  lp_q_.s2.s1 = s1_2[1];
  lp_i_.s2.s2 = s2_2[0];
  lp_q_.s2.s2 = s2_2[1];
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
      store4(wp_ + i, load4(p + i));
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
    if (seen > 0 && confirm_sum_ / static_cast<double>(seen) > ratio_ * trigger_ref_)
      refine_and_emit(trigger_, band_count_);
    confirming_ = false;
  }
}

std::uint64_t ImpactDetector::dec_end_index(double m) const {
  return seg_start_ + static_cast<std::uint64_t>(std::llround((m + 1.0) * static_cast<double>(dec_) - 1.0));
}

void ImpactDetector::decide_band_sample(std::uint64_t m, double e, double mad) {
  // Trigger logic for band sample m (energy e), after band_blocks() has stored it and updated the sums
  // and the LTA (band_count_ == m + 1); mad: the spike stage's scale as of m's block.
  const double sta = std::max(sta_sum_, 0.0) * inv_sta_d_;

  if (confirming_) {
    ++confirm_seen_;
    if (confirm_seen_ <= confirm_d_) confirm_sum_ += e;
    if (e > e_hist_[peak_at_ & e_mask_]) {
      peak_at_ = m;
      peak_since_ = m;
    }
    if (confirm_seen_ == confirm_d_) confirmed_ = confirm_sum_ / static_cast<double>(confirm_d_) > ratio_ * trigger_ref_;
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
  double pre = std::max(pre_sum_, 0.0) * inv_pre_d_;
  if (band_count_ < sta_d_ + pre_d_) {  // pre-window not yet full: mean over what it holds
    const std::uint64_t pre_count = band_count_ - std::min<std::uint64_t>(band_count_, sta_d_);
    pre = pre_count > 0 ? std::max(pre_sum_, 0.0) / static_cast<double>(pre_count) : 0.0;
  }
  double rise_ref = pre;
  if (startup_ && m >= warmup_d_ + lag_d_ + lagw_d_ - 1) {
    // Start-up (see the header, stage 4): the band can hold a decaying start transient (a rig that
    // rings from the start of the record, the filters' own switch-on transient). PRE lags its decay;
    // the lagged window, extrapolated with the model decay, is the level the transient can have now.
    double lag = 0.0;
    for (std::size_t k = 0; k < lagw_d_; ++k) lag += e_hist_[(m - lag_d_ - k) & e_mask_];
    // Floored by the white-noise band power (the LTA may still be too low, see the LTA update).
    rise_ref = std::min(pre, std::max(lag / static_cast<double>(lagw_d_) * lag_decay_, white_band_power(mad)));
  }
  if (startup_ && m >= startup_end_d_) startup_ = false;
  const double ref = std::max({lta_ * (1.0 / kCapBias), rise_ref, 1e-30});
  if (sta > ratio_ * ref) {
    confirming_ = true;
    trigger_ = m;
    peak_at_ = m;
    peak_since_ = m;
    est_peak_ = kNoPeak;
    trigger_ref_ = ref;
    confirm_sum_ = 0.0;
    confirm_seen_ = 0;
    confirmed_ = false;
    lta_frozen_until_ = m + std::max<std::size_t>(holdoff_d_, confirm_d_) + 1;
  }
}

void ImpactDetector::start_run_scale() {
  run_clip_ = static_cast<float>(3.0 * mad_sum_ + 1e-30);
  run_clip_ready_ = mad_count_ >= kMadWarmup;
}

void ImpactDetector::note_scale(std::size_t k) {
  scale_at_[k] = mad_sum_;
  scale_ready_[k] = mad_count_ >= kMadWarmup;
}

double ImpactDetector::white_band_power(double mad) const {
  // The band power of white noise with the variance the spike stage measures: the interpolation
  // residual has variance (1 + 34/36) sigma^2 for white noise (stage 1), mad (mad_sum_) is its mean
  // absolute value (0.7979 sd), and a start transient or a line in or near the band leaves almost no
  // residual (theta^4 / 6 of its amplitude).
  const double sd_r = mad / 0.7979;
  return sd_r * sd_r / (1.0 + 34.0 / 36.0) * band_noise_gain_;
}

std::uint64_t ImpactDetector::search_floor(std::uint64_t trigger) const {
  const std::uint64_t oldest = band_count_ > e_hist_.size() ? band_count_ - e_hist_.size() + 1 : 0;
  return std::max(oldest, trigger > search_back_d_ ? trigger - search_back_d_ : 0);
}

std::uint64_t ImpactDetector::onset_estimate(std::uint64_t trigger, std::uint64_t k_peak, double* onset_d) const {
  // The last crossing of half the envelope maximum before it (not further back than the search
  // window), in fractional band samples, minus the model's 50 % rise time.
  const double half = 0.5 * std::sqrt(e_hist_[k_peak & e_mask_]);
  const std::uint64_t floor_k = search_floor(trigger);
  double crossing = static_cast<double>(floor_k);
  for (std::uint64_t k = k_peak; k > floor_k; --k) {
    const double lo = std::sqrt(e_hist_[(k - 1) & e_mask_]);
    if (lo < half) {
      const double hi = std::sqrt(e_hist_[k & e_mask_]);
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
    if (e_hist_[k & e_mask_] > e_hist_[k_peak & e_mask_]) k_peak = k;
  double onset_d = 0.0;
  const std::uint64_t onset = onset_estimate(trigger, k_peak, &onset_d);
  holdoff_end_ = std::max<std::uint64_t>(trigger + holdoff_d_, end);
  startup_ = false;
  lta_frozen_until_ = std::max(lta_frozen_until_, holdoff_end_);
  if (onset_count_ < kMaxOnsets) {
    onsets_[(onset_head_ + onset_count_) % kMaxOnsets] = onset;
    ++onset_count_;
  }
}

double ImpactDetector::band_power(std::uint64_t begin, std::uint64_t end) const {
  // Time average over [begin, end) of e, linearly interpolated between the band samples. Interpolating matters: the in-band floor between
  // impacts often holds the residuals of two lines (a beat in e at their difference frequency, e.g.
  // 440 Hz for 660/1100 Hz lines), which a plain mean of the few band samples in a 2 ms window
  // would sample rather than average. Only band samples after the chain's fill-up are used (before,
  // e is divided by the small fill-up factor g, and a start transient of the rig may still ring).
  begin = std::max(begin, seg_start_);
  if (end < begin + 8) return NAN;
  const std::uint64_t oldest = std::max<std::uint64_t>(band_count_ > e_hist_.size() ? band_count_ - e_hist_.size() : 0,
                                                       fill_.size());
  if (band_count_ < oldest + 2) return NAN;
  // Band sample m is stamped at its block's end minus the FIR's group delay (D - 1), i.e. at
  // seg_start + m D: the time its e describes, like the per-sample e of a filter without the
  // decimation stage.
  const double d = static_cast<double>(dec_);
  const double t0 = static_cast<double>(seg_start_);
  // Interval in band-sample units, clamped to the stored samples [oldest, band_count_ - 1].
  double u0 = (static_cast<double>(begin) - t0) / d;
  double u1 = (static_cast<double>(end) - t0) / d;
  u0 = std::max(u0, static_cast<double>(oldest));
  u1 = std::min(u1, static_cast<double>(band_count_ - 1));
  if (u1 - u0 < 8.0 / d) return NAN;
  auto at = [&](double u) {
    const auto k = static_cast<std::uint64_t>(u);
    const double f = u - static_cast<double>(k);
    const double a = e_hist_[k & e_mask_];
    return f > 0.0 ? a + f * (e_hist_[(k + 1) & e_mask_] - a) : a;
  };
  // Trapezoids: partial first and last intervals, whole ones between.
  const double k0 = std::ceil(u0), k1 = std::floor(u1);
  if (k0 > k1) return 0.5 * (at(u0) + at(u1));
  double area = 0.5 * (at(u0) + at(k0)) * (k0 - u0) + 0.5 * (at(k1) + at(u1)) * (u1 - k1);
  for (auto k = static_cast<std::uint64_t>(k0); k < static_cast<std::uint64_t>(k1); ++k)
    area += 0.5 * (e_hist_[k & e_mask_] + e_hist_[(k + 1) & e_mask_]);
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
