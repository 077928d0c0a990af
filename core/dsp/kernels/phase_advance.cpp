#include "core/dsp/kernels/phase_advance.hpp"

#include <cmath>
#include <type_traits>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

namespace {

template <typename T>
T splat(double x) {
  if constexpr (std::is_same_v<T, simd::f64x2>) return simd::splat2(x);
  else return x;
}

// atan t for |t| <= 1/8: t sum_j (-t^2)^j / (2j + 1), j <= 9, Horner in t^2, on a double or lane by
// lane on an f64x2 (the same operations, so the same bits).
template <typename T>
T atan_series(T t) {
  const T s = t * t;
  T p = splat<T>(1.0 / 19.0);
  p = splat<T>(1.0 / 17.0) - s * p;
  p = splat<T>(1.0 / 15.0) - s * p;
  p = splat<T>(1.0 / 13.0) - s * p;
  p = splat<T>(1.0 / 11.0) - s * p;
  p = splat<T>(1.0 / 9.0) - s * p;
  p = splat<T>(1.0 / 7.0) - s * p;
  p = splat<T>(1.0 / 5.0) - s * p;
  p = splat<T>(1.0 / 3.0) - s * p;
  p = splat<T>(1.0) - s * p;
  return t * p;
}

// The advances of columns i and i + 1 (w points at w_i) into d[0] and d[1].
void advances_pair(const std::complex<double>* w, std::complex<double> derotate, double advance, double* d) {
  using simd::f64x2;
  const f64x2 a = {w[0].real(), w[1].real()}, b = {w[0].imag(), w[1].imag()};
  const f64x2 c = {w[-1].real(), w[0].real()}, nd = {-w[-1].imag(), -w[0].imag()};  // conj(w_{i-1})
  const f64x2 re1 = a * c - b * nd, im1 = a * nd + b * c;
  const f64x2 dr = simd::splat2(derotate.real()), di = simd::splat2(derotate.imag());
  const f64x2 re = re1 * dr - im1 * di, im = re1 * di + im1 * dr;
  // phase_angle's test re > 0 && |im| <= re / 8, false for NaN like it.
  const f64x2 q = simd::splat2(0.125) * re;
  const auto in_range = (re > simd::splat2(0.0)) & (im <= q) & (-im <= q);
  if (in_range[0] && in_range[1]) {
    simd::store(d, atan_series(im / re) + simd::splat2(advance));
    return;
  }
  for (std::size_t j = 0; j < 2; ++j)
    d[j] = phase_angle(w[j] * std::conj(w[static_cast<std::ptrdiff_t>(j) - 1]) * derotate) + advance;
}

}  // namespace

double phase_angle(std::complex<double> z) {
  const double re = z.real(), im = z.imag();
  if (re > 0.0 && std::abs(im) <= 0.125 * re) return atan_series(im / re);
  return std::arg(z);
}

void phase_advances(const std::complex<double>* w, std::size_t count, std::complex<double> derotate,
                    double advance, double* d) {
  std::size_t i = 1;
  for (; i + 2 <= count; i += 2) advances_pair(w + i, derotate, advance, d + i);
  if (i < count) d[i] = phase_angle(w[i] * std::conj(w[i - 1]) * derotate) + advance;
}

void phase_advances_generic(const std::complex<double>* w, std::size_t count, std::complex<double> derotate,
                            double advance, double* d) {
  for (std::size_t i = 1; i < count; ++i) d[i] = phase_angle(w[i] * std::conj(w[i - 1]) * derotate) + advance;
}

}  // namespace ridgewatch::dsp::kernels
