// Rank of a pivot in an array of non-negative values, in one pass that moves nothing: the counts of
// the values below and at or below the pivot, and the nearest values on either side of it.
//
// For v[0..n) with every value >= 0 and no NaN (squared magnitudes, powers):
//     below       = #{i : v[i] < pivot}
//     at_or_below = #{i : v[i] <= pivot}
//     below_max   = the largest v[i] < pivot, or +0 when there is none
//     above_min   = the smallest v[i] > pivot, or +infinity when there is none
// Counts are exact and a maximum or minimum is one of the inputs, so every form of the kernel gives
// the same result (tests/test_kernels_dsp.cpp checks it bit for bit).
//
// Used by dsp::select_kth_nonnegative (core/dsp/select.hpp): when the wanted rank k falls in
// [below, at_or_below) the answer is the pivot, at below - 1 it is below_max, at at_or_below it is
// above_min, and only otherwise is a partition pass needed.
//
// pivot_counts is the fast form (simd.hpp f64x2 pairs in two independent sets of lanes, the counts
// accumulated from the comparison masks, no data-dependent branch); pivot_counts_generic is the plain
// one-value-per-step reference.
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

struct PivotCounts {
  std::size_t below = 0;        ///< values < pivot
  std::size_t at_or_below = 0;  ///< values <= pivot
  double below_max = 0.0;       ///< largest value < pivot; +0 when none
  double above_min = 0.0;       ///< smallest value > pivot; +infinity when none
};

PivotCounts pivot_counts(const double* v, std::size_t n, double pivot);
PivotCounts pivot_counts_generic(const double* v, std::size_t n, double pivot);

}  // namespace ridgewatch::dsp::kernels
