// Band envelopes of one whole record, cut in the frequency domain of a single FFT: the building block
// of the survey's kurtogram and of its impact-period estimate.
//
// The record x[n] (n < N, sample rate fs) is zero-padded to Np >= N (a product of 2, 3 and 5) and
// transformed once: X[k], k = 0 .. Np/2, bin spacing fs / Np. The complex envelope of the band
// [f_lo, f_hi) is the inverse transform of the band's bins shifted to 0 Hz:
//     c[m] = sum_{k in band} X[k] e^{+2 pi i (k - k_lo) m / M},   m = 0 .. M-1,
// i.e. the analytic signal of the band-passed record, moved down to base band and sampled at
// fs_env = M fs / Np (M >= the band's bin count, times `oversample`). |c| is the band's envelope
// (up to the factor 2/Np, which cancels in every ratio the survey uses: kurtosis, correlations,
// contrasts). The band edges are brick-wall (one bin wide transition); samples m that map beyond the
// record's end (the zero padding) are not part of the envelope.
#pragma once

#include <complex>
#include <cstddef>
#include <memory>
#include <span>
#include <vector>

namespace ridgewatch::survey {

/// The smallest integer >= n whose only prime factors are 2, 3 and 5 (fast FFT sizes).
std::size_t nice_fft_size(std::size_t n);

class RecordSpectrum {
 public:
  /// Transforms the record once. Throws std::invalid_argument for fewer than 64 samples or fs <= 0.
  RecordSpectrum(std::span<const double> x, double sample_rate_hz);
  ~RecordSpectrum();
  RecordSpectrum(const RecordSpectrum&) = delete;
  RecordSpectrum& operator=(const RecordSpectrum&) = delete;

  double sample_rate_hz() const { return fs_; }
  std::size_t samples() const { return n_; }
  std::size_t padded_samples() const { return np_; }
  double bin_hz() const { return fs_ / static_cast<double>(np_); }
  /// X[k], k = 0 .. Np/2.
  std::span<const std::complex<double>> bins() const { return spec_; }

  /// Complex envelope of [f_lo_hz, f_hi_hz) (clamped to [0, fs/2]); `rate_hz` receives fs_env.
  /// Only the samples inside the record are returned. Empty when the band holds no bin.
  std::vector<std::complex<double>> envelope(double f_lo_hz, double f_hi_hz, double oversample,
                                             double& rate_hz) const;

  /// One-sided power spectrum |X[k]|^2 smoothed over `width_bins` (boxcar), k = 0 .. Np/2.
  std::vector<double> smoothed_power(std::size_t width_bins) const;

 private:
  struct Plans;
  double fs_ = 0;
  std::size_t n_ = 0, np_ = 0;
  std::vector<std::complex<double>> spec_;
  std::unique_ptr<Plans> plans_;  // inverse plans by size, made on first use
};

}  // namespace ridgewatch::survey
