// Order statistic of a short array without data-dependent branches in the partition loop.
//
// The impact analyzer takes the median of each CWT row's power (14 rows of ~64 columns per impact).
// std::nth_element's partition branches on every comparison, and on such rows (a noise floor, a
// decaying ridge) the branches are unpredictable: it was 1.6 us of a 16 us analysis. Here each pass
// writes every element to both ends of a second buffer and advances one end by the comparison result
// (three-way: below, equal to and above the pivot), so the loop has no branch but its own.
#pragma once

#include <algorithm>
#include <cstddef>
#include <utility>

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

}  // namespace ridgewatch::dsp
