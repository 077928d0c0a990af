// Step 4 of the impact analysis (core/pipeline/impact_analyzer.hpp): the maximum-likelihood fit of one
// damped mode (dsp::SpectralModeFitter) to the decay segment, and, when a steady line near the mode
// widens its interval, the second fit with a nearly undamped line component (used only when the line
// is significant: F test against the one-mode fit on the same bins).
//
// Segment lengths are k/8 of the full window's ML segment, k = 1..8 (at least 64 samples), so that
// the fitters and their buffers are made once (prepare()); a fit uses the longest one the segment
// holds. At half rate (input decimation 2) the segments are samples of the half-rate copy.
#pragma once

#include <complex>
#include <cstddef>
#include <memory>
#include <span>
#include <vector>

#include "core/dsp/damping.hpp"
#include "core/dsp/ml_fit.hpp"

namespace ridgewatch::pipeline {

class MlStep {
 public:
  /// full_len: the complete window's ML segment in full-rate samples; in_dec: 1 or 2 (the analysis
  /// rate is fs / in_dec); ml_band_rel: the fit band's half-width relative to f_d; f_top_hz: the
  /// highest f_d a fit sees (the top CWT row); max_ci_ratio: the precision rule (hi / lo, > 1).
  MlStep(std::size_t full_len, std::size_t in_dec, double fs, double ml_band_rel, double f_top_hz,
         double max_ci_ratio);
  ~MlStep();
  MlStep(const MlStep&) = delete;
  MlStep& operator=(const MlStep&) = delete;

  /// Makes the fitters and buffers and runs every FFT plan once; after it, fit() allocates nothing.
  void prepare();

  /// Length (analysis-rate samples) of the longest segment a fit of [a0, a_end) uses; 0: none.
  std::size_t segment_length(std::size_t a0, std::size_t a_end) const;

  struct Outcome {
    bool fitted = false;          ///< the fitter returned an estimate (else `estimate` is unset)
    dsp::DampingEstimate estimate;
    /// White-equivalent noise variance of the full-rate input from the residual of the fit with a
    /// line component when that fit was used; NaN otherwise.
    double resid_var = NAN;
  };
  /// Fits `seg` (segment_length(a0, ...) samples from analysis-rate sample a0 of the window) started
  /// from (f_d, zeta0). The estimate's window is in seconds from the window start and its amplitude
  /// refers to the full-rate samples (the half-rate copy's H(f) divided out).
  Outcome fit(std::span<const double> seg, std::size_t a0, double f_d, double zeta0);

 private:
  double fs_ = 0, fs_a_ = 0;
  std::size_t in_dec_ = 1;
  double ml_band_rel_ = 0, f_top_hz_ = 0, max_ci_ratio_ = 1.25;
  std::vector<std::size_t> fitter_len_;          // segment lengths of the fitters
  std::vector<std::size_t> fitter_bins_;         // the most DFT bins each fitter's fits use
  std::vector<std::unique_ptr<dsp::SpectralModeFitter>> fitters_;
  dsp::MlFitResult one_;                         // reused: modes reserved for one guess
  dsp::MlFitResult with_line_;                   // the fit with a line component: two guesses
  dsp::MlFitResult try_;                         // ... one of its candidates
  dsp::MlFitResult base_;                        // the one-mode fit on a candidate's bins (line test)
  std::vector<std::complex<double>> line_bins_;  // the segment's DFT bins around the fit band

  std::size_t bins_for(std::size_t len) const;
  bool precise(const dsp::MlFitResult& r) const;
  /// The second fit (with a line component); true when it replaced the first in with_line_.
  bool fit_with_line(std::size_t pick, std::span<const double> seg, const dsp::ModeGuess& guess,
                     const dsp::MlFitOptions& mo, double fm);
};

}  // namespace ridgewatch::pipeline
