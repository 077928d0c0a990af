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
// one-value-per-step reference. The fast form is defined here, inline, so that it inlines into the
// caller's per-row code as the loop it replaced did.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "core/dsp/kernels/simd.hpp"

namespace ridgewatch::dsp::kernels {

struct PivotCounts {
  std::size_t below = 0;        ///< values < pivot
  std::size_t at_or_below = 0;  ///< values <= pivot
  double below_max = 0.0;       ///< largest value < pivot; +0 when none
  double above_min = 0.0;       ///< smallest value > pivot; +infinity when none
};

// One value into the running result (the reference's step and the fast form's odd tail): the same selects as the vector lanes (for values >= 0 the
// conditional updates below equal those of x & (x < pivot) and max(x, inf & (x <= pivot)) in the
// lanes). A maximum is replaced only by a strictly larger value, so a -0 never replaces the initial +0.
inline void pivot_counts_one(PivotCounts& c, double x, double pivot) {
  c.below += static_cast<std::size_t>(x < pivot);
  c.at_or_below += static_cast<std::size_t>(x <= pivot);
  if (x < pivot) c.below_max = x > c.below_max ? x : c.below_max;
  if (x > pivot) c.above_min = x < c.above_min ? x : c.above_min;
}

[[gnu::always_inline]] inline PivotCounts pivot_counts(const double* v, std::size_t n, double pivot) {
  using simd::f64x2;
  using simd::i64x2;
  const double inf = std::numeric_limits<double>::infinity();
  const f64x2 piv = simd::splat2(pivot), infs = simd::splat2(inf);
  // Two sets of lanes (independent max / min chains). The comparison masks are -1 where true, so the
  // counts are subtracted. Non-negative values make the masking cheap: x & (x < pivot) is x or +0,
  // which never exceeds the largest value below the pivot when there is one; max(x, inf & (x <= pivot))
  // is x above the pivot and inf otherwise.
  i64x2 below2[2] = {{0, 0}, {0, 0}}, at2[2] = {{0, 0}, {0, 0}};
  f64x2 lo2[2] = {simd::splat2(0.0), simd::splat2(0.0)}, hi2[2] = {infs, infs};
  auto step = [&](const double* src, std::size_t j) {
    const f64x2 x = simd::load(src);
    const i64x2 lt = x < piv, le = x <= piv;
    below2[j] -= lt;
    at2[j] -= le;
    const f64x2 lo_x = std::bit_cast<f64x2>(std::bit_cast<i64x2>(x) & lt);
    const f64x2 inf_le = std::bit_cast<f64x2>(std::bit_cast<i64x2>(infs) & le);
    const f64x2 hi_x = x > inf_le ? x : inf_le;
    lo2[j] = lo_x > lo2[j] ? lo_x : lo2[j];
    hi2[j] = hi2[j] < hi_x ? hi2[j] : hi_x;
  };
  std::size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    step(v + i, 0);
    step(v + i + 2, 1);
  }
  if (i + 2 <= n) {
    step(v + i, 0);
    i += 2;
  }
  const i64x2 below_sum = below2[0] + below2[1], at_sum = at2[0] + at2[1];
  PivotCounts c;
  c.below = static_cast<std::size_t>(below_sum[0] + below_sum[1]);
  c.at_or_below = static_cast<std::size_t>(at_sum[0] + at_sum[1]);
  const f64x2 lo = lo2[0] > lo2[1] ? lo2[0] : lo2[1], hi = hi2[0] < hi2[1] ? hi2[0] : hi2[1];
  c.below_max = lo[0] > lo[1] ? lo[0] : lo[1];
  c.above_min = hi[0] < hi[1] ? hi[0] : hi[1];
  if (i < n) pivot_counts_one(c, v[i], pivot);
  return c;
}

PivotCounts pivot_counts_generic(const double* v, std::size_t n, double pivot);

}  // namespace ridgewatch::dsp::kernels
