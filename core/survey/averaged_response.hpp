// Survey step 4''' (survey.hpp): the ringing mode identified from quantities averaged over the
// impacts, for decays too short and too weak to be identified in any single free response (a time
// constant of 1-2 ms at 10 dB SNR stands only 6-9 dB over the noise in one free response's spectrum).
//
// The impact times are known to ~0.25 ms only (the survey's envelope bins), far too coarse to add
// the free responses coherently at several kHz, so the averages are of powers (incoherent):
//  1. Frequency: on the analytic envelope of the searched range (no negative-frequency image), for
//     each impact j at the estimated onset c_j, a Hann window of 2L samples centred on
//     c_j (E_j: the decay starts at the window's middle, where the weight is 1, so the onset's
//     uncertainty hardly matters) and one of the same length just before it (R_j, ending 1 ms before
//     E_j starts, in the second half of the previous interval). P_E(f) and P_R(f) are their power
//     spectra averaged over the N impacts. A decaying mode puts power into E and not into R; noise,
//     hum and mesh lines put the same into both. The peak of P_E / P_R over the searched range, at
//     the half-length L (powers of two, 32 samples .. 1/6 of the shortest interval) where it is most
//     significant, gives f (refined on the excess P_E - P_R, parabolic on its logarithm).
//  2. Significance: in a bin holding only noise each periodogram value is exponential (2 degrees of
//     freedom), so P_E and P_R are Gamma(N) with the same scale and P_E / P_R > r has the
//     probability I_{1/(1+r)}(N, N) (regularised incomplete beta: the F distribution with 2N, 2N
//     degrees of freedom; its spread narrows as 1/sqrt(N), the variance of an N-average falling as
//     1/N). The peak is a mode when that probability times the number of tests (searched bandwidth
//     x 2L per half-length, twice for maxima between the Hann bins, summed over the half-lengths:
//     a Bonferroni bound) stays below the family-wise false-alarm probability (1e-3 by default: at
//     most one survey in a thousand of a record without decays invents a mode here). Deterministic
//     lines are the same in E and R and only make the ratio's spread smaller than the noise's.
//     A stationary line (a peak of P_R >= 10x its surroundings with P_E / P_R < 2) within the Hann
//     main lobe of the peak would bias f: then nothing is identified.
//  3. Damping: the band power |c|^2 of f +- hw (hw = 1/L within 3-15 % of f, kept clear of the lines),
//     averaged over the impacts aligned at c_j, minus its floor (its mean before the impacts): the
//     excess decays as exp(-2 sigma t) (the square of paper eq. 16's envelope, sigma = zeta omega_0);
//     a least-squares
//     line through its logarithm (weights excess^2, the inverse variance of the log) from its peak to
//     where it falls to 3 standard deviations of the floor gives sigma, and zeta = sigma T / sqrt(4 pi^2
//     + (sigma T)^2), T = 1/f (eq. 19 with the decrement sigma T). A first value: it sets the
//     proposal's decay window, not the analyzer's per-impact estimate. A free decay starts at the
//     impact: the excess over three power time constants before the peak (and its rise time earlier)
//     must hold < 30 % of the excess over the same span after it; a line swept through the band by
//     the speed variation rises as it falls, and also passes the ratio test of 1-2 (it is elsewhere
//     in the R window), so without this its passages would be taken for a decaying mode.
#pragma once

#include <cmath>
#include <cstddef>
#include <span>
#include <string>

#include "core/survey/band_envelope.hpp"

namespace ridgewatch::survey {

struct AveragedModeSearch {
  double f_lo_hz = 20;          ///< searched range
  double f_hi_hz = 0;           ///< <= 0: 0.45 fs
  double false_alarm = 1e-3;    ///< family-wise probability of a mode in a record without decays
};

struct AveragedMode {
  bool found = false;
  double f_hz = NAN;            ///< peak of the averaged excess power (the best bin even when not found)
  double zeta = NAN;            ///< from the averaged band-power decay (found only)
  double ratio = NAN;           ///< P_E / P_R at the peak
  double ratio_needed = NAN;    ///< the ratio that reaches the false-alarm bound at the chosen L
  double half_window_s = NAN;   ///< L of the chosen windows
  std::size_t impacts = 0;      ///< N, impacts averaged at the chosen L
  std::size_t tests = 0;        ///< number of tests of the Bonferroni bound
  std::string why;              ///< why nothing was identified (empty when found)
};

/// P(X / Y > r) for independent X, Y ~ Gamma(n, same scale): I_{1/(1+r)}(n, n), exactly, as the
/// tail of Binomial(2n - 1, 1/(1+r)) from n on. n >= 1, r >= 0.
double gamma_ratio_tail(std::size_t n, double r);
/// Its natural logarithm, without underflow.
double log_gamma_ratio_tail(std::size_t n, double r);

/// Steps 1-3 above on the record whose transform is `spectrum` (step 1 on the analytic envelope of
/// the searched range). onset_s[j]: the estimated onset of impact j; previous_s[j] that of the
/// impact before it (the R window stays in the second half of that interval).
AveragedMode identify_averaged_mode(const RecordSpectrum& spectrum, std::span<const double> onset_s,
                                    std::span<const double> previous_s, const AveragedModeSearch& opt = {});

}  // namespace ridgewatch::survey
