#include "core/dsp/kernels/subtract_and_max.hpp"

#include <algorithm>
#include <limits>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

double subtract_and_max(double* p, std::size_t cols, double med, std::size_t c_begin, std::size_t c_end) {
  using simd::f64x2;
  std::size_t c = 0;
  for (; c < c_begin; ++c) p[c] -= med;
  const f64x2 m2 = simd::splat2(med);
  const double inf = std::numeric_limits<double>::infinity();
  f64x2 mx0 = simd::splat2(-inf), mx1 = mx0;
  for (; c + 4 <= c_end; c += 4) {
    const f64x2 a = simd::load(p + c) - m2, b = simd::load(p + c + 2) - m2;
    simd::store(p + c, a);
    simd::store(p + c + 2, b);
    mx0 = a > mx0 ? a : mx0;
    mx1 = b > mx1 ? b : mx1;
  }
  double mx = std::max(std::max(mx0[0], mx0[1]), std::max(mx1[0], mx1[1]));
  for (; c < c_end; ++c) {
    p[c] -= med;
    mx = std::max(mx, p[c]);
  }
  for (; c < cols; ++c) p[c] -= med;
  return mx;
}

double subtract_and_max_generic(double* p, std::size_t cols, double med, std::size_t c_begin, std::size_t c_end) {
  double mx = -std::numeric_limits<double>::infinity();
  for (std::size_t c = 0; c < cols; ++c) {
    p[c] -= med;
    if (c >= c_begin && c < c_end) mx = std::max(mx, p[c]);
  }
  return mx;
}

}  // namespace ridgewatch::dsp::kernels
