#include "core/dsp/kernels/spike_residual.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "core/dsp/kernels/clipped_sum.hpp"
#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

namespace {
constexpr float kSixthF = 1.0f / 6.0f, kTwoThirdsF = 2.0f / 3.0f;
// The vector form, inlined into its baseline and AVX2 instances (isa.hpp).
[[gnu::always_inline]] inline void residual_blocks(const float* x, float* r, std::size_t len, std::size_t count,
                                                   float clip, float* sums, float* tops) {
  using simd::f32x4;
  using simd::i32x4;
  using simd::load;
  const f32x4 sixth = simd::splat4(kSixthF), two_thirds = simd::splat4(kTwoThirdsF), vclip = simd::splat4(clip);
  constexpr std::int32_t kNoSign = 0x7fffffff;
  const i32x4 no_sign = {kNoSign, kNoSign, kNoSign, kNoSign};
  auto residuals = [&](std::size_t v) {
    const float* xv = x + 4 * v;
    return (load(xv) + (load(xv - 2) + load(xv + 2)) * sixth) - (load(xv - 1) + load(xv + 1)) * two_thirds;
  };
  const std::size_t nv = len / 4;  // whole vectors per block
  f32x4 rv = residuals(0);
  rv[0] = r[0];
  rv[1] = r[1];
  std::size_t v = 0;  // the vector in rv
  for (std::size_t k = 0; k < count; ++k) {
    f32x4 sum = {0, 0, 0, 0}, top = {0, 0, 0, 0};
    for (std::size_t u = 0; u < nv; ++u) {
      if (v > 0) rv = residuals(v);
      simd::store(r + 4 * v, rv);
      ++v;
      const f32x4 a = reinterpret_cast<f32x4>(reinterpret_cast<i32x4>(rv) & no_sign);  // |r|
      sum += vclip < a ? vclip : a;                                                  // std::min(a, clip)
      top = top < a ? a : top;                                                       // std::max(top, a)
    }
    sums[k] = sum[0];
    tops[k] = std::max(std::max(top[0], top[1]), std::max(top[2], top[3]));
    if (k + 1 == count) {
      // The vectors past the last whole one: the rest of the block (len mod 4, count == 1) and the
      // residuals after it.
      const std::size_t n_vec = (count * len + 5) / 4;
      for (; v < n_vec; ++v) {
        rv = v > 0 ? residuals(v) : rv;
        simd::store(r + 4 * v, rv);
      }
      for (std::size_t i = k * len + 4 * nv; i < (k + 1) * len; ++i) {
        const float a = std::abs(r[i]);
        sums[k] += std::min(a, clip);
        tops[k] = tops[k] < a ? a : tops[k];
      }
    }
    sums[k] = (sums[k] + sum[1]) + (sum[2] + sum[3]);
  }
}

void residual_blocks_baseline(const float* x, float* r, std::size_t len, std::size_t count, float clip, float* sums,
                              float* tops) {
  residual_blocks(x, r, len, count, clip, sums, tops);
}

RIDGEWATCH_TARGET_AVX2 void residual_blocks_avx2(const float* x, float* r, std::size_t len, std::size_t count,
                                                 float clip, float* sums, float* tops) {
  residual_blocks(x, r, len, count, clip, sums, tops);
}

}  // namespace

void spike_residual_blocks(const float* x, float* r, std::size_t len, std::size_t count, float clip, float* sums,
                           float* tops) {
  if (use_avx2()) return residual_blocks_avx2(x, r, len, count, clip, sums, tops);
  residual_blocks_baseline(x, r, len, count, clip, sums, tops);
}

void spike_residual_blocks_generic(const float* x, float* r, std::size_t len, std::size_t count, float clip,
                                   float* sums, float* tops) {
  const std::size_t end = 4 * ((count * len + 5) / 4);
  for (std::size_t i = 2; i < end; ++i)
    r[i] = (x[i] + (x[i - 2] + x[i + 2]) * kSixthF) - (x[i - 1] + x[i + 1]) * kTwoThirdsF;
  for (std::size_t k = 0; k < count; ++k) {
    double s = 0.0;
    clipped_sum_any_above_generic(r + k * len, len, clip, 0.0f, s);
    sums[k] = static_cast<float>(s);  // exact: the sum is a float widened
    float t = 0.0f;
    for (std::size_t i = k * len; i < (k + 1) * len; ++i) {
      const float a = std::abs(r[i]);
      t = t < a ? a : t;
    }
    tops[k] = t;
  }
}

}  // namespace ridgewatch::dsp::kernels
