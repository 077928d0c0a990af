// A slow, sample-by-sample implementation of the impact detector's documented algorithm
// (core/pipeline/impact_detector.hpp, stages 1-5), written from that description and independently
// of the fast code's block and run structure, vectors, running sums and float arithmetic: every
// quantity is recomputed from its definition, in double, one sample or band sample at a time, on a
// whole record in memory. Only the algorithm's own granularity is kept, as documented: the spike
// stage's scale is updated once per block of whole decimation steps of ~0.4 ms, its winsorisation
// limit is taken once per run of ~1.6 ms, and a band sample sees the scale as of its own block.
// Used by tests/test_reference_detector.cpp.
#pragma once

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdint>
#include <numbers>
#include <vector>

#include "core/pipeline/detector_config.hpp"

namespace ridgewatch::testref {

struct ReferenceResult {
  std::vector<std::uint64_t> onsets;  // sample indices, in order
  std::vector<std::uint64_t> spikes;  // sample indices, in order
};

class ReferenceDetector {
 public:
  ReferenceDetector(const pipeline::ImpactDetectorConfig& c, double fs) : c_(c), fs_(fs) {
    fc_ = 0.5 * (c.band_lo_hz + c.band_hi_hz);
    bw_ = 0.5 * (c.band_hi_hz - c.band_lo_hz);
    D_ = std::clamp<std::size_t>(static_cast<std::size_t>(std::floor(fs / (40.0 * bw_))), 1, 64);
    fs_d_ = fs / static_cast<double>(D_);
    blk_ = D_ * std::max<std::size_t>(1, static_cast<std::size_t>(std::floor(0.0004 * fs / static_cast<double>(D_))));
    run_ = blk_ * std::clamp<std::size_t>(static_cast<std::size_t>(std::floor(0.0016 * fs / static_cast<double>(blk_))), 1, 8);
    sta_ = std::max<std::size_t>(1, static_cast<std::size_t>(std::llround(c.sta_s * fs_d_)));
    lta_d_ = std::max<std::size_t>(sta_ + 1, static_cast<std::size_t>(std::llround(c.lta_s * fs_d_)));
    holdoff_ = static_cast<std::size_t>(std::llround(c.holdoff_s * fs_d_));
    confirm_ = std::max<std::size_t>(sta_, static_cast<std::size_t>(std::llround(4.0 * c.sta_s * fs_d_)));
    pre_ = std::max<std::size_t>(4 * sta_, static_cast<std::size_t>(std::ceil(fs_d_ / bw_)));
    const double lta_in = std::max(2.0, std::round(c.lta_s * fs));
    mad_beta_ = 1.0 - std::pow(1.0 - 1.0 / lta_in, static_cast<double>(blk_));
    // Butterworth 4th order = two RBJ low-pass biquads, Q = 1 / (2 cos(pi/8)), 1 / (2 cos(3 pi/8)).
    lp_[0] = lowpass(bw_, 1.0 / (2.0 * std::cos(std::numbers::pi / 8.0)));
    lp_[1] = lowpass(bw_, 1.0 / (2.0 * std::cos(3.0 * std::numbers::pi / 8.0)));
    fill_up();
    calibrate();
    lag_ = static_cast<std::size_t>(std::llround(peak_ / static_cast<double>(D_)));
    lagw_ = std::max<std::size_t>(sta_, static_cast<std::size_t>(std::ceil(0.002 * fs_d_)));
    const double sigma0 = 0.024 * 2.0 * std::numbers::pi * fc_;
    lag_decay_ = std::exp(-2.0 * sigma0 * (static_cast<double>(lag_) + 0.5 * static_cast<double>(lagw_ - 1)) / fs_d_);
    hold_ = std::max<std::size_t>(2, static_cast<std::size_t>(std::ceil(0.001 * fs_d_)));
    search_back_ = static_cast<std::size_t>(std::ceil((peak_ - t50_) / static_cast<double>(D_))) + sta_ + 1;
    cap_ = search_back_ + static_cast<std::size_t>(std::ceil(peak_ / static_cast<double>(D_))) + hold_;
  }

  double t50_samples() const { return t50_; }
  double peak_samples() const { return peak_; }
  std::size_t decimation() const { return D_; }

  ReferenceResult run(const std::vector<float>& input) {
    ReferenceResult out;
    std::vector<double> x(input.begin(), input.end());
    const std::vector<double> scale = spike_stage(x, out.spikes);  // x cleaned in place
    trigger_stages(x, scale, out.onsets);
    return out;
  }

 private:
  struct Bq {
    double b0, b1, b2, a1, a2;
  };
  Bq lowpass(double f, double q) const {
    const double w0 = 2.0 * std::numbers::pi * f / fs_d_, cw = std::cos(w0), al = std::sin(w0) / (2.0 * q);
    const double a0 = 1.0 + al;
    return {(1.0 - cw) / 2.0 / a0, (1.0 - cw) / a0, (1.0 - cw) / 2.0 / a0, -2.0 * cw / a0, (1.0 - al) / a0};
  }

  // Stage 2 on a whole record: band sample m from the decimation step ending at j = (m + 1) D - 1,
  // z_m = e^{-i w j} sum_k h[k] e^{+i w k} x[j - k] (x = 0 before the record), then the low-pass on
  // I and Q; returns I + iQ per band sample.
  std::vector<std::complex<double>> chain(const std::vector<double>& x) const {
    const double w = 2.0 * std::numbers::pi * fc_ / fs_;
    const double d = static_cast<double>(D_);
    std::vector<std::complex<double>> y;
    double s[2][2][2] = {};  // [I/Q][stage][state]
    for (std::size_t j = D_ - 1; j < x.size(); j += D_) {
      std::complex<double> z = 0.0;
      for (std::size_t k = 0; k + 1 < 2 * D_ && k <= j; ++k) {
        const double h = (d - std::abs(static_cast<double>(k) - (d - 1.0))) / (d * d);
        z += h * x[j - k] * std::polar(1.0, -w * static_cast<double>(j - k));
      }
      double v[2] = {z.real(), z.imag()};
      for (int l = 0; l < 2; ++l)
        for (int st = 0; st < 2; ++st) {
          const Bq& b = lp_[st];
          const double yy = b.b0 * v[l] + s[l][st][0];
          s[l][st][0] = b.b1 * v[l] + s[l][st][1] - b.a1 * yy;
          s[l][st][1] = b.b2 * v[l] - b.a2 * yy;
          v[l] = yy;
        }
      y.emplace_back(v[0], v[1]);
    }
    return y;
  }

  // Fill-up g(m) and white-noise gain: squared impulse responses summed over the D positions.
  void fill_up() {
    const std::size_t n_out = static_cast<std::size_t>(std::ceil(std::max(0.25, 3.0 / bw_) * fs_d_)) + 8;
    std::vector<double> s(n_out, 0.0);
    for (std::size_t p = 0; p < D_; ++p) {
      std::vector<double> x(n_out * D_, 0.0);
      x[p] = 1.0;
      const auto y = chain(x);
      for (std::size_t m = 0; m < n_out; ++m) s[m] += std::norm(y[m]);
    }
    gain_ = 0.0;
    for (double v : s) gain_ += v;
    double acc = 0.0;
    for (std::size_t m = 0; m < n_out; ++m) {
      acc += s[m];
      if (acc / gain_ >= 0.999) break;
      fill_.push_back(std::max(acc / gain_, 1e-3));
    }
    warmup_ = sta_;
    while (warmup_ < fill_.size() && fill_[warmup_] < 0.25) ++warmup_;
  }

  // Stage 5's model: the envelope of a step-started decay (zeta 0.024) at each grid position.
  void calibrate() {
    const double sigma0 = 0.024 * 2.0 * std::numbers::pi * fc_;
    const auto n = static_cast<std::size_t>(std::ceil(0.1 * fs_)) + 2 * D_;
    double sum = 0.0;
    for (std::size_t p = 0; p < D_; ++p) {
      std::vector<double> x(n, 0.0);
      for (std::size_t i = p; i < n; ++i) {
        const double t = static_cast<double>(i - p) / fs_;
        x[i] = std::exp(-sigma0 * t) * std::cos(2.0 * std::numbers::pi * fc_ * t);
      }
      const auto y = chain(x);
      std::size_t mp = 0;
      for (std::size_t m = 0; m < y.size(); ++m)
        if (std::abs(y[m]) > std::abs(y[mp])) mp = m;
      const double half = 0.5 * std::abs(y[mp]);
      double u = 0.0;
      for (std::size_t m = mp; m > 0; --m)
        if (std::abs(y[m - 1]) < half) {
          u = static_cast<double>(m - 1) + (half - std::abs(y[m - 1])) / (std::abs(y[m]) - std::abs(y[m - 1]));
          break;
        }
      const double d = static_cast<double>(D_);
      sum += (u + 1.0) * d - 1.0 - static_cast<double>(p);
      peak_ = std::max(peak_, static_cast<double>(mp + 1) * d - 1.0 - static_cast<double>(p));
    }
    t50_ = sum / static_cast<double>(D_);
  }

  static double residual(const std::vector<double>& x, std::size_t n) {
    return x[n] + (x[n - 2] + x[n + 2]) / 6.0 - (x[n - 1] + x[n + 1]) * (2.0 / 3.0);
  }

  // Stage 1, sample by sample. Returns the scale (winsorised mean |r|) after each block, indexed by
  // block; -1 while it has seen fewer than 32 residuals. A block is tested for spikes when its last
  // sample has 12 samples after it in the record (the decision delay) and the scale is warm.
  std::vector<double> spike_stage(std::vector<double>& x, std::vector<std::uint64_t>& spikes) const {
    const std::size_t N = x.size();
    auto r_at = [&](std::size_t n) { return n >= 2 && n + 2 < N ? residual(x, n) : 0.0; };
    double mad = 0.0, clip = 0.0;
    std::uint64_t count = 0;
    bool clip_fixed = false;
    std::vector<double> scale;
    for (std::size_t b = 0; b < N; b += blk_) {
      const std::size_t len = std::min(blk_, N - b) / D_ * D_;  // the last block: whole steps only
      if (len == 0) break;
      if (b % run_ == 0) {  // a run starts: the winsorisation limit as of now, once warm
        clip_fixed = count >= 32;
        clip = 3.0 * mad + 1e-30;
      }
      const bool whole = len == blk_ && b + blk_ + 12 <= N;
      if (whole && count >= 32) {
        const double t = c_.spike_mad * std::max(0.6745 / 0.7979 * mad, 1e-9);
        for (std::size_t n = std::max<std::size_t>(b, 2); n < b + len; ++n) {
          const double rr = r_at(n);
          const double nb = std::max({std::abs(x[n - 1]), std::abs(x[n + 1]), std::abs(x[n - 2]), std::abs(x[n + 2])});
          const double limit = std::max(t, 0.25 * nb);
          if (!(std::abs(rr) > limit)) continue;
          double around = 0.0;  // largest residual at n-10..n-3 and n+3..n+10 (within the record)
          for (std::size_t k = (n >= 12 ? n - 10 : 2); k + 3 <= n; ++k) around = std::max(around, std::abs(r_at(k)));
          for (std::size_t k = n + 3; k <= n + 10; ++k) around = std::max(around, std::abs(r_at(k)));
          if (!(std::abs(rr) > 3.0 * around)) continue;
          const double saved = x[n];
          x[n] -= rr;  // the interpolation; the neighbours must then be normal
          bool isolated = true;
          for (std::size_t k : {n - 2, n - 1, n + 1, n + 2}) isolated = isolated && std::abs(r_at(k)) <= limit;
          if (isolated) {
            spikes.push_back(n);
          } else {
            x[n] = saved;
          }
        }
      }
      // The scale update with the block's residuals (after spike removal; the first two samples of
      // the record have none).
      const double lim = clip_fixed ? clip : 3.0 * mad + 1e-30;
      if (count < 32) {
        for (std::size_t n = std::max<std::size_t>(b, 2); n < b + len; ++n) {
          const double a = std::abs(r_at(n));
          if (count < 32) {
            ++count;
            mad += (a - mad) / static_cast<double>(count);
          } else {
            mad += mad_beta_ / static_cast<double>(blk_) * (std::min(a, 3.0 * mad + 1e-30) - mad);
          }
        }
      } else {
        double s = 0.0;
        for (std::size_t n = b; n < b + len; ++n) s += std::min(std::abs(r_at(n)), lim);
        mad += mad_beta_ * static_cast<double>(len) / static_cast<double>(blk_) * (s / static_cast<double>(len) - mad);
      }
      scale.push_back(count >= 32 ? mad : -1.0);
    }
    return scale;
  }

  double white_power(double mad) const {
    const double sd_r = mad / 0.7979;
    return sd_r * sd_r / (1.0 + 34.0 / 36.0) * gain_;
  }

  // Stages 3-5, band sample by band sample, every window mean recomputed from the stored energies.
  void trigger_stages(const std::vector<double>& x, const std::vector<double>& scale, std::vector<std::uint64_t>& onsets) const {
    const auto y = chain(x);
    std::vector<double> e(y.size());
    auto mean = [&](std::size_t lo, std::size_t hi) {  // mean of e[lo, hi)
      double s = 0.0;
      for (std::size_t k = lo; k < hi; ++k) s += e[k];
      return hi > lo ? s / static_cast<double>(hi - lo) : 0.0;
    };
    double lta = 0.0;
    std::uint64_t lta_n = 0;
    bool raised = false, startup = true, confirming = false;
    std::size_t holdoff_end = 0, frozen_until = 0, trigger = 0, peak_at = 0, peak_since = 0, seen = 0;
    double ref = 0.0, confirm_sum = 0.0;
    auto onset_of = [&](std::size_t k_peak) {
      const double half = 0.5 * std::sqrt(e[k_peak]);
      const std::size_t floor_k = trigger > search_back_ ? trigger - search_back_ : 0;
      double crossing = static_cast<double>(floor_k);
      for (std::size_t k = k_peak; k > floor_k; --k) {
        const double lo = std::sqrt(e[k - 1]), hi = std::sqrt(e[k]);
        if (lo < half) {
          crossing = static_cast<double>(k - 1) + (hi > lo ? (half - lo) / (hi - lo) : 0.0);
          break;
        }
      }
      return std::max((crossing + 1.0) * static_cast<double>(D_) - 1.0 - t50_, 0.0);
    };
    auto emit = [&](std::size_t end) {
      std::size_t k_peak = trigger;
      for (std::size_t k = trigger; k < end; ++k)
        if (e[k] > e[k_peak]) k_peak = k;
      onsets.push_back(static_cast<std::uint64_t>(std::llround(onset_of(k_peak))));
      holdoff_end = std::max(trigger + holdoff_, end);
      startup = false;
      frozen_until = std::max(frozen_until, holdoff_end);
      confirming = false;
    };
    for (std::size_t m = 0; m < y.size(); ++m) {
      const double mad = scale[m * D_ / blk_];
      e[m] = std::norm(y[m]) / (m < fill_.size() ? fill_[m] : 1.0);
      // LTA (stage 3): raised once to the white-noise band power at the end of the warm-up.
      if (!raised && m + 1 >= warmup_ && mad >= 0.0) {
        lta = std::max(lta, 0.857 * white_power(mad));
        raised = true;
      }
      if (m >= frozen_until) {
        ++lta_n;
        const double cap = lta_n <= sta_ ? e[m] : std::min(e[m], 3.0 * lta);
        lta += (cap - lta) / static_cast<double>(std::min<std::uint64_t>(lta_n, lta_d_));
      }
      if (m + 1 < warmup_) continue;
      const double sta = mean(m + 1 - sta_, m + 1);
      if (confirming) {
        ++seen;
        if (seen <= confirm_) confirm_sum += e[m];
        if (e[m] > e[peak_at]) peak_at = peak_since = m;
        if (seen < confirm_) continue;
        if (seen == confirm_ && !(confirm_sum / static_cast<double>(confirm_) > c_.trigger_ratio * ref)) {
          confirming = false;  // rejected: re-armed at once
          holdoff_end = frozen_until = m + 1;
          continue;
        }
        const double end_index = static_cast<double>(std::llround(static_cast<double>(m + 1) * static_cast<double>(D_) - 1.0));
        if (m - peak_since >= hold_ || m - trigger >= cap_ || end_index >= onset_of(peak_at) + peak_ + 0.001 * fs_) emit(m + 1);
        continue;
      }
      if (m < holdoff_end) continue;
      const std::size_t sta_lo = m + 1 - std::min(m + 1, sta_);
      const double pre = mean(sta_lo - std::min(sta_lo, pre_), sta_lo);
      double rise = pre;
      if (startup && m >= warmup_ + lag_ + lagw_ - 1)
        rise = std::min(pre, std::max(mean(m - lag_ - lagw_ + 1, m - lag_ + 1) * lag_decay_, white_power(mad)));
      if (startup && m >= warmup_ + lta_d_) startup = false;
      const double r = std::max({lta / 0.857, rise, 1e-30});
      if (sta > c_.trigger_ratio * r) {
        confirming = true;
        trigger = peak_at = peak_since = m;
        ref = r;
        confirm_sum = 0.0;
        seen = 0;
        frozen_until = m + std::max(holdoff_, confirm_) + 1;
      }
    }
    if (confirming) {  // the record ended during the confirmation or settling: judged on what was seen,
      // and emitted only when the maximum is final by the same rule as above (else it is truncated)
      const std::size_t n = std::min(seen, confirm_);
      const std::size_t m = y.size() - 1;
      const double end_index = static_cast<double>(std::llround(static_cast<double>(m + 1) * static_cast<double>(D_) - 1.0));
      const bool final = m - peak_since >= hold_ || m - trigger >= cap_ || end_index >= onset_of(peak_at) + peak_ + 0.001 * fs_;
      if (n > 0 && confirm_sum / static_cast<double>(n) > c_.trigger_ratio * ref && final) emit(y.size());
    }
  }

  pipeline::ImpactDetectorConfig c_;
  double fs_, fc_ = 0, bw_ = 0, fs_d_ = 0, mad_beta_ = 0, gain_ = 0, t50_ = 0, peak_ = 0, lag_decay_ = 1;
  std::size_t D_ = 1, blk_ = 1, run_ = 1, sta_ = 1, lta_d_ = 2, holdoff_ = 0, confirm_ = 1, pre_ = 1, warmup_ = 1;
  std::size_t lag_ = 1, lagw_ = 1, hold_ = 2, search_back_ = 1, cap_ = 1;
  Bq lp_[2]{};
  std::vector<double> fill_;
};

}  // namespace ridgewatch::testref
