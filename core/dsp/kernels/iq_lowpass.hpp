// A 4th-order low-pass (two transposed-direct-form-II biquads) run on I and Q at once, one lane each
// of a two-double vector (the trigger band's low-pass, impact_detector.hpp stage 2b). Per lane and
// stage, with input x and states s1, s2 (Biquad::step's order):
//   y = b0 x + s1;  s1 = (b1 x + s2) - a1 y;  s2 = b2 x - a2 y.
// The vector version takes low-pass numerators (1, 2, 1) b0 (a bilinear-transform low-pass) and forms
// b0 x once: b1 x = b0 x + b0 x and b2 x = b0 x are then exact (binary scaling commutes with rounding),
// one product instead of three; bit-identical to the reference with b1 = 2 b0 and b2 = b0.
#pragma once

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

/// Coefficients of one biquad stage (a0 = 1).
struct BiquadCoefs {
  double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0;
};

/// States of both stages, lane 0 = I, lane 1 = Q.
struct IqLowPass4State {
  simd::f64x2 s1_1{0.0, 0.0}, s2_1{0.0, 0.0}, s1_2{0.0, 0.0}, s2_2{0.0, 0.0};
};

/// The stages' coefficients splatted to both lanes (b1, b2 implied: see above).
struct IqLowPass4Coefs {
  simd::f64x2 b0_1, a1_1, a2_1, b0_2, a1_2, a2_2;
  IqLowPass4Coefs(const BiquadCoefs& c1, const BiquadCoefs& c2)
      : b0_1(simd::splat2(c1.b0)), a1_1(simd::splat2(c1.a1)), a2_1(simd::splat2(c1.a2)),
        b0_2(simd::splat2(c2.b0)), a1_2(simd::splat2(c2.a1)), a2_2(simd::splat2(c2.a2)) {}
};

/// One step on z = {I, Q}; returns the output {I, Q}.
inline simd::f64x2 iq_lowpass4_step(const IqLowPass4Coefs& c, IqLowPass4State& s, simd::f64x2 z) {
  const simd::f64x2 bz_1 = c.b0_1 * z;
  const simd::f64x2 y1 = bz_1 + s.s1_1;
  s.s1_1 = ((bz_1 + bz_1) + s.s2_1) - c.a1_1 * y1;
  s.s2_1 = bz_1 - c.a2_1 * y1;
  const simd::f64x2 bz_2 = c.b0_2 * y1;
  const simd::f64x2 y = bz_2 + s.s1_2;
  s.s1_2 = ((bz_2 + bz_2) + s.s2_2) - c.a1_2 * y;
  s.s2_2 = bz_2 - c.a2_2 * y;
  return y;
}

/// Scalar reference: each lane through the two stages with the full numerator.
inline simd::f64x2 iq_lowpass4_step_generic(const BiquadCoefs& c1, const BiquadCoefs& c2, IqLowPass4State& s,
                                            simd::f64x2 z) {
  simd::f64x2 out{0.0, 0.0};
  for (int l = 0; l < 2; ++l) {
    const double x = z[l];
    const double y1 = c1.b0 * x + s.s1_1[l];
    s.s1_1[l] = (c1.b1 * x + s.s2_1[l]) - c1.a1 * y1;
    s.s2_1[l] = c1.b2 * x - c1.a2 * y1;
    const double y = c2.b0 * y1 + s.s1_2[l];
    s.s1_2[l] = (c2.b1 * y1 + s.s2_2[l]) - c2.a1 * y;
    s.s2_2[l] = c2.b2 * y1 - c2.a2 * y;
    out[l] = y;
  }
  return out;
}

}  // namespace ridgewatch::dsp::kernels
