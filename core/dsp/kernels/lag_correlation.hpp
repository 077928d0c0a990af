// Kernel of the envelope estimators' sandwich covariance (core/dsp/damping.cpp): a sum of lag
// autocorrelations of one sequence weighted by a correlation function of the lag.
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// sum_{k=0}^{reach} rho[k] * s_k with s_k = sum_{i=0}^{count-1-k} z[i] z[i+k]. Requires reach < count.
/// Each s_k is summed in two lanes, lane 0 over the even i and lane 1 over the odd i of the pairs
/// (i, i + 1) with i + 1 < count - k, in increasing i; then s_k = lane0 + lane1, plus z[i] z[i+k] for
/// the last i when count - k is odd; the rho[k] s_k are added in increasing k. lag_correlation_sum
/// evaluates four lags per pass in f64x2 lanes (the loads of z[i] shared) with that order per lag,
/// so its result equals lag_correlation_sum_generic's bit for bit.
double lag_correlation_sum(const double* z, std::size_t count, const double* rho, std::size_t reach);
/// Plain scalar reference.
double lag_correlation_sum_generic(const double* z, std::size_t count, const double* rho, std::size_t reach);

}  // namespace ridgewatch::dsp::kernels
