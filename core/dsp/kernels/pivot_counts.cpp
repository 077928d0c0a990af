#include "core/dsp/kernels/pivot_counts.hpp"

#include <limits>

namespace ridgewatch::dsp::kernels {

PivotCounts pivot_counts_generic(const double* v, std::size_t n, double pivot) {
  PivotCounts c;
  c.above_min = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < n; ++i) pivot_counts_one(c, v[i], pivot);
  return c;
}

}  // namespace ridgewatch::dsp::kernels
