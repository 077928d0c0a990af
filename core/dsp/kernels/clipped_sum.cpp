#include "core/dsp/kernels/clipped_sum.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

bool clipped_sum_any_above(const float* r, std::size_t n, float clip, float above, double& sum) {
  using simd::f32x4;
  using simd::i32x4;
  const f32x4 vclip = simd::splat4(clip), vabove = simd::splat4(above);
  constexpr std::int32_t kNoSign = 0x7fffffff;
  const i32x4 no_sign = {kNoSign, kNoSign, kNoSign, kNoSign};
  f32x4 s = {0, 0, 0, 0};
  i32x4 any = {0, 0, 0, 0};
  std::size_t k = 0;
  for (; k + 4 <= n; k += 4) {
    const f32x4 a = reinterpret_cast<f32x4>(reinterpret_cast<i32x4>(simd::load(r + k)) & no_sign);  // |r|
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

bool clipped_sum_any_above_generic(const float* r, std::size_t n, float clip, float above, double& sum) {
  float lane[4] = {0, 0, 0, 0};
  bool any = false;
  const std::size_t n4 = n / 4 * 4;
  for (std::size_t i = 0; i < n; ++i) {
    const float a = std::abs(r[i]);
    lane[i < n4 ? i % 4 : 0] += std::min(a, clip);
    any = any || a > above;
  }
  sum = static_cast<double>((lane[0] + lane[1]) + (lane[2] + lane[3]));
  return any;
}

}  // namespace ridgewatch::dsp::kernels
