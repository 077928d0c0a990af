#include "core/dsp/kernels/lag_correlation.hpp"

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

double lag_correlation_sum(const double* z, std::size_t count, const double* rho, std::size_t reach) {
  using simd::f64x2;
  double sum = 0;
  std::size_t k = 0;
  // Four lags per pass: four independent chains, the loads of z_i shared.
  for (; k + 4 <= reach + 1; k += 4) {
    const std::size_t len = count - k;  // points of lag k; lag k + j has len - j
    f64x2 acc[4] = {{0, 0}, {0, 0}, {0, 0}, {0, 0}};
    std::size_t i = 0;
    for (; i + 5 <= len; i += 2) {  // i + 2 <= len - 3: every lag has the pair
      const f64x2 zi = simd::load(z + i);
      for (std::size_t j = 0; j < 4; ++j) acc[j] += zi * simd::load(z + k + j + i);
    }
    for (std::size_t j = 0; j < 4; ++j) {  // each lag's last pair, its odd last point, into the sum
      std::size_t ij = i;
      for (; ij + 2 <= len - j; ij += 2) acc[j] += simd::load(z + ij) * simd::load(z + k + j + ij);
      double sj = simd::lanes_sum(acc[j]);
      if (ij < len - j) sj += z[ij] * z[ij + k + j];
      sum += rho[k + j] * sj;
    }
  }
  for (; k <= reach; ++k) {
    const std::size_t len = count - k;
    f64x2 a = {0, 0};
    std::size_t i = 0;
    for (; i + 2 <= len; i += 2) a += simd::load(z + i) * simd::load(z + k + i);
    double sk = simd::lanes_sum(a);
    if (i < len) sk += z[i] * z[i + k];
    sum += rho[k] * sk;
  }
  return sum;
}

double lag_correlation_sum_generic(const double* z, std::size_t count, const double* rho, std::size_t reach) {
  double sum = 0;
  for (std::size_t k = 0; k <= reach; ++k) {
    const std::size_t len = count - k;
    double even = 0, odd = 0;
    std::size_t i = 0;
    for (; i + 2 <= len; i += 2) {
      even += z[i] * z[i + k];
      odd += z[i + 1] * z[i + 1 + k];
    }
    double sk = even + odd;
    if (i < len) sk += z[i] * z[i + k];
    sum += rho[k] * sk;
  }
  return sum;
}

}  // namespace ridgewatch::dsp::kernels
