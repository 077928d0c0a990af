// The spike stage's interpolation residuals with their per-block statistics (impact_detector.hpp
// stage 1), in one pass over vectors of four:
//   r[i] = (x[i] + (x[i-2] + x[i+2]) * (1/6)) - (x[i-1] + x[i+1]) * (2/3)   (float, in this order)
// for i in [2, 4 nv), nv = (count len + 5) / 4: the blocks' residuals and up to five past them (from
// samples that must be readable: x is read up to x[4 nv + 1]); r[0] and r[1] are kept (they came with
// the previous block, possibly corrected by its spike test). Per block k (r[k len .. (k + 1) len)):
//   sums[k] = sum of min(|r|, clip) in the order of clipped_sum_any_above (clipped_sum.hpp),
//   tops[k] = max |r| (0 for an empty or all-NaN block).
// Requires len % 4 == 0 or count == 1.
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// Vector version: residuals stay in registers for the sums; bit-identical to the reference.
void spike_residual_blocks(const float* x, float* r, std::size_t len, std::size_t count, float clip, float* sums,
                           float* tops);
/// Scalar reference: residuals one by one, then clipped_sum_any_above_generic and a plain maximum.
void spike_residual_blocks_generic(const float* x, float* r, std::size_t len, std::size_t count, float clip,
                                   float* sums, float* tops);

}  // namespace ridgewatch::dsp::kernels
