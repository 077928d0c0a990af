// Kernel of the ML fit's model (core/dsp/ml_fit.cpp): one damped mode's term in one DFT bin and its
// Jacobian entries. Header-only: it runs once per mode and bin inside the fit's innermost loop, where a
// call per bin would cost more than the arithmetic.
//
// The segment model of ml_fit.hpp, X_k = sum_j [C_j G(z_j, k) + conj(C_j) G(conj z_j, k)] / 2 with
//   G(z, k) = (1 - z^N) / d,  d = 1 - z w_k,  w_k = e^{-2 pi i k / N},
//   G'(z)   = (-N z^(N-1) d + (1 - z^N) w_k) / d^2 = (G w_k - N z^(N-1)) / d,
// so each mode costs two complex reciprocals per bin. mode_bin puts the z term and the conj(z) term
// side by side in the two lanes of f64x2 values (Split): lane 0 holds what the scalar complex
// arithmetic of mode_bin_generic computes for the z term, lane 1 the same for the conj(z) term, by the
// same operations in the same order (conjugating an operand negates its imaginary part exactly, and
// x - y rounds as x + (-y)), so every value equals mode_bin_generic's bit for bit
// (tests/test_kernels_analyzer.cpp), at half the instructions and divisions.
#pragma once

#include <complex>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

using cd = std::complex<double>;

// Complex product and reciprocal without the C99 Annex G special cases of operator* and operator/
// (a NaN test and possible call to __muldc3 per product, an unconditional call to __divdc3 per
// quotient). The operands here are finite and the denominators are 1 - z e^{-i theta} with |z| < 1,
// never zero.
inline cd mul(cd a, cd b) {
  return {a.real() * b.real() - a.imag() * b.imag(), a.real() * b.imag() + a.imag() * b.real()};
}
inline cd inv(cd b) { return std::conj(b) / std::norm(b); }

/// Two complex numbers in lanes: (re[0], im[0]) and (re[1], im[1]).
struct Split {
  simd::f64x2 re, im;
};
inline Split smul(const Split& a, const Split& b) {  // mul() per lane
  return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re};
}
inline Split with_conj(cd a) { return {simd::f64x2{a.real(), a.real()}, simd::f64x2{a.imag(), -a.imag()}}; }  // (a, conj a)
inline Split both(cd a) { return {simd::splat2(a.real()), simd::splat2(a.imag())}; }  // (a, a)
inline cd half_sum(const Split& a) {  // 0.5 * (lane 0 + lane 1)
  return {0.5 * (a.re[0] + a.re[1]), 0.5 * (a.im[0] + a.im[1])};
}
/// Stores the complex number (v[0], v[1]) with one 16-byte store: a later 16-byte load of it is
/// forwarded from the store (two 8-byte stores cannot forward to one 16-byte load, a stall of ~15
/// cycles in the normal equations' accumulation).
inline void store_complex(cd* to, simd::f64x2 v) { simd::store(reinterpret_cast<double*>(to), v); }
inline void store_half_sum(cd* to, const Split& a) {  // half_sum(a) into *to
  store_complex(to, simd::splat2(0.5) * (simd::f64x2{a.re[0], a.im[0]} + simd::f64x2{a.re[1], a.im[1]}));
}

/// A mode's terms for one model evaluation: z = exp((-sigma + i omega) / fs), 1 - z^N, z^(N-1), the
/// amplitude C and C dz/df, C dz/d ln zeta, and the (a, conj a) lane pairs of z, 1 - z^N, C,
/// N z^(N-1), C dz/df, C dz/du that mode_bin reads.
struct ModeBinState {
  cd z, one_minus_zn, zn1, c, c_dz_df, c_dz_du;
  Split z2, one_minus_zn2, c2, n_zn1_2, c_dz_df2, c_dz_du2;
};

/// Mode m's term of X_model_k (wk = both(w_k)), and when col != nullptr its four Jacobian entries
/// (complex: d/df, d/d ln zeta, d/d Re C, d/d Im C) into col[0..3].
inline cd mode_bin(const ModeBinState& m, const Split& wk, cd* col) {
  using simd::f64x2;
  // inv = conj(d) / |d|^2, d = 1 - z w_k (real part 1 - re, which rounds as (-re) + 1)
  const Split zw = smul(m.z2, wk);
  const f64x2 d_re = simd::splat2(1.0) - zw.re, d_im = -zw.im;
  const f64x2 nrm = d_re * d_re + d_im * d_im;
  const Split inv12{d_re / nrm, -d_im / nrm};
  const Split g12 = smul(m.one_minus_zn2, inv12);
  const cd out = half_sum(smul(m.c2, g12));  // 0.5 (C g1 + conj(C) g2)
  if (!col) return out;
  const Split gw = smul(g12, wk);
  const Split gp12 = smul({gw.re - m.n_zn1_2.re, gw.im - m.n_zn1_2.im}, inv12);  // (g w_k - N z^(N-1)) / d
  store_half_sum(col, smul(m.c_dz_df2, gp12));
  store_half_sum(col + 1, smul(m.c_dz_du2, gp12));
  store_half_sum(col + 2, g12);
  const f64x2 diff = f64x2{g12.re[0], g12.im[0]} - f64x2{g12.re[1], g12.im[1]};  // g1 - g2
  store_complex(col + 3, f64x2{-0.5, 0.5} * f64x2{diff[1], diff[0]});             // i (g1 - g2) / 2
  return out;
}

/// Plain scalar reference: the same in scalar complex arithmetic, one term at a time (reads the
/// scalar members only; n_samples = N).
inline cd mode_bin_generic(const ModeBinState& m, cd wk, double n_samples, cd* col) {
  const cd inv1 = inv(1.0 - mul(m.z, wk));
  const cd inv2 = inv(1.0 - mul(std::conj(m.z), wk));
  const cd g1 = mul(m.one_minus_zn, inv1);
  const cd g2 = mul(std::conj(m.one_minus_zn), inv2);
  const cd out = 0.5 * (mul(m.c, g1) + mul(std::conj(m.c), g2));
  if (!col) return out;
  const cd gp1 = mul(mul(g1, wk) - n_samples * m.zn1, inv1);
  const cd gp2 = mul(mul(g2, wk) - n_samples * std::conj(m.zn1), inv2);
  col[0] = 0.5 * (mul(m.c_dz_df, gp1) + mul(std::conj(m.c_dz_df), gp2));
  col[1] = 0.5 * (mul(m.c_dz_du, gp1) + mul(std::conj(m.c_dz_du), gp2));
  col[2] = 0.5 * (g1 + g2);
  const cd diff = g1 - g2;
  col[3] = cd(-0.5 * diff.imag(), 0.5 * diff.real());  // i (g1 - g2) / 2
  return out;
}

/// The lane pairs of m from its scalar members (n_samples = N).
inline void fill_lanes(ModeBinState& m, double n_samples) {
  m.z2 = with_conj(m.z);
  m.one_minus_zn2 = with_conj(m.one_minus_zn);
  m.n_zn1_2 = with_conj(n_samples * m.zn1);  // n_samples * conj(zn1) = conj(n_samples * zn1) exactly
  m.c2 = with_conj(m.c);
  m.c_dz_df2 = with_conj(m.c_dz_df);
  m.c_dz_du2 = with_conj(m.c_dz_du);
}

}  // namespace ridgewatch::dsp::kernels
