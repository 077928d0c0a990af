// One vector vocabulary for the hot kernels of core/ (GCC/Clang vector extensions).
//
// A vector type holds independent lanes that the compiler maps to one SSE2 register on x86-64 or one
// NEON register on AArch64; arithmetic on it is element-wise with the scalar rounding of each lane, so
// a kernel written on these types gives bit-identical results to its scalar reference as long as it
// performs the same operations in the same order per lane (each kernel's reference in
// core/dsp/kernels/ states that order and tests/test_kernels.cpp checks it).
//
// The *_u types are the same vectors with the alignment of their element type: loads and stores
// through them accept any element-aligned address. They are accesses of the element type for the
// compiler's alias analysis (memcpy would count as a store that may alias anything).
#pragma once

#include <cstdint>

namespace ridgewatch::dsp::simd {

using f32x4 = float __attribute__((vector_size(4 * sizeof(float))));
using f32x4_u = float __attribute__((vector_size(4 * sizeof(float)), aligned(alignof(float))));
using f64x2 = double __attribute__((vector_size(2 * sizeof(double))));
using f64x2_u = double __attribute__((vector_size(2 * sizeof(double)), aligned(alignof(double))));
using f64x4 = double __attribute__((vector_size(4 * sizeof(double))));
using i32x4 = std::int32_t __attribute__((vector_size(4 * sizeof(std::int32_t))));
using u32x4 = std::uint32_t __attribute__((vector_size(4 * sizeof(std::uint32_t))));
using i64x2 = std::int64_t __attribute__((vector_size(2 * sizeof(std::int64_t))));

/// Four floats from p[0..3] (any float-aligned address).
inline f32x4 load(const float* p) { return *reinterpret_cast<const f32x4_u*>(p); }
/// Two doubles from p[0..1] (any double-aligned address).
inline f64x2 load(const double* p) { return *reinterpret_cast<const f64x2_u*>(p); }
/// Stores v to p[0..3].
inline void store(float* p, f32x4 v) { *reinterpret_cast<f32x4_u*>(p) = v; }
/// Stores v to p[0..1].
inline void store(double* p, f64x2 v) { *reinterpret_cast<f64x2_u*>(p) = v; }

/// (v0 + v1) + (v2 + v3): the lane order every four-lane sum in core/ uses when it is reduced.
inline float lanes_sum(f32x4 v) { return (v[0] + v[1]) + (v[2] + v[3]); }
/// v0 + v1.
inline double lanes_sum(f64x2 v) { return v[0] + v[1]; }

/// The vector with every lane equal to x.
inline f32x4 splat4(float x) { return f32x4{x, x, x, x}; }
inline f64x2 splat2(double x) { return f64x2{x, x}; }

}  // namespace ridgewatch::dsp::simd
