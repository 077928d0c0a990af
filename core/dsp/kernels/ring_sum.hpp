// Sum of the entries ring[i & mask], i in [lo, hi), of a power-of-two ring of doubles (the trigger
// band's STA and pre-window sums re-summed from the energy history, impact_detector.hpp stage 3).
// Summation order (the reference): the range split where it wraps; in each contiguous piece, groups of
// four q[4g..4g+3] go to partial sums p0 += q0, p1 += q1, p2 += q2, p3 += q3 and the piece's
// remainder (< 4 terms) to p0 in order; the result is (p0 + p2) + (p1 + p3).
#pragma once

#include <cstddef>
#include <cstdint>

namespace ridgewatch::dsp::kernels {

/// Vector version (two two-double partial sums: a short dependency chain); bit-identical to
/// ring_sum_generic.
double ring_sum(const double* ring, std::uint64_t mask, std::uint64_t lo, std::uint64_t hi);
/// Scalar reference.
double ring_sum_generic(const double* ring, std::uint64_t mask, std::uint64_t lo, std::uint64_t hi);

}  // namespace ridgewatch::dsp::kernels
