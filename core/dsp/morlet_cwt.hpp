// Morlet continuous wavelet transform computed in the frequency domain with FFTW.
//
// Paper, Eq. (1)-(7): psi(t) = g(t) exp(i eta0 t), g(t) = pi^(-1/4) exp(-t^2/2), scale s = eta0/omega.
// This class uses an amplitude normalisation instead of the paper's 1/sqrt(s): the analysing filter of
// the row at frequency f is
//
//     Psi_f(omega) = 2 exp(-(s omega - eta0)^2 / 2)  for omega > 0,  0 for omega <= 0,  s = eta0/(2 pi f)
//
// (the Morlet's negative-frequency tail, below exp(-eta0^2/2) < 1e-10 for eta0 >= 7, is dropped, so the
// rows are analytic signals; on the DFT grid the DC and Nyquist bins, which sit on the filter's jump, take
// half the filter value). With this gain, a(t) cos(2 pi f t + beta) with a slowly varying envelope
// gives |W(t, f)| = a(t) directly: the row's modulus *is* the wavelet envelope of Eq. (12), i.e. this
// W equals the paper's W_x times K = 2 pi^(1/4) sqrt(alpha0/eta0).
//
// Time-domain view (used by the reference implementation in the tests):
//     W(t, f) = (2/(s sqrt(2 pi))) * integral x(u) exp(-(u-t)^2/(2 s^2)) exp(-i eta0 (u-t)/s) du
// up to the dropped negative-frequency tail; the kernel's time standard deviation is s seconds.
//
// Signals are treated as zero outside [0, n): the transform near either end shows the edge effect of a
// step, which callers skip. Internally the signal is zero-padded far enough that the Gaussian kernel
// never wraps around the circular FFT convolution. Small eta0 caveat: for eta0 < sqrt(2 ln(1/truncation))
// (6.8 at the full-rate default) the kept band reaches DC, where the analytic filter jumps by
// 2 exp(-eta0^2/2) (7.5e-6 at eta0 = 5); the kernel of that jump decays only like 1/tau. The padding is
// then extended by max_samples, which keeps the wrapped part below ~3e-6 of max |W| even for a record
// dominated by a DC level; for eta0 >= 7 this effect is below 1e-10.
//
// Band-limited mode: each row only needs the FFT bins where its Gaussian exceeds `truncation` of the
// peak. Those bins are folded into a short inverse FFT of length D = L/R, which yields W exactly on the
// decimated time grid t = m R / fs (no carrier to restore: bin k lands in slot k mod D, which is
// alias-free because every row's band is narrower than D bins). R is the largest 2,3,5,7-smooth integer
// for which the band of the highest configured frequency fits, R ~ fs eta0 / (2 c f_max) with
// c = sqrt(2 ln(1/truncation)); D is a 2,3,5-smooth length. The error against the exact transform is
// bounded by the dropped Gaussian tail (about `truncation` relative to the row's peak gain) plus the FFT
// round-off of the chosen precision. Band-limited mode therefore defaults to a coarser truncation
// (kBandLimitedTruncation = 1e-6: c = 5.3 instead of 6.8, i.e. a 29 % larger R and shorter FFTs), which
// keeps the error near 1e-6 of max |W| (measured against the exact transform: <= 4.5e-7 double and
// <= 1.0e-6 float in test_morlet_cwt, 1.2e-7 / 3.5e-7 on the rig workload in bench/bench_cwt.cpp).
//
// Band-limited forward transform: only the bins up to the top of band_limit_hz()'s band are read, so
// for even L the real FFT is done as a complex FFT of L/2 sample pairs, unpacked for those bins only
// (FFTW's estimated r2c plans of some lengths are slower than the complex plan of half the length;
// timings in docs/performance.md, "cwt").
//
// Half-rate input (half_rate_121_input): the signal is y[m] = (x[2m-1] + 2 x[2m] + x[2m+1]) / 4 of an
// x sampled at fs_x = 2 fs. Below fs/2 the DTFT of y is H(f) X(f) + H(fs - f) X(f - fs) with
// H(f) = cos^2(pi f / fs_x) (the taps' response; symmetric around x[2m], so no delay), i.e. x's band
// times H plus the image from fs - f attenuated by H(fs - f) = sin^2(pi f / fs_x). Every filter gain is
// divided by H at its bin, so that W is the transform of x's band up to that image. Noise: white x of
// variance sigma^2 gives y the spectral density sigma^2 (H(f)^2 + H(fs - f)^2) / 2 (in units where a
// white sequence of variance v has density v), so with the compensated gains
//     E|W|^2 = sigma^2 (1/L) sum_k |Psi_f(k)|^2 (H_k^2 + H'_k^2) / (2 H_k^2)
// which noise_gain() returns (per unit variance of x). The sum over the uncompensated filter at fs is
// twice the full-rate one at fs_x (4 sqrt(pi) f / (eta0 fs)), so the half-rate gain equals the full-rate
// gain at fs_x times 1 + H'^2 / H^2 = 1 + tan^4(pi f / fs_x) averaged over the row's band (2e-5 for
// 1.1 kHz at fs_x = 51.2 kHz, 3 % for 1 kHz at 8 kHz).
//
// Real-time contract: all FFTW plans and buffers are made in the constructor; `transform`, `load` and
// `row` allocate nothing provided the output has been sized once (Scalogram::resize keeps capacity).
#pragma once

#include <complex>
#include <cstddef>
#include <memory>
#include <span>
#include <vector>

namespace ridgewatch::dsp {

enum class GridSpacing { linear, log };

/// `count` analysis frequencies from f_min_hz to f_max_hz inclusive, linearly or logarithmically spaced.
/// Throws std::invalid_argument unless 0 < f_min_hz < f_max_hz and count >= 2 (count == 1 needs
/// f_min_hz == f_max_hz).
std::vector<double> make_frequency_grid(double f_min_hz, double f_max_hz, std::size_t count,
                                        GridSpacing spacing);

struct MorletCwtConfig {
  double sample_rate_hz = 0.0;         ///< > 0, Hz
  double eta0 = 7.0;                   ///< Morlet centre frequency eta0 of Eq. (4); 5 <= eta0 <= 50
  /// Allow 5 <= eta0 <= 1000 (mode identification: fine frequency resolution on long records; the
  /// transform itself has no upper limit, the padding follows the kernel width).
  bool fine_resolution = false;
  std::vector<double> frequencies_hz;  ///< analysis rows, each 0 < f < sample_rate_hz / 2
  std::size_t max_samples = 0;         ///< longest signal that will be transformed, > 0
  bool band_limited = false;           ///< decimated output (see header comment)
  /// Default truncation for full-rate transforms: equal to the exact transform to ~1e-10.
  static constexpr double kFullRateTruncation = 1e-10;
  /// Default truncation for band-limited transforms: error ~1e-6 of max |W|, faster (see header comment).
  static constexpr double kBandLimitedTruncation = 1e-6;
  /// Gaussian level below which filter bins are dropped, relative to the peak; 1e-14 <= t <= 1e-2, or 0
  /// (default) for the mode's default: kFullRateTruncation, or kBandLimitedTruncation when band_limited.
  double truncation = 0.0;
  /// Measure FFTW plans (slower constructor, faster transforms) instead of estimating them.
  bool measure_plans = false;
  /// The input is a half-rate copy y[m] = (x[2m-1] + 2 x[2m] + x[2m+1]) / 4 of a signal x sampled at
  /// 2 sample_rate_hz (see the header comment, "Half-rate input"): the filter gains are divided by the
  /// decimation filter's response H(f) = cos^2(pi f / (2 sample_rate_hz)), so |W| is the envelope of x,
  /// and noise_gain() refers to white noise of x at 2 sample_rate_hz.
  bool half_rate_121_input = false;
};

/// Wavelet coefficients, rows = analysis frequencies, columns = time. Row-major, owns its data.
template <typename Real>
struct Scalogram {
  std::size_t rows = 0;
  std::size_t cols = 0;
  double time_step_s = 0.0;  ///< spacing of the columns; column m is at t = m * time_step_s
  std::size_t decimation = 1;  ///< input samples per column
  std::vector<double> frequencies_hz;
  std::vector<std::complex<Real>> data;

  void resize(std::size_t n_rows, std::size_t n_cols) {
    rows = n_rows;
    cols = n_cols;
    data.resize(n_rows * n_cols);
  }
  std::complex<Real>& at(std::size_t r, std::size_t c) { return data[r * cols + c]; }
  const std::complex<Real>& at(std::size_t r, std::size_t c) const { return data[r * cols + c]; }
  std::span<const std::complex<Real>> row(std::size_t r) const {
    return {data.data() + r * cols, cols};
  }
  std::span<std::complex<Real>> row(std::size_t r) { return {data.data() + r * cols, cols}; }
};

/// Real = double or float (FFTW's fftw_ and fftwf_ plans respectively).
template <typename Real>
class MorletCwt {
 public:
  /// Validates the configuration (throws std::invalid_argument naming the field) and makes the plans.
  explicit MorletCwt(MorletCwtConfig config);
  ~MorletCwt();
  MorletCwt(const MorletCwt&) = delete;
  MorletCwt& operator=(const MorletCwt&) = delete;
  MorletCwt(MorletCwt&&) noexcept;
  MorletCwt& operator=(MorletCwt&&) noexcept;

  /// Full transform of `signal` (1 <= size <= max_samples) on the configured grid.
  /// out gets rows = frequencies, cols = ceil(size / decimation()).
  void transform(std::span<const Real> signal, Scalogram<Real>& out);

  /// Stores the spectrum of `signal` for subsequent `row` calls.
  void load(std::span<const Real> signal);
  /// One row at any frequency 0 < f_hz < fs/2 (band-limited mode: the row's band must fit the decimated
  /// grid, i.e. f_hz <= band_limit_hz()). Writes columns(); requires a prior load().
  void row(double f_hz, std::span<std::complex<Real>> out);
  /// The row of configured frequency frequencies_hz()[index], identical to row(frequencies_hz()[index])
  /// but with the filter gains made once in the constructor (the same for every load).
  void row_at(std::size_t index, std::span<std::complex<Real>> out);
  /// All configured rows, row-major (frequencies_hz().size() x columns()), equal to row_at for each
  /// index up to FFT round-off (small band-limited grids go through one batched inverse FFT).
  void grid_rows(std::span<std::complex<Real>> out);

  /// Number of output columns for the loaded signal.
  std::size_t columns() const;
  std::size_t decimation() const;
  double time_step_s() const;
  double sample_rate_hz() const;
  double eta0() const;
  const std::vector<double>& frequencies_hz() const;
  /// Highest row frequency the band-limited grid can represent without aliasing.
  double band_limit_hz() const;
  /// FFT length used internally (padded).
  std::size_t fft_length() const;
  /// Effective Gaussian truncation level (the configured one, or the mode default when configured as 0).
  double truncation() const;

  /// The transform's sizes for a configuration (what the constructor picks; the configuration is not
  /// validated): input samples per column, the FFT length and the short (decimated) length. Cheap, no
  /// allocation: callers that compare several configurations need not make the plans.
  struct Layout {
    std::size_t decimation = 1;
    std::size_t fft_length = 0;
    std::size_t short_length = 0;
  };
  static Layout layout(const MorletCwtConfig& config);

  /// Time standard deviation of the kernel at frequency f: s = eta0 / (2 pi f), in seconds.
  static double kernel_time_sd_s(double eta0, double f_hz);
  /// Frequency standard deviation of the filter |Psi_f| at frequency f: f / eta0, in Hz.
  static double kernel_freq_sd_hz(double eta0, double f_hz);
  /// Variance gain of the row at f_hz for white noise: E|W|^2 = noise_gain * sigma^2 for input samples
  /// of variance sigma^2. Computed from the discrete filter: (1/L) sum_k |Psi_f(k)|^2
  /// (~ 4 sqrt(pi) f / (eta0 fs) in the continuum limit).
  double noise_gain(double f_hz) const;


 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Half-rate copy for half_rate_121_input: y[m] = (x[2m-1] + 2 x[2m] + x[2m+1]) / 4 for
/// m < (x.size() + 1) / 2, with x taken as zero outside [0, x.size()) (as the transform does), written to
/// y and, when y_float is not empty, in single precision to y_float (both of size >= (x.size() + 1) / 2).
/// Only y[1 .. x.size() / 2 - 1] use in-range samples alone. Returns max |x| (the same pass reads every
/// sample; the impact analyzer's peak check uses it). Float input is widened to double sample by sample
/// (exactly), so both overloads give the same y for the same values. The interior outputs are
/// kernels::half_rate_121 (core/dsp/kernels/half_rate_121.hpp); this adds the two edges.
double decimate_half_121(std::span<const double> x, std::span<double> y, std::span<float> y_float);
double decimate_half_121(std::span<const float> x, std::span<double> y, std::span<float> y_float);

extern template class MorletCwt<double>;
extern template class MorletCwt<float>;

}  // namespace ridgewatch::dsp
