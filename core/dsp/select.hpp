// Order statistic of a short array without data-dependent branches in the partition loop.
//
// The impact analyzer takes the median of each CWT row's power (14 rows of ~64 columns per impact).
// std::nth_element's partition branches on every comparison, and on such rows (a noise floor, a
// decaying ridge) the branches are unpredictable: it was 1.6 us of a 16 us analysis. Here each pass
// writes every element to both ends of a second buffer and advances one end by the comparison result
// (three-way: below, equal to and above the pivot), so the loop has no branch but its own.
//
// select_kth_nonnegative (the analyzer's row medians: powers, >= 0) first tests the pivot's rank in
// one branch-free pass of SSE2 pairs that partitions nothing: it counts the values below and at or
// below the pivot and finds the nearest values on either side of it. On the rig's rows the median is
// the pivot or its neighbour in rank (rw60.wav, 21000 rows: the pivot 59 %, the next value above it
// 28 %, the next below it 1.4 %), so most rows need no partition pass at all. Measured on 1400 of those rows
// (64 values, k = 32, in cache): select_kth 99 ns per row, this 48 ns.
#pragma once

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>
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

/// The k-th smallest (0-based) of v[0..n), the value select_kth returns, for values >= 0 (NaN-free);
/// v is not modified, tmp (2n elements) is scratch. Requires 0 <= k < n.
/// One pass with the pivot of select_kth: below = #(x < pivot), at_or_below = #(x <= pivot), and the
/// largest value below and the smallest above it. k in [below, at_or_below): the pivot; k = below - 1:
/// the largest below; k = at_or_below: the smallest above (whatever their multiplicities). Otherwise
/// the side that holds the k-th is copied out (one pass) and select_kth finishes on it.
inline double select_kth_nonnegative(const double* v, double* tmp, std::size_t n, std::size_t k) {
  using Pair = double __attribute__((vector_size(2 * sizeof(double))));
  using PairU = double __attribute__((vector_size(2 * sizeof(double)), aligned(alignof(double))));
  using Mask = std::int64_t __attribute__((vector_size(2 * sizeof(std::int64_t))));
  const double a = v[n / 4], b = v[n / 2], c = v[3 * n / 4];
  const double pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));
  const double inf = std::numeric_limits<double>::infinity();
  const Pair piv = {pivot, pivot}, infs = {inf, inf};
  // Two sets of lanes (independent max / min chains). The masks are -1 where true: the counts are
  // subtracted. Non-negative values make the masking cheap: x & (x < pivot) is x or +0, which never
  // exceeds the largest value below the pivot when there is one; max(x, inf & (x <= pivot)) is x
  // above the pivot and inf otherwise.
  Mask below2[2] = {{0, 0}, {0, 0}}, at2[2] = {{0, 0}, {0, 0}};
  Pair lo2[2] = {{0.0, 0.0}, {0.0, 0.0}}, hi2[2] = {infs, infs};
  auto step = [&](const double* src, std::size_t j) {
    const Pair x = *reinterpret_cast<const PairU*>(src);
    const Mask lt = x < piv, le = x <= piv;
    below2[j] -= lt;
    at2[j] -= le;
    const Pair lo_x = std::bit_cast<Pair>(std::bit_cast<Mask>(x) & lt);
    const Pair inf_le = std::bit_cast<Pair>(std::bit_cast<Mask>(infs) & le);
    const Pair hi_x = x > inf_le ? x : inf_le;
    lo2[j] = lo2[j] > lo_x ? lo2[j] : lo_x;
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
  const Mask below_sum = below2[0] + below2[1], at_sum = at2[0] + at2[1];
  auto below = static_cast<std::size_t>(below_sum[0] + below_sum[1]);
  auto at_or_below = static_cast<std::size_t>(at_sum[0] + at_sum[1]);
  double below_max = std::max(std::max(lo2[0][0], lo2[0][1]), std::max(lo2[1][0], lo2[1][1]));
  double above_min = std::min(std::min(hi2[0][0], hi2[0][1]), std::min(hi2[1][0], hi2[1][1]));
  if (i < n) {
    const double x = v[i];
    below += static_cast<std::size_t>(x < pivot);
    at_or_below += static_cast<std::size_t>(x <= pivot);
    if (x < pivot) below_max = std::max(below_max, x);
    if (x > pivot) above_min = std::min(above_min, x);
  }
  if (k < below) {
    if (k + 1 == below) return below_max;
  } else if (k < at_or_below) {
    return pivot;
  } else if (k == at_or_below) {
    return above_min;
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
