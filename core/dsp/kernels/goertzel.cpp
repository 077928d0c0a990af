#include "core/dsp/kernels/goertzel.hpp"

#include <cstring>
#include <stdexcept>

#include "core/dsp/kernels/isa.hpp"
#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

namespace {

using simd::f64x2;
using simd::f64x4;
constexpr std::size_t kPhases = kGoertzelPhases;

// V with the alignment of double (loads from any double-aligned address, as simd.hpp's *_u types).
using f64x4_u = double __attribute__((vector_size(4 * sizeof(double)), aligned(alignof(double))));
template <typename V>
struct Unaligned;
template <>
struct Unaligned<f64x2> {
  using type = simd::f64x2_u;
};
template <>
struct Unaligned<f64x4> {
  using type = f64x4_u;
};

// kPhases recursions per bin in vector lanes V (f64x2: 4 chains per bin and step; f64x4 with AVX2: 2
// chains of four lanes). Steps go in pairs with the roles of the two state arrays swapped (the new
// value overwrites s[m-2]), so that no register copies s[m-1] to s[m-2]: the loop is bound by the issue
// of its vector operations, not by the latency of one step. B = 2: the sample loads shared by two bins
// (B = 3 spills its state with f64x2).
template <typename V, std::size_t B>
[[gnu::always_inline]] inline void recursions(const double* x, std::size_t m_full, const double* tail,
                                              const double* coef, double* out) {
  constexpr std::size_t kLanes = sizeof(V) / sizeof(double), kVecs = kPhases / kLanes;
  V c[B], sa[B][kVecs], sb[B][kVecs];
  for (std::size_t b = 0; b < B; ++b) {
    c[b] = V{} + coef[b];
    for (std::size_t q = 0; q < kVecs; ++q) sa[b][q] = sb[b][q] = V{};
  }
  // s2 <- x - s2 + c s1: s2 then holds the newest value.
  auto step = [&](const double* xm, const V (*s1)[kVecs], V (*s2)[kVecs]) {
    for (std::size_t q = 0; q < kVecs; ++q) {
      const V xv = *reinterpret_cast<const typename Unaligned<V>::type*>(xm + kLanes * q);
      for (std::size_t b = 0; b < B; ++b) s2[b][q] = (xv - s2[b][q]) + c[b] * s1[b][q];
    }
  };
  std::size_t m = 0;
  for (; m + 1 < m_full; m += 2) {
    step(x + kPhases * m, sa, sb);
    step(x + kPhases * (m + 1), sb, sa);
  }
  bool newest_in_b = false;  // after an odd number of steps the newest values are in sb
  if (m < m_full) {
    step(x + kPhases * m, sa, sb);
    newest_in_b = true;
  }
  if (tail) {
    if (newest_in_b)
      step(tail, sb, sa);
    else
      step(tail, sa, sb);
    newest_in_b = !newest_in_b;
  }
  for (std::size_t b = 0; b < B; ++b) {
    std::memcpy(out + 2 * kPhases * b, newest_in_b ? sb[b] : sa[b], sizeof sa[b]);
    std::memcpy(out + 2 * kPhases * b + kPhases, newest_in_b ? sa[b] : sb[b], sizeof sa[b]);
  }
}

void recursions_baseline(const double* x, std::size_t m_full, const double* tail, const double* coef, std::size_t bins,
                         double* out) {
  if (bins == 2) return recursions<f64x2, 2>(x, m_full, tail, coef, out);
  recursions<f64x2, 1>(x, m_full, tail, coef, out);
}

// Four lanes per vector and three-operand encodings (no copy of s2 before the subtraction).
RIDGEWATCH_TARGET_AVX2 void recursions_avx2(const double* x, std::size_t m_full, const double* tail, const double* coef,
                                            std::size_t bins, double* out) {
  if (bins == 2) return recursions<f64x4, 2>(x, m_full, tail, coef, out);
  recursions<f64x4, 1>(x, m_full, tail, coef, out);
}

}  // namespace

void goertzel_recursions(const double* x, std::size_t m_full, const double* tail, const double* coef, std::size_t bins,
                         double* out) {
  if (bins != 1 && bins != 2) throw std::invalid_argument("goertzel_recursions: bins must be 1 or 2");
  if (use_avx2()) return recursions_avx2(x, m_full, tail, coef, bins, out);
  recursions_baseline(x, m_full, tail, coef, bins, out);
}

void goertzel_recursions_generic(const double* x, std::size_t m_full, const double* tail, const double* coef,
                                 std::size_t bins, double* out) {
  if (bins != 1 && bins != 2) throw std::invalid_argument("goertzel_recursions_generic: bins must be 1 or 2");
  for (std::size_t b = 0; b < bins; ++b) {
    for (std::size_t j = 0; j < kPhases; ++j) {
      double s1 = 0.0, s2 = 0.0;  // s[m-1], s[m-2]
      auto step = [&](double xm) {
        const double s = (xm - s2) + coef[b] * s1;
        s2 = s1;
        s1 = s;
      };
      for (std::size_t m = 0; m < m_full; ++m) step(x[kPhases * m + j]);
      if (tail) step(tail[j]);
      out[2 * kPhases * b + j] = s1;
      out[2 * kPhases * b + kPhases + j] = s2;
    }
  }
}

}  // namespace ridgewatch::dsp::kernels
