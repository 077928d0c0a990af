// Demodulation of complex FIR outputs by a phasor given as a base times a table entry (the trigger
// band's complex demodulation, impact_detector.hpp stage 2a), in float, per element j < n:
//   p = (br t_re[j] - bi t_im[j]) + i (br t_im[j] + bi t_re[j]),
//   z_re[j] = f_re[j] p_re - f_im[j] p_im,  z_im[j] = f_re[j] p_im + f_im[j] p_re.
#pragma once

#include <cstddef>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

/// Vector version: processes n rounded up to a multiple of 4 (all arrays padded); bit-identical to
/// the reference on the first n.
inline void phasor_rotate(const float* f_re, const float* f_im, const float* t_re, const float* t_im, float br,
                          float bi, std::size_t n, float* z_re, float* z_im) {
  using simd::f32x4;
  const f32x4 vbr = simd::splat4(br), vbi = simd::splat4(bi);
  for (std::size_t v = 0; v < n; v += 4) {
    const f32x4 tr = simd::load(t_re + v), ti = simd::load(t_im + v);
    const f32x4 pr = vbr * tr - vbi * ti, pi = vbr * ti + vbi * tr;
    const f32x4 fr = simd::load(f_re + v), fi = simd::load(f_im + v);
    simd::store(z_re + v, fr * pr - fi * pi);
    simd::store(z_im + v, fr * pi + fi * pr);
  }
}

/// Scalar reference.
inline void phasor_rotate_generic(const float* f_re, const float* f_im, const float* t_re, const float* t_im,
                                  float br, float bi, std::size_t n, float* z_re, float* z_im) {
  for (std::size_t j = 0; j < n; ++j) {
    const float pr = br * t_re[j] - bi * t_im[j], pi = br * t_im[j] + bi * t_re[j];
    const float zr = f_re[j] * pr - f_im[j] * pi, zi = f_re[j] * pi + f_im[j] * pr;
    z_re[j] = zr;
    z_im[j] = zi;
  }
}

}  // namespace ridgewatch::dsp::kernels
