// Complex FIR on real samples, evaluated at count windows step samples apart (the trigger band's
// anti-alias FIR with decimation, impact_detector.hpp stage 2a):
//   re[j] = sum_k g_re[k] x[j step + k],  im[j] = sum_k g_im[k] x[j step + k],  k < n_taps,
// n_taps a multiple of 4 (taps zero-padded). Float products and sums. Summation order (the reference):
// four partial sums, lane l holding the terms k = l (mod 4) in increasing k, combined as
// (l0 + l1) + (l2 + l3).
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// Vector version: the taps stay in registers (up to 24 taps; longer FIRs take a plain vector loop);
/// four windows at a time, their lane sums by a transposition. Bit-identical to fir_steps_generic.
void fir_steps(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
               std::size_t n_taps, float* re, float* im);
/// Scalar reference, the order stated above.
void fir_steps_generic(const float* x, std::size_t step, std::size_t count, const float* g_re, const float* g_im,
                       std::size_t n_taps, float* re, float* im);

}  // namespace ridgewatch::dsp::kernels
