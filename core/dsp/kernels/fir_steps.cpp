#include "core/dsp/kernels/fir_steps.hpp"

#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

namespace {

using simd::f32x4;
using simd::load;
using simd::store;

// {lanes_sum(a[0]), ..., lanes_sum(a[3])} with the same additions in the same order: pairs of lanes of
// two vectors summed in one addition, then the pairs of pairs. (__builtin_shufflevector: GCC >= 12 and
// Clang, which the libFuzzer build uses.)
[[gnu::always_inline]] inline f32x4 lanes_sum4(const f32x4 (&a)[4]) {
  const f32x4 p = __builtin_shufflevector(a[0], a[1], 0, 2, 4, 6) + __builtin_shufflevector(a[0], a[1], 1, 3, 5, 7);
  const f32x4 q = __builtin_shufflevector(a[2], a[3], 0, 2, 4, 6) + __builtin_shufflevector(a[2], a[3], 1, 3, 5, 7);
  return __builtin_shufflevector(p, q, 0, 2, 4, 6) + __builtin_shufflevector(p, q, 1, 3, 5, 7);
}

// NV tap vectors held in registers. Inlined into both forms of fir_steps (isa.hpp).
template <std::size_t NV>
[[gnu::always_inline]] inline void fir_steps_nv(const float* x, std::size_t step, std::size_t count, const float* g_re,
                                                const float* g_im, float* re, float* im) {
  f32x4 gr[NV], gi[NV];
  for (std::size_t v = 0; v < NV; ++v) {
    gr[v] = load(g_re + 4 * v);
    gi[v] = load(g_im + 4 * v);
  }
  std::size_t j = 0;
  for (; j + 4 <= count; j += 4, x += 4 * step) {
    f32x4 a_re[4], a_im[4];
    for (std::size_t u = 0; u < 4; ++u) {
      a_re[u] = f32x4{0, 0, 0, 0};
      a_im[u] = f32x4{0, 0, 0, 0};
      for (std::size_t v = 0; v < NV; ++v) {
        const f32x4 xv = load(x + u * step + 4 * v);
        a_re[u] += gr[v] * xv;
        a_im[u] += gi[v] * xv;
      }
    }
    store(re + j, lanes_sum4(a_re));
    store(im + j, lanes_sum4(a_im));
  }
  for (; j < count; ++j, x += step) {
    f32x4 a_re = {0, 0, 0, 0}, a_im = {0, 0, 0, 0};
    for (std::size_t v = 0; v < NV; ++v) {
      const f32x4 xv = load(x + 4 * v);
      a_re += gr[v] * xv;
      a_im += gi[v] * xv;
    }
    re[j] = simd::lanes_sum(a_re);
    im[j] = simd::lanes_sum(a_im);
  }
}

[[gnu::always_inline]] inline void fir_steps_vector(const float* x, std::size_t step, std::size_t count,
                                                    const float* g_re, const float* g_im, std::size_t n_taps, float* re,
                                                    float* im) {
  switch (n_taps / 4) {
    case 1: return fir_steps_nv<1>(x, step, count, g_re, g_im, re, im);
    case 2: return fir_steps_nv<2>(x, step, count, g_re, g_im, re, im);
    case 3: return fir_steps_nv<3>(x, step, count, g_re, g_im, re, im);
    case 4: return fir_steps_nv<4>(x, step, count, g_re, g_im, re, im);
    case 5: return fir_steps_nv<5>(x, step, count, g_re, g_im, re, im);
    case 6: return fir_steps_nv<6>(x, step, count, g_re, g_im, re, im);
    default:
      for (std::size_t j = 0; j < count; ++j, x += step) {
        f32x4 a_re = {0, 0, 0, 0}, a_im = {0, 0, 0, 0};
        for (std::size_t k = 0; k < n_taps; k += 4) {
          const f32x4 xv = load(x + k);
          a_re += load(g_re + k) * xv;
          a_im += load(g_im + k) * xv;
        }
        re[j] = simd::lanes_sum(a_re);
        im[j] = simd::lanes_sum(a_im);
      }
  }
}

void fir_steps_baseline(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
                        std::size_t n_taps, float* re, float* im) {
  fir_steps_vector(x, step, count, g_re, g_im, n_taps, re, im);
}

RIDGEWATCH_TARGET_AVX2 void fir_steps_avx2(const float* x, std::size_t step, std::size_t count, const float* g_re,
                                           const float* g_im, std::size_t n_taps, float* re, float* im) {
  fir_steps_vector(x, step, count, g_re, g_im, n_taps, re, im);
}

}  // namespace

void fir_steps(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
               std::size_t n_taps, float* re, float* im) {
  if (use_avx2()) return fir_steps_avx2(x, step, count, g_re, g_im, n_taps, re, im);
  fir_steps_baseline(x, step, count, g_re, g_im, n_taps, re, im);
}

void fir_steps_generic(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
                       std::size_t n_taps, float* re, float* im) {
  for (std::size_t j = 0; j < count; ++j, x += step) {
    float lr[4] = {0, 0, 0, 0}, li[4] = {0, 0, 0, 0};
    for (std::size_t k = 0; k < n_taps; ++k) {
      const float p_re = g_re[k] * x[k], p_im = g_im[k] * x[k];
      lr[k % 4] += p_re;
      li[k % 4] += p_im;
    }
    re[j] = (lr[0] + lr[1]) + (lr[2] + lr[3]);
    im[j] = (li[0] + li[1]) + (li[2] + li[3]);
  }
}

}  // namespace ridgewatch::dsp::kernels
