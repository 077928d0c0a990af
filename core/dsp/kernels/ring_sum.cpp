#include "core/dsp/kernels/ring_sum.hpp"

#include <algorithm>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

double ring_sum(const double* ring, std::uint64_t mask, std::uint64_t lo, std::uint64_t hi) {
  using simd::f64x2;
  f64x2 a = {0.0, 0.0}, c = {0.0, 0.0};  // {p0, p1}, {p2, p3}
  for (std::uint64_t i = lo; i < hi;) {
    const std::uint64_t p = i & mask;
    const std::uint64_t n = std::min(hi - i, mask + 1 - p);  // contiguous up to the ring's end
    const double* q = ring + p;
    std::uint64_t k = 0;
    for (; k + 4 <= n; k += 4) {
      a += simd::load(q + k);
      c += simd::load(q + k + 2);
    }
    for (; k < n; ++k) a[0] += q[k];
    i += n;
  }
  return simd::lanes_sum(a + c);
}

double ring_sum_generic(const double* ring, std::uint64_t mask, std::uint64_t lo, std::uint64_t hi) {
  double p[4] = {0.0, 0.0, 0.0, 0.0};
  for (std::uint64_t i = lo; i < hi;) {
    const std::uint64_t start = i & mask;
    const std::uint64_t n = std::min(hi - i, mask + 1 - start);
    for (std::uint64_t k = 0; k < n; ++k) p[k < n / 4 * 4 ? k % 4 : 0] += ring[start + k];
    i += n;
  }
  return (p[0] + p[2]) + (p[1] + p[3]);
}

}  // namespace ridgewatch::dsp::kernels
