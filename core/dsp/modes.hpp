// Multi-mode identification of one free response (the paper's Section 3 procedure and numerical
// example, Eq. 15-19), with better estimators than the two-point decrement:
//
//  1. Detection (detect_peaks), independent of the band and eta0 the user asks for, over the whole
//     usable band [auto f_min, 0.45 fs]: energy spectra at a ladder of resolutions eta0 = 7 .. 1000
//     (by Parseval, a row's time-mean |W|^2 is the periodogram weighted by the filter's power response,
//     so they come from one FFT; a resolution is used only where its filter's sd f / eta0 spans 1.5
//     periodogram bins), in units of the row's white-noise gain. The noise floor is what is noise: an
//     eta0 = 7 CWT (rows where the kernel fits the record 16 times), the lower quartile of each row's
//     |W|^2 in time (where the row holds only noise, after the decays), then the 25 % quantile of those
//     over +-1 octave of rows (robust to modes that outlast the record). Peaks standing min_peak_snr_db
//     above the floor are modes (Eq. 15: linearity of the CWT separates the components); a peak at a
//     coarse resolution that a finer one already resolved is the same mode.
//  2. eta0 per mode from the data (ModeAnalysis::read_candidate; Boltezar-Slavic / Staszewski): large
//     enough that the nearest detected neighbour (Delta f away, r times stronger) leaks less than 1 %
//     into the mode's row, eta0 >= x f / Delta f with x = sqrt(2 ln(100 max(1, r))) (the Gaussian
//     filter's skirt); small enough that the edge effect (edge_widths kernel widths) plus a 6-width
//     window fit in the decay's usable length (until its envelope falls to end_snr times the noise) and
//     the record. Where both cannot hold the time limit wins and the mode is marked as not resolved
//     from its neighbour (the envelope estimators then read the signal with the neighbours'
//     maximum-likelihood fits subtracted: read_deflated).
//  3. For each mode (estimate_envelope): phase slope of W along the row gives the damped frequency
//     (unbiased); the row at that frequency gives the wavelet envelope (Eq. 12), its window, the
//     two-point (Eq. 17-19) and the ridge least-squares estimates, and the backbone (backbone.hpp).
//  4. All modes in the band are refined together by the maximum-likelihood fit of ml_fit.hpp
//     (refine_ml); a mode whose joint fit fails is refitted alone in a band around it. Modes hidden by
//     a stronger neighbour (closer than any scan resolves) are searched for once on the residual of the
//     joint fit (hidden_peaks); found ones join the candidates and steps 2-4 run again.
//  5. Status rules (apply_status_rules; "ok is a promise"): estimators that disagree beyond their
//     uncertainties (no extra room when zeta varies along the decay), a ridge whose frequency drifts
//     within its window (it left the mode), an ml fit that left its spectral peak, a backbone
//     scattering > 25 % that no amplitude law explains (beating of an unresolved neighbour), a close
//     detected peak left out of the fit, zeta <= 0 or >= 1 (values null), a frequency outside the
//     band: not ok, with a note. A varying zeta is stated in the note with its backbone range. A mode
//     the user's eta0 cannot read stays in the joint fit (read at the automatic eta0) and is reported,
//     not ok.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "core/dsp/backbone.hpp"
#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

struct ModeSearchOptions {
  double f_min_hz = 0.0;            ///< lowest mode frequency searched; <= 0: automatic (>= 20 Hz)
  double f_max_hz = 0.0;            ///< highest; <= 0: 0.45 fs
  std::size_t max_modes = 16;       ///< the strongest K peaks in the band are kept
  double min_peak_snr_db = 10.0;    ///< a peak must stand this far above the noise floor
  double eta0 = 0.0;                ///< Morlet eta0 (Eq. 4) of the estimation; <= 0: chosen per mode
  std::size_t voices_per_octave = 32;
  DampingMethod method = DampingMethod::ml;
  /// Start of the free response in seconds from the record start; < 0: automatic (first sample whose
  /// magnitude reaches half the record's peak).
  double onset_s = -1.0;
  /// End of the analysed part in seconds from the record start; <= 0: the record end.
  double end_s = 0.0;
  EnvelopeOptions envelope;         ///< onset_s inside is ignored (set from the field above)
  BackboneOptions backbone;
};

struct IdentifiedMode {
  DampingEstimate selected;  ///< the estimate of the requested method
  DampingEstimate two_point, ridge_ls, ml;
  double eta0 = NAN;                 ///< eta0 used for this mode's envelope
  double eta0_needed = NAN;          ///< eta0 that would separate it from its nearest neighbour
  double neighbour_hz = NAN;         ///< nearest other detected peak (anywhere in the usable band)
  bool resolved = true;              ///< eta0 >= eta0_needed (else neighbours were subtracted)
  double detection_snr_db = NAN;     ///< peak of the energy spectrum over the noise floor
  Backbone backbone;
  std::string note;                  ///< why a status is not ok, when it is not
};

/// One detected spectral peak (all of them, also outside the band, for the eta0 choice and plots).
struct DetectedPeak {
  double f_hz = 0.0;
  double snr_db = 0.0;  ///< energy spectrum over the noise floor
  double eta0 = 0.0;    ///< resolution it was found at
};

struct ModeSearchResult {
  std::vector<IdentifiedMode> modes;  ///< sorted by frequency
  double onset_s = 0.0;
  double noise_sd = 0.0;              ///< noise standard deviation of the samples: the white-noise
                                      ///< equivalent floor, median over the band
  double f_min_hz = 0.0, f_max_hz = 0.0;
  double end_s = 0.0;                 ///< end of the analysed part
  std::vector<DetectedPeak> peaks;    ///< every detected peak, sorted by frequency
  std::string note;                   ///< when no mode was found: why
};

/// Throws std::invalid_argument for invalid options or a signal too short to analyse (< 64 samples).
ModeSearchResult identify_modes(std::span<const double> signal, double sample_rate_hz,
                                const ModeSearchOptions& options);

}  // namespace ridgewatch::dsp
