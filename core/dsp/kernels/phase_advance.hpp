// Kernel of the phase-slope frequency estimate (core/dsp/damping.cpp): the column-to-column phase
// advances of a CWT row, arg(w_i conj(w_{i-1}) derotate) + advance.
#pragma once

#include <complex>
#include <cstddef>

namespace ridgewatch::dsp::kernels {

/// arg z in (-pi, pi], as std::arg: near the positive real axis (re > 0 and |im| <= re / 8, i.e.
/// |arg z| <= 0.1244, where the derotated advances of a row near the mode lie) by the series of
/// atan(im / re); elsewhere (and for NaN) std::arg. With t^2 <= 1/64 the first omitted term of the
/// series (t^21 / 21) is below 3e-18 of the sum: as accurate as the division that forms t.
double phase_angle(std::complex<double> z);

/// d[i] = phase_angle(w[i] * conj(w[i - 1]) * derotate) + advance for i in [1, count) (d[0] is not
/// written; w[0..count) readable). Two columns per step in f64x2 lanes: the complex products formed
/// as std::complex forms them (x.r y.r - x.i y.i, x.r y.i + x.i y.r; its special-value handling only
/// acts on NaN results) and the same series, when both columns are in the series' range, else the
/// scalar expression: the same bits as phase_advances_generic.
void phase_advances(const std::complex<double>* w, std::size_t count, std::complex<double> derotate,
                    double advance, double* d);
/// Plain scalar reference: the expression above column by column.
void phase_advances_generic(const std::complex<double>* w, std::size_t count, std::complex<double> derotate,
                            double advance, double* d);

}  // namespace ridgewatch::dsp::kernels
