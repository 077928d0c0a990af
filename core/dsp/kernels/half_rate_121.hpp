// Half-rate (1, 2, 1)/4 copy of a signal's interior, with the largest |x| of the samples it reads.
//
// For outputs m in [m0, m1) (m0 >= 1, so every tap is in range):
//
//     y[m] = 0.25 * (x[2m-1] + x[2m+1]) + 0.5 * x[2m]      (every tap widened to double first, exactly)
//     yf[m] = (float) y[m]                                  (only when yf is not null)
//
// in this order of operations in every implementation, so the results are bit-identical; the kernel
// reads x[2 m0 - 1 .. 2 m1 - 1]. It also returns max |x[k]| over k in [2 m0, 2 m1) (the centre and
// right taps of each output: each sample exactly once over consecutive calls), 0 when m0 >= m1; a NaN
// sample never counts as the largest (every comparison with it is false). The maximum of floats is
// computed in float and widened, which is exact, so it equals the double one for the same values.
//
// Used by dsp::decimate_half_121 (core/dsp/morlet_cwt.hpp) for the half-rate input of the impact
// analyzer's wavelet transform; that function adds the edge outputs (x taken as zero outside the record).
//
// half_rate_121 is the fast form (float input: four outputs per step in simd.hpp vector lanes, the
// maximum in eight lanes; double input: four outputs per step, eight independent maxima);
// half_rate_121_generic is the plain one-output-per-step reference it must equal bit for bit
// (tests/test_kernels_dsp.cpp).
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

double half_rate_121(const float* x, double* y, float* yf, std::size_t m0, std::size_t m1);
double half_rate_121(const double* x, double* y, float* yf, std::size_t m0, std::size_t m1);

double half_rate_121_generic(const float* x, double* y, float* yf, std::size_t m0, std::size_t m1);
double half_rate_121_generic(const double* x, double* y, float* yf, std::size_t m0, std::size_t m1);

}  // namespace ridgewatch::dsp::kernels
