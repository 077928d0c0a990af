// Damping and frequency against amplitude ("backbone") of one mode from its wavelet ridge envelope:
// the wavelet counterpart of Feldman's FREEVIB backbones (instantaneous modal parameters of one free
// decay), with a test of whether the mode's damping is viscous (constant) at all.
//
// The ridge window of the mode (damping.hpp's choose_window) is cut into K consecutive segments of at
// least `min_segment_widths` kernel widths each. Each segment gives a local decay rate by the weighted
// least squares of ln|W| (estimate_ridge_ls, Eq. 12/16: ln|W| = ln A - sigma t on a viscous segment) and
// a local damped frequency by the phase slope, i.e. an equivalent viscous zeta(A) and f(A) at the
// segment's mean envelope amplitude A. Segments further apart than a few kernel widths see nearly
// independent noise (the row's noise autocorrelation is exp(-dt^2 / (4 s^2))), so the points are
// treated as independent.
//
// Constancy test: weighted least squares (weights 1/zeta_sd_i^2) of both laws below; the better one
// (smaller residual sum) decides. The mode is called amplitude dependent when both
//   - the law's slope is significant: |b| / sd(b) > `slope_z` (sd(b) inflated by sqrt(chi2/dof) when
//     the scatter about the law exceeds the stated uncertainties), and
//   - it matters: the fitted zeta changes by more than `min_relative_change` of its mean over the
//     measured amplitude range.
// The second condition keeps small deterministic biases of the envelope (neighbour leakage, the noise
// debiasing at the window end) from being reported as physics.
// Laws (one per damping mechanism): viscous zeta = a (constant); dry (Coulomb) friction
// dA/dt = -b0 gives zeta_eq = a + c / A (rises as the amplitude falls); quadratic (aerodynamic) damping
// dA/dt = -c A^2 gives zeta_eq = a + b A. Both are fitted by weighted least squares; the one with the
// smaller residual sum is reported, with 95 % intervals.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

struct BackbonePoint {
  double amplitude = NAN;  ///< mean envelope amplitude of the segment (signal units)
  double zeta = NAN;       ///< equivalent viscous damping ratio of the segment
  double zeta_sd = NAN;    ///< its standard uncertainty
  double f_hz = NAN;       ///< damped frequency of the segment
  double f_sd_hz = NAN;
  double t_s = NAN;        ///< segment centre, seconds on the row's time axis
};

enum class BackboneLaw { none, linear, coulomb };  ///< zeta = a; a + b A; a + b / A
std::string_view to_string(BackboneLaw law);

struct BackboneOptions {
  double min_segment_widths = 3.0;  ///< segment length, kernel widths s = eta0 / (2 pi f)
  std::size_t max_segments = 8;
  std::size_t min_segments = 4;     ///< fewer usable segments: no test (tested = false)
  double slope_z = 4.0;             ///< significance of the slope (|b| / sd(b)) needed to flag
  double min_relative_change = 0.15;  ///< and the relative change of zeta over the amplitude range
};

struct Backbone {
  std::vector<BackbonePoint> points;  ///< ordered by time (amplitude falling)
  bool tested = false;                ///< enough segments for the constancy test
  bool amplitude_dependent = false;
  double slope_z = NAN;               ///< b / sd(b) of the better law (sign: + when zeta rises with A)
  double relative_change = NAN;       ///< |b| (A_max - A_min) / zeta_mean
  double chi2_constant = NAN;         ///< chi-square of the points about their weighted mean
  std::size_t dof = 0;                ///< its degrees of freedom (points - 1)
  BackboneLaw law = BackboneLaw::none;  ///< the better-fitting law, when amplitude_dependent
  double a = NAN, a_ci95_lo = NAN, a_ci95_hi = NAN;  ///< law coefficients with 95 % intervals
  double b = NAN, b_ci95_lo = NAN, b_ci95_hi = NAN;
};

/// Backbone of the mode on `row` over `window` (as chosen by choose_window). f_d_hz: the mode's
/// damped frequency (the fallback for a segment whose phase slope fails).
Backbone estimate_backbone(const EnvelopeRow& row, const EnvelopeWindow& window, double f_d_hz,
                           const BackboneOptions& options = {});

/// The constancy test and law fit alone, on given points (used by estimate_backbone; public for tests).
void test_backbone(Backbone& backbone, const BackboneOptions& options);

}  // namespace ridgewatch::dsp
