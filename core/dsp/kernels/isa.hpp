// Run-time choice of the instruction set for the hot kernels of core/dsp/kernels/.
//
// The release builds target generic x86-64 (SSE2). A kernel that has a faster form for AVX2 compiles
// the same vector code (simd.hpp) twice: as is, and in a function marked RIDGEWATCH_TARGET_AVX2, and
// calls the second only when use_avx2() is true. Both forms perform the same operations in the same
// order per lane; AVX2 changes the encoding (three-operand VEX instructions: no register copies) and
// lets the compiler use 256-bit registers, never the rounding: no fused multiply-add is enabled (FMA is
// a separate target feature), so the results are bit-identical to the kernel's scalar reference
// (tests/test_kernels_*.cpp run both forms against it).
#pragma once

namespace ridgewatch::dsp::kernels {

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define RIDGEWATCH_HAVE_AVX2_KERNELS 1
#define RIDGEWATCH_TARGET_AVX2 [[gnu::target("avx2")]]
#else
#define RIDGEWATCH_HAVE_AVX2_KERNELS 0
#define RIDGEWATCH_TARGET_AVX2
#endif

/// True when the kernels take their AVX2 forms: the CPU has AVX2 (checked once) and
/// limit_kernels_to_baseline(true) has not been called.
bool use_avx2();

/// Tests and comparisons: true makes every kernel take its baseline (SSE2) form on any CPU, false
/// restores the choice by the CPU. Not meant to be switched while kernels run on other threads.
void limit_kernels_to_baseline(bool on);

}  // namespace ridgewatch::dsp::kernels
