// Multi-mode identification of one free response (the paper's Section 3 procedure and numerical
// example, Eq. 15-19), with better estimators than the two-point decrement:
//
//  1. CWT on a log-spaced frequency grid; the time-integrated energy of each row divided by the row's
//     white-noise gain gives a spectrum in units of the noise floor. Its peaks are the modes
//     (Eq. 15: linearity of the CWT separates the components); sub-bin position by a parabola in ln f.
//  2. For each mode: phase slope of W along the row gives the damped frequency (unbiased); the row at
//     that frequency gives the wavelet envelope (Eq. 12), its window, the two-point (Eq. 17-19) and
//     the ridge least-squares estimates.
//  3. All modes are refined together by the maximum-likelihood fit of ml_fit.hpp.
#pragma once

#include <cstddef>
#include <span>
#include <vector>

#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

struct ModeSearchOptions {
  double f_min_hz = 0.0;            ///< lowest mode frequency searched; <= 0: automatic (>= 20 Hz)
  double f_max_hz = 0.0;            ///< highest; <= 0: 0.45 fs
  std::size_t max_modes = 8;        ///< the strongest K peaks are kept
  double min_peak_snr_db = 10.0;    ///< a peak must stand this far above the noise floor
  double eta0 = 7.0;                ///< Morlet eta0 (Eq. 4)
  std::size_t voices_per_octave = 32;
  DampingMethod method = DampingMethod::ml;
  /// Start of the free response in seconds from the record start; < 0: automatic (first sample whose
  /// magnitude reaches half the record's peak).
  double onset_s = -1.0;
  EnvelopeOptions envelope;         ///< onset_s inside is ignored (set from the field above)
};

struct IdentifiedMode {
  DampingEstimate selected;  ///< the estimate of the requested method
  DampingEstimate two_point, ridge_ls, ml;
};

struct ModeSearchResult {
  std::vector<IdentifiedMode> modes;  ///< sorted by frequency
  double onset_s = 0.0;
  double noise_sd = 0.0;              ///< estimated noise standard deviation of the samples
  double f_min_hz = 0.0, f_max_hz = 0.0;
};

/// Throws std::invalid_argument for invalid options or a signal too short to analyse (< 64 samples).
ModeSearchResult identify_modes(std::span<const double> signal, double sample_rate_hz,
                                const ModeSearchOptions& options);

}  // namespace ridgewatch::dsp
