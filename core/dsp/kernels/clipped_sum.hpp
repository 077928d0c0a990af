// Sum of min(|r[i]|, clip) over i < n and whether any |r[i]| > above (the spike stage's scale update
// and candidate pre-test, impact_detector.hpp stage 1). Float sums. Summation order (the reference):
// four partial sums, lane l holding i = l (mod 4) for i < 4 floor(n / 4) in increasing i, then the
// remaining n mod 4 terms added to lane 0 in order; combined as (l0 + l1) + (l2 + l3), widened to double.
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// Vector version (|r| by clearing the sign bit); bit-identical to clipped_sum_any_above_generic.
bool clipped_sum_any_above(const float* r, std::size_t n, float clip, float above, double& sum);
/// Scalar reference.
bool clipped_sum_any_above_generic(const float* r, std::size_t n, float clip, float above, double& sum);

}  // namespace ridgewatch::dsp::kernels
