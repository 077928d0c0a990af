// Stage 1 of the impact detector (impact_detector.hpp): isolated spikes found by their cubic
// interpolation residual against a robust running scale, replaced by the interpolation. Blocks of a
// run are decided one after the other (each block's scale update is seen by the next).
#include <algorithm>
#include <cmath>

#include "core/dsp/kernels/clipped_sum.hpp"
#include "core/dsp/kernels/spike_residual.hpp"
#include "core/pipeline/impact_detector.hpp"

namespace ridgewatch::pipeline {

namespace {
constexpr double kSixth = 1.0 / 6.0;
// The interpolation residual in float as x[n] + (x[n-2] + x[n+2]) / 6 - (x[n-1] + x[n+1]) 2/3 (as the
// kernel spike_residual_blocks).
constexpr float kSixthF = 1.0f / 6.0f, kTwoThirdsF = 2.0f / 3.0f;
}  // namespace

void ImpactDetector::start_run_scale() {
  run_clip_ = static_cast<float>(3.0 * mad_sum_ + 1e-30);
  run_clip_ready_ = mad_count_ >= kMadWarmup;
}

void ImpactDetector::note_scale(std::size_t k) {
  scale_at_[k] = mad_sum_;
  scale_ready_[k] = mad_count_ >= kMadWarmup;
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
    // (Not bounded by base_: it wraps below 0 for a segment starting before index hist_, and the
    // buffer always holds hist_ >= 12 samples before the run's first sample anyway.)
    const std::uint64_t lo = std::max<std::uint64_t>(n > 10 ? n - 10 : 0, seg_start_ + 2);
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
    if (!dsp::kernels::clipped_sum_any_above(r + first, d - first, clip, static_cast<float>(t_mad), s)) {
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
    dsp::kernels::clipped_sum_any_above(r + first, d - first, clip, 3e38f, s);
    mad_sum_ += mad_beta_ * static_cast<double>(d - first) * inv_blk_ * (s / static_cast<double>(d - first) - mad_sum_);
  }
}

void ImpactDetector::decide_blocks(std::uint64_t b, std::size_t count) {
  // count whole blocks from b whose spike delay has passed, one after the other; the scale after each
  // is kept for the band samples in it. A block with a warm scale, not at the segment start, first
  // takes the fast path: its residuals, their clipped sum (the sums of clipped_sum_any_above(), bit for
  // bit) and maximum in one pass (kernel spike_residual_blocks), which keeps r[0], r[1] (from the
  // previous block, possibly corrected by its spike test) and also writes up to five residuals past
  // the block from samples not yet pushed, which the next block recomputes before anything reads them
  // (the buffer has room). A block whose maximum exceeds the spike limit is decided again by
  // decide_block() (the same residuals, then the isolation test).
  const std::size_t d = blk_;
  std::size_t k0 = 0;  // blocks before k0 are decided
  std::array<float, kMaxRunBlocks> sums{}, tops{};
  auto t_mad = [&] { return static_cast<float>(spike_k_ * std::max(0.6745 / 0.7979 * mad_sum_, 1e-9)); };
  if (d % 4 == 0 && count > 1 && mad_count_ >= kMadWarmup && b != seg_start_) {
    // Blocks of whole vectors with a warm scale (and so one winsorisation limit for the run): the
    // residuals, clipped sums and maxima of all count blocks in one pass, then the blocks' pre-tests
    // and scale updates in order. The first block with a candidate is decided by decide_block(), which
    // may correct r[0], r[1] of the next one: the blocks after it take the per-block path.
    dsp::kernels::spike_residual_blocks(buf_x_.data() + (b - base_), buf_r_.data() + (b - base_), d, count,
                                        block_clip(), sums.data(), tops.data());
    for (; k0 < count; ++k0) {
      if (tops[k0] > t_mad()) {
        decide_block(b + k0 * d, d, d, true);
        note_scale(k0);
        ++k0;
        break;
      }
      mad_sum_ += mad_beta_ * (static_cast<double>(sums[k0]) * inv_blk_ - mad_sum_);  // as in decide_block()
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
    const float above = t_mad();
    dsp::kernels::spike_residual_blocks(buf_x_.data() + (bk - base_), buf_r_.data() + (bk - base_), d, 1,
                                        block_clip(), sums.data(), tops.data());
    if (tops[0] > above) {
      decide_block(bk, d, d, true);
    } else {
      mad_sum_ += mad_beta_ * (static_cast<double>(sums[0]) * inv_blk_ - mad_sum_);  // as in decide_block()
    }
    note_scale(k);
  }
}

}  // namespace ridgewatch::pipeline
