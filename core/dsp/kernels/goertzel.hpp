// The Goertzel recursions of the ML fit's DFT bins (core/dsp/ml_fit.cpp, goertzel_bins): for each of
// `bins` coefficients c_b (1 or 2) and each of the kGoertzelPhases phases j, over the rows m < M of the
// samples laid out as x[kGoertzelPhases m + j]:
//
//     s[m] = (x[P m + j] - s[m-2]) + c_b s[m-1],   s[-1] = s[-2] = 0      (in this order of operations)
//
// x holds m_full complete rows; `tail` (nullptr for none) one more row, zero-padded, so M = m_full + 1
// with a tail, m_full without. Writes, for bin b, s[M-1] of the P phases to out[2 P b .. 2 P b + P)
// and s[M-2] to out[2 P b + P .. 2 P (b + 1)).
//
// goertzel_recursions is the fast form (two bins per pass sharing the sample loads, the phases in
// simd.hpp vector lanes; an AVX2 form chosen at run time, isa.hpp); goertzel_recursions_generic the
// plain one-phase-at-a-time reference it must equal bit for bit (tests/test_kernels_dsp.cpp).
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// Phases P of the polyphase recursion (independent chains per bin).
inline constexpr std::size_t kGoertzelPhases = 8;

void goertzel_recursions(const double* x, std::size_t m_full, const double* tail, const double* coef, std::size_t bins,
                         double* out);
void goertzel_recursions_generic(const double* x, std::size_t m_full, const double* tail, const double* coef,
                                 std::size_t bins, double* out);

}  // namespace ridgewatch::dsp::kernels
