// Kernel of the impact analyzer's ridge search (core/pipeline/ridge_track.cpp): subtract a row's
// median power from every column of the row and return the row's largest value after the onset.
#pragma once

#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// p[c] -= med for every c < cols; returns the largest p[c] (after the subtraction) over
/// [c_begin, c_end). Requires c_begin < c_end <= cols and NaN-free values (|W|^2 powers, >= 0).
/// Two independent pairs of f64x2 lanes for the maximum. The maximum of NaN-free values does not
/// depend on the order of the comparisons, so the result equals subtract_and_max_generic's bit for bit.
double subtract_and_max(double* p, std::size_t cols, double med, std::size_t c_begin, std::size_t c_end);
/// Plain scalar reference.
double subtract_and_max_generic(double* p, std::size_t cols, double med, std::size_t c_begin, std::size_t c_end);

}  // namespace ridgewatch::dsp::kernels
