// Order statistic of a short array without data-dependent branches in the partition loop.
//
// The impact analyzer takes the median of each CWT row's power (14 rows of ~64 columns per impact).
// std::nth_element's partition branches on every comparison, and on such rows (a noise floor, a
// decaying ridge) the branches are unpredictable (docs/performance.md, "select"). Here each pass
// writes every element to both ends of a second buffer and advances one end by the comparison result
// (three-way: below, equal to and above the pivot), so the loop has no branch but its own.
//
// select_kth_nonnegative (the analyzer's row medians: powers, >= 0) first tests the pivot's rank in
// one branch-free pass that partitions nothing (kernels::pivot_counts): it counts the values below
// and at or below the pivot and finds the nearest values on either side of it. On the rig's rows the
// median is the pivot or its neighbour in rank (rw60.wav, 21000 rows: the pivot 59 %, the next value
// above it 28 %, the next below it 1.4 %), so most rows need no partition pass at all (timings in
// docs/performance.md, "select").
#pragma once

#include <algorithm>
#include <cstddef>

#include "core/dsp/kernels/pivot_counts.hpp"

namespace ridgewatch::dsp {

/// The k-th smallest (0-based) of v[0..n): the value std::nth_element(v, v + k, v + n) leaves at v[k].
/// Requires 0 <= k < n and NaN-free values; v and tmp (n elements each) are overwritten.
/// Pivot: median of the elements at n/4, n/2, 3n/4 (a monotone run, such as a decaying envelope,
/// then splits at its middle). Worst case O(n^2) comparisons, deterministic.
inline double select_kth(double* v, double* tmp, std::size_t n, std::size_t k) {
  while (n > 8) {
    const double a = v[n / 4], b = v[n / 2], c = v[3 * n / 4];
    const double pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));
    // tmp[0, lo): below the pivot, tmp(hi, n): above it; the slots in between are the equal ones
    // (their contents are stale copies). At least one element (the pivot) is equal, so lo <= hi.
    std::size_t lo = 0, hi = n - 1;
    for (std::size_t i = 0; i < n; ++i) {
      const double x = v[i];
      tmp[lo] = x;
      tmp[hi] = x;
      lo += static_cast<std::size_t>(x < pivot);
      hi -= static_cast<std::size_t>(x > pivot);
    }
    if (k >= lo && k <= hi) return pivot;
    double* const data = tmp;
    tmp = v;
    if (k < lo) {
      v = data;
      n = lo;
    } else {
      v = data + hi + 1;
      k -= hi + 1;
      n -= hi + 1;
    }
  }
  // Insertion sort of the last few.
  for (std::size_t i = 1; i < n; ++i) {
    const double x = v[i];
    std::size_t j = i;
    for (; j > 0 && v[j - 1] > x; --j) v[j] = v[j - 1];
    v[j] = x;
  }
  return v[k];
}

/// The k-th smallest (0-based) of v[0..n), the value select_kth returns, for values >= 0 (NaN-free);
/// v is not modified, tmp (2n elements) is scratch. Requires 0 <= k < n.
/// One pass with the pivot of select_kth: below = #(x < pivot), at_or_below = #(x <= pivot), and the
/// largest value below and the smallest above it. k in [below, at_or_below): the pivot; k = below - 1:
/// the largest below; k = at_or_below: the smallest above (whatever their multiplicities). Otherwise
/// the side that holds the k-th is copied out (one pass) and select_kth finishes on it.
[[gnu::always_inline]] inline double select_kth_nonnegative(const double* v, double* tmp, std::size_t n, std::size_t k) {
  const double a = v[n / 4], b = v[n / 2], c = v[3 * n / 4];
  const double pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));
  const kernels::PivotCounts counts = kernels::pivot_counts(v, n, pivot);
  const std::size_t below = counts.below, at_or_below = counts.at_or_below;
  if (k < below) {
    if (k + 1 == below) return counts.below_max;
  } else if (k < at_or_below) {
    return pivot;
  } else if (k == at_or_below) {
    return counts.above_min;
  }
  // The side holding the k-th, copied out as in select_kth's partition (one store per value).
  std::size_t m = 0;
  if (k < below) {
    for (std::size_t j = 0; j < n; ++j) {
      tmp[m] = v[j];
      m += static_cast<std::size_t>(v[j] < pivot);
    }
  } else {
    for (std::size_t j = 0; j < n; ++j) {
      tmp[m] = v[j];
      m += static_cast<std::size_t>(v[j] > pivot);
    }
    k -= at_or_below;
  }
  return select_kth(tmp, tmp + n, m, k);
}

}  // namespace ridgewatch::dsp
