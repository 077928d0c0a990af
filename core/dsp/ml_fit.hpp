// Maximum-likelihood refinement: nonlinear least squares of a sum of sampled damped sinusoids
// (Eq. 16 for each mode, Eq. 15 for their sum) to the signal, started from envelope estimates.
//
// The signal segment x[n], n = 0..N-1 (n = 0 at the segment start t0) is modelled as
//     x[n] = sum_j Re(C_j z_j^n) + noise,   z_j = exp((-sigma_j + i omega_j) / fs)
// and compared in the DFT domain, where the model has the closed form
//     X_k = sum_j [ C_j G(z_j, k) + conj(C_j) G(conj z_j, k) ] / 2,  G(z, k) = (1 - z^N) / (1 - z e^{-2 pi i k / N}).
// The DFT is a unitary change of basis, so fitting all bins is the same least-squares problem as in
// the time domain; keeping only the bins of a band [f_lo, f_hi] lets the fit ignore everything outside
// it (hum, out-of-band modes), and white noise stays white and independent across bins. A low-order
// complex polynomial in k ("residual terms", as in modal analysis) absorbs the smooth in-band tails of
// modes outside the band. Free parameters per mode: f_j (damped frequency), ln zeta_j, Re C_j, Im C_j.
// A component that does not decay within the segment (sigma T < 1e-6: a steady line fitted as a
// mode) has no determined damping: its interval is null (status fit_failed) and the other parameters'
// uncertainties are taken with it held undamped.
// Optimiser: Levenberg-Marquardt with an analytic Jacobian: for up to 12 parameters an allocation-free
// one on the normal equations with Marquardt scaling, for larger problems Eigen's MINPACK port (QR).
#pragma once

#include <complex>
#include <cstddef>
#include <memory>
#include <span>
#include <vector>

#include "core/dsp/damping.hpp"

namespace ridgewatch::dsp {

struct ModeGuess {
  double f_hz = 0.0;   ///< damped frequency, inside the band
  double zeta = 0.01;  ///< damping ratio, 0 < zeta < 1
};

struct MlFitOptions {
  double f_lo_hz = 0.0;         ///< band of DFT bins used; 0 < f_lo < f_hi <= fs/2
  double f_hi_hz = 0.0;
  int residual_terms = 2;       ///< complex polynomial terms for out-of-band tails (0..4)
  int max_evaluations = 400;    ///< optimiser budget (function evaluations)
};

struct MlFitResult {
  std::vector<DampingEstimate> modes;  ///< one per guess, same order; method = ml
  double noise_sd = 0.0;               ///< estimated noise standard deviation of the input samples
  bool converged = false;
  std::size_t bins = 0;                ///< DFT bins used
};

/// t_{0.975, dof}: the two-sided 95 % quantile of Student's t with `dof` degrees of freedom (the
/// fit's residual ones, 2 values per DFT bin minus the parameters); NaN for dof < 1. The 95 %
/// intervals use it because the noise variance is estimated from the residual: with the few bins of a
/// short low-frequency segment (6 degrees of freedom at 300 Hz in 28 ms) the normal 1.96 covers only
/// ~90 %.
double student_t95(int dof);

/// Plans an FFT for segments of exactly `segment_samples` samples; reusable for many segments.
class SpectralModeFitter {
 public:
  /// max_bins > 0: the caller's fits never use more than this many DFT bins. When that is few enough
  /// for the Goertzel evaluation (<= 2 log2 segment_samples, the rule fit() applies), no FFT plan is
  /// made (planning an awkward length, e.g. a prime, costs milliseconds at start-up); a fit with more
  /// bins then still works, through the Goertzel evaluation.
  /// fit_bins > 0: room reserved for the bins of one fit (default: max_bins, or every bin when
  /// max_bins is 0); a fit over more bins than reserved still works but allocates.
  SpectralModeFitter(std::size_t segment_samples, double sample_rate_hz, std::size_t max_bins = 0,
                     std::size_t fit_bins = 0);
  ~SpectralModeFitter();
  SpectralModeFitter(const SpectralModeFitter&) = delete;
  SpectralModeFitter& operator=(const SpectralModeFitter&) = delete;

  /// Fits the modes to `segment` (size == segment_samples). Amplitudes are reported at the segment
  /// start; window_start_s/end_s are 0 and the segment duration (callers shift them).
  MlFitResult fit(std::span<const double> segment, std::span<const ModeGuess> guesses,
                  const MlFitOptions& options);
  /// Same, into `result` (its vector's capacity is reused). With at most 12 parameters (one mode with
  /// up to 4 residual terms, or 3 modes without) and result.modes reserved for the guesses, a fit
  /// allocates nothing: real-time callers (the impact analyzer) use this.
  void fit(std::span<const double> segment, std::span<const ModeGuess> guesses, const MlFitOptions& options,
           MlFitResult& result);

  /// The DFT bins X_k = sum_n x[n] e^{-2 pi i k n / N}, k = k_lo .. k_lo + bins.size() - 1, of `segment`
  /// (size == segment_samples), evaluated exactly as fit() evaluates a band of that many bins (Goertzel
  /// recursions for few bins, else the FFT). Requires 1 <= k_lo and k_lo + bins.size() - 1 <= (N - 1) / 2.
  /// Allocates nothing. (Tests compare the evaluations with a reference.)
  void dft_bins(std::span<const double> segment, std::size_t k_lo, std::span<std::complex<double>> bins);

  /// on: this fitter's fits evaluate the model and the normal equations by the plain reference
  /// kernels (scalar complex arithmetic one term at a time, run-time-size loops, no reuse of mode
  /// states) instead of the SSE2 pair kernels; the results are the same bit for bit (tests compare).
  void use_reference_kernels(bool on);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ridgewatch::dsp
