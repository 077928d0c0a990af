#include "core/dsp/kernels/half_rate_121.hpp"

#include <bit>
#include <cmath>
#include <cstdint>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

namespace {

using simd::f32x4;
using simd::f64x2;
using simd::f64x4;
using simd::u32x4;

// One output from its three taps x[k-1], x[k], x[k+1], widened to double (the operations every form
// of the kernel performs, in this order).
template <typename In>
double taps_121(const In* x, std::size_t k) {
  const double a = static_cast<double>(x[k - 1]), b = static_cast<double>(x[k]), c = static_cast<double>(x[k + 1]);
  return 0.25 * (a + c) + 0.5 * b;
}

// The larger of m and v, keeping m when v is NaN.
template <typename T>
T max_keep(T m, T v) {
  return v > m ? v : m;
}

// The outputs m .. m1-1 one at a time (the tail after the four-wide steps), folding max |x| of their
// samples into peak; Peak is the input's own type, so float input keeps a float maximum.
template <bool kFloat, typename In, typename Peak>
Peak scalar_tail(const In* x, double* y, float* yf, std::size_t m, std::size_t m1, Peak peak) {
  for (; m < m1; ++m) {
    const double v = taps_121(x, 2 * m);
    y[m] = v;
    if constexpr (kFloat) yf[m] = static_cast<float>(v);
    peak = max_keep(peak, std::abs(x[2 * m]));
    peak = max_keep(peak, std::abs(x[2 * m + 1]));
  }
  return peak;
}

// Double input: four outputs per step written out in scalars, the maximum in eight independent lanes
// (one lane would be a serial chain of compare-selects, two per output).
template <bool kFloat>
[[gnu::noinline]] double interior_f64(const double* __restrict x, double* __restrict y, float* __restrict yf,
                                      std::size_t m0, std::size_t m1) {
  double pk[8] = {};
  std::size_t m = m0;
  for (; m + 4 <= m1; m += 4) {
    for (int j = 0; j < 4; ++j) {
      const std::size_t k = 2 * (m + static_cast<std::size_t>(j));
      const double a = x[k - 1], b = x[k], c = x[k + 1];
      const double v = 0.25 * (a + c) + 0.5 * b;
      y[m + static_cast<std::size_t>(j)] = v;
      if constexpr (kFloat) yf[m + static_cast<std::size_t>(j)] = static_cast<float>(v);
      pk[2 * j] = max_keep(pk[2 * j], std::abs(b));
      pk[2 * j + 1] = max_keep(pk[2 * j + 1], std::abs(c));
    }
  }
  double peak = 0.0;
  for (double p : pk) peak = max_keep(peak, p);
  return scalar_tail<kFloat>(x, y, yf, m, m1, peak);
}

// Float input: four outputs per step in vector lanes. x[2m .. 2m+7] in two loads, widened to double
// four samples at a time (__builtin_convertvector to f64x4; GCC 12 turns a two-float conversion into a
// scalar conversion per sample), split into the even samples (centre taps) and the odd ones (right
// taps); the left taps are the odd ones shifted by one output (lane 1 of odd_prev: the previous step's
// last odd sample). The same two loads feed max |x| (|x| by clearing the sign bit, exact) in two sets
// of four float lanes.
template <bool kFloat>
[[gnu::noinline]] double interior_f32(const float* __restrict x, double* __restrict y, float* __restrict yf,
                                      std::size_t m0, std::size_t m1) {
  const u32x4 abs_mask = {0x7FFFFFFFU, 0x7FFFFFFFU, 0x7FFFFFFFU, 0x7FFFFFFFU};
  const f64x2 quarter = simd::splat2(0.25), half = simd::splat2(0.5);
  f32x4 pk0 = simd::splat4(0.0f), pk1 = pk0;
  std::size_t m = m0;
  f64x2 odd_prev = {0.0, m + 4 <= m1 ? static_cast<double>(x[2 * m - 1]) : 0.0};  // lane 1: x[2m - 1]
  for (; m + 4 <= m1; m += 4) {
    const f32x4 lo = simd::load(x + 2 * m);      // x[2m .. 2m+3]
    const f32x4 hi = simd::load(x + 2 * m + 4);  // x[2m+4 .. 2m+7]
    const f32x4 alo = std::bit_cast<f32x4>(std::bit_cast<u32x4>(lo) & abs_mask);
    const f32x4 ahi = std::bit_cast<f32x4>(std::bit_cast<u32x4>(hi) & abs_mask);
    pk0 = alo > pk0 ? alo : pk0;
    pk1 = ahi > pk1 ? ahi : pk1;
    const f64x4 dlo = __builtin_convertvector(lo, f64x4), dhi = __builtin_convertvector(hi, f64x4);
    const f64x2 even01 = __builtin_shufflevector(dlo, dlo, 0, 2), odd01 = __builtin_shufflevector(dlo, dlo, 1, 3);
    const f64x2 even23 = __builtin_shufflevector(dhi, dhi, 0, 2), odd23 = __builtin_shufflevector(dhi, dhi, 1, 3);
    const f64x2 left01 = __builtin_shufflevector(odd_prev, odd01, 1, 2);  // x[2m-1], x[2m+1]
    const f64x2 left23 = __builtin_shufflevector(odd01, odd23, 1, 2);     // x[2m+3], x[2m+5]
    odd_prev = odd23;
    const f64x2 v01 = quarter * (left01 + odd01) + half * even01;
    const f64x2 v23 = quarter * (left23 + odd23) + half * even23;
    simd::store(y + m, v01);
    simd::store(y + m + 2, v23);
    if constexpr (kFloat) {
      const f64x4 v = __builtin_shufflevector(v01, v23, 0, 1, 2, 3);
      simd::store(yf + m, __builtin_convertvector(v, f32x4));
    }
  }
  pk0 = pk1 > pk0 ? pk1 : pk0;
  const float peak = max_keep(max_keep(pk0[0], pk0[1]), max_keep(pk0[2], pk0[3]));
  return static_cast<double>(scalar_tail<kFloat>(x, y, yf, m, m1, peak));
}

template <typename In>
double generic(const In* x, double* y, float* yf, std::size_t m0, std::size_t m1) {
  double peak = 0.0;
  for (std::size_t m = m0; m < m1; ++m) {
    const double v = taps_121(x, 2 * m);
    y[m] = v;
    if (yf) yf[m] = static_cast<float>(v);
    peak = max_keep(peak, std::abs(static_cast<double>(x[2 * m])));
    peak = max_keep(peak, std::abs(static_cast<double>(x[2 * m + 1])));
  }
  return peak;
}

}  // namespace

double half_rate_121(const float* x, double* y, float* yf, std::size_t m0, std::size_t m1) {
  return yf ? interior_f32<true>(x, y, yf, m0, m1) : interior_f32<false>(x, y, nullptr, m0, m1);
}
double half_rate_121(const double* x, double* y, float* yf, std::size_t m0, std::size_t m1) {
  return yf ? interior_f64<true>(x, y, yf, m0, m1) : interior_f64<false>(x, y, nullptr, m0, m1);
}

double half_rate_121_generic(const float* x, double* y, float* yf, std::size_t m0, std::size_t m1) {
  return generic(x, y, yf, m0, m1);
}
double half_rate_121_generic(const double* x, double* y, float* yf, std::size_t m0, std::size_t m1) {
  return generic(x, y, yf, m0, m1);
}

}  // namespace ridgewatch::dsp::kernels
