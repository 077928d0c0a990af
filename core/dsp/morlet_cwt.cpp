#include "core/dsp/morlet_cwt.hpp"

#include "core/dsp/fftw_planner.hpp"
#include "core/dsp/kernels/half_rate_121.hpp"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <mutex>
#include <numbers>
#include <stdexcept>
#include <string>

namespace ridgewatch::dsp {

namespace {


template <typename Real>
struct Fftw;

template <>
struct Fftw<double> {
  using Complex = fftw_complex;
  using Plan = fftw_plan;
  static double* alloc_real(std::size_t n) { return fftw_alloc_real(n); }
  static Complex* alloc_complex(std::size_t n) { return fftw_alloc_complex(n); }
  static void free(void* p) { fftw_free(p); }
  static Plan plan_r2c(int n, double* in, Complex* out, unsigned flags) {
    return fftw_plan_dft_r2c_1d(n, in, out, flags);
  }
  static Plan plan_c2c_backward(int n, Complex* in, Complex* out, unsigned flags) {
    return fftw_plan_dft_1d(n, in, out, FFTW_BACKWARD, flags);
  }
  static Plan plan_c2c_forward(int n, Complex* in, Complex* out, unsigned flags) {
    return fftw_plan_dft_1d(n, in, out, FFTW_FORWARD, flags);
  }
  static Plan plan_c2c_backward_many(int n, int howmany, Complex* in, Complex* out, unsigned flags) {
    return fftw_plan_many_dft(1, &n, howmany, in, nullptr, 1, n, out, nullptr, 1, n, FFTW_BACKWARD, flags);
  }
  static void execute(Plan p) { fftw_execute(p); }
  static void destroy(Plan p) { fftw_destroy_plan(p); }
};

template <>
struct Fftw<float> {
  using Complex = fftwf_complex;
  using Plan = fftwf_plan;
  static float* alloc_real(std::size_t n) { return fftwf_alloc_real(n); }
  static Complex* alloc_complex(std::size_t n) { return fftwf_alloc_complex(n); }
  static void free(void* p) { fftwf_free(p); }
  static Plan plan_r2c(int n, float* in, Complex* out, unsigned flags) {
    return fftwf_plan_dft_r2c_1d(n, in, out, flags);
  }
  static Plan plan_c2c_backward(int n, Complex* in, Complex* out, unsigned flags) {
    return fftwf_plan_dft_1d(n, in, out, FFTW_BACKWARD, flags);
  }
  static Plan plan_c2c_forward(int n, Complex* in, Complex* out, unsigned flags) {
    return fftwf_plan_dft_1d(n, in, out, FFTW_FORWARD, flags);
  }
  static Plan plan_c2c_backward_many(int n, int howmany, Complex* in, Complex* out, unsigned flags) {
    return fftwf_plan_many_dft(1, &n, howmany, in, nullptr, 1, n, out, nullptr, 1, n, FFTW_BACKWARD, flags);
  }
  static void execute(Plan p) { fftwf_execute(p); }
  static void destroy(Plan p) { fftwf_destroy_plan(p); }
};

bool is_smooth(std::size_t n, std::initializer_list<std::size_t> primes) {
  for (std::size_t p : primes) {
    while (n % p == 0) n /= p;
  }
  return n == 1;
}

// Smallest n' >= n whose only prime factors are 2, 3, 5 (the lengths FFTW transforms fastest: a
// factor 7^2 made a measured plan about twice as slow, docs/performance.md "cwt").
std::size_t next_fast_size(std::size_t n) {
  if (n <= 1) return 1;
  while (!is_smooth(n, {2, 3, 5})) ++n;
  return n;
}

// Largest r <= limit (r >= 1) with only prime factors 2, 3, 5, 7.
std::size_t prev_fast_size(std::size_t limit) {
  std::size_t r = std::max<std::size_t>(limit, 1);
  while (!is_smooth(r, {2, 3, 5, 7})) --r;
  return r;
}

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("MorletCwt: " + what);
}

}  // namespace

std::vector<double> make_frequency_grid(double f_min_hz, double f_max_hz, std::size_t count,
                                        GridSpacing spacing) {
  if (!(std::isfinite(f_min_hz) && std::isfinite(f_max_hz) && f_min_hz > 0.0))
    throw std::invalid_argument("frequency grid: f_min_hz and f_max_hz must be finite and > 0");
  if (count == 0) throw std::invalid_argument("frequency grid: count must be >= 1");
  if (count == 1) {
    if (f_min_hz != f_max_hz)
      throw std::invalid_argument("frequency grid: count == 1 needs f_min_hz == f_max_hz");
    return {f_min_hz};
  }
  if (!(f_max_hz > f_min_hz))
    throw std::invalid_argument("frequency grid: f_max_hz must be greater than f_min_hz");
  std::vector<double> f(count);
  const double last = static_cast<double>(count - 1);
  for (std::size_t i = 0; i < count; ++i) {
    const double u = static_cast<double>(i) / last;
    f[i] = spacing == GridSpacing::linear ? f_min_hz + u * (f_max_hz - f_min_hz)
                                          : f_min_hz * std::pow(f_max_hz / f_min_hz, u);
  }
  f.back() = f_max_hz;
  return f;
}

namespace {

template <typename In>
double decimate_half_121_impl(std::span<const In> x, std::span<double> y, std::span<float> y_float) {
  const std::size_t n = x.size(), m_out = (n + 1) / 2;
  if (y.size() < m_out || (!y_float.empty() && y_float.size() < m_out))
    throw std::invalid_argument("decimate_half_121: output too short");
  if (n == 0) return 0.0;
  auto at = [&](std::size_t i) { return i < n ? static_cast<double>(x[i]) : 0.0; };
  double peak = 0.0;
  // m = 0 and the outputs from n / 2 on read x[-1] = 0 or x[n] = 0; the interior m in [1, n / 2)
  // (2m + 1 <= n - 1) reads in-range samples only.
  const std::size_t inner_end = std::max<std::size_t>(n / 2, 1);
  auto edge = [&](std::size_t m) {
    const double left = m == 0 ? 0.0 : static_cast<double>(x[2 * m - 1]);
    const double mid = static_cast<double>(x[2 * m]);
    y[m] = 0.25 * (left + at(2 * m + 1)) + 0.5 * mid;
    if (!y_float.empty()) y_float[m] = static_cast<float>(y[m]);
    peak = std::max(peak, std::max(std::abs(mid), std::abs(at(2 * m + 1))));
  };
  edge(0);
  const double inner = kernels::half_rate_121(x.data(), y.data(), y_float.empty() ? nullptr : y_float.data(), 1, inner_end);
  for (std::size_t m = inner_end; m < m_out; ++m) edge(m);
  return std::max(peak, inner);
}

}  // namespace

double decimate_half_121(std::span<const double> x, std::span<double> y, std::span<float> y_float) {
  return decimate_half_121_impl(x, y, y_float);
}
double decimate_half_121(std::span<const float> x, std::span<double> y, std::span<float> y_float) {
  return decimate_half_121_impl(x, y, y_float);
}

template <typename Real>
struct MorletCwt<Real>::Impl {
  using F = Fftw<Real>;
  MorletCwtConfig cfg;
  double truncation = 0.0;         // effective Gaussian truncation level (config or mode default)
  std::size_t fft_len = 0;         // L
  std::size_t dec = 1;             // R
  std::size_t short_len = 0;       // D = L / R
  double band_halfwidth_sd = 0.0;  // c: Gaussian kept within +-c standard deviations
  std::size_t n_loaded = 0;

  Real* time_buf = nullptr;                  // L reals
  typename F::Complex* spectrum = nullptr;   // L/2 + 1
  typename F::Complex* work = nullptr;       // D: one row's folded band
  // D: its inverse transform. Out of place: FFTW's in-place plans for some lengths (80 at the rig's
  // rates) allocate a buffer inside every execute, which breaks the real-time contract.
  typename F::Complex* work_out = nullptr;
  Real* weights = nullptr;                   // min(D, L/2 + 1): one row's filter gains
  // Half-rate input: 1 / H(f_k) for k = 0..L/2, H(f) = cos^2(pi f / (2 fs)) (empty otherwise).
  std::vector<Real> inv_prefilter;
  typename F::Plan forward = nullptr;
  // Band-limited mode with even L: the forward transform as a complex FFT of the L/2 pairs
  // z[m] = x[2m] + i x[2m+1] (into half_spec), unpacked only for bins 0..k_used (every bin a row up to
  // band_limit() reads): X[k] = E[k] + e^{-2 pi i k / L} O[k], E = (Z[k] + conj Z[L/2-k]) / 2,
  // O = (Z[k] - conj Z[L/2-k]) / (2i). Used because FFTW's estimated r2c plans of some lengths (1200
  // points, the analyzer's half rate) are much slower than the complex plan of half the length
  // (docs/performance.md, "cwt").
  typename F::Complex* half_spec = nullptr;  // L/2
  std::vector<Real> unpack_twiddle;          // e^{-2 pi i k / L}, k = 0..k_used, interleaved re, im
  std::size_t k_used = 0;
  typename F::Plan backward = nullptr;
  // All configured rows at once (band-limited mode with cached gains): one batched inverse FFT.
  typename F::Complex* grid_work = nullptr;      // rows x D
  typename F::Complex* grid_work_out = nullptr;  // rows x D
  typename F::Plan grid_backward = nullptr;

  // Lanes of the Gaussian recurrence (independent chains, so the compiler can vectorise them).
  static constexpr std::size_t kLanes = 8;

  ~Impl() {
    std::lock_guard<std::mutex> lock(fftw_planner_mutex());
    if (forward) F::destroy(forward);
    F::free(half_spec);
    if (backward) F::destroy(backward);
    if (grid_backward) F::destroy(grid_backward);
    F::free(grid_work);
    F::free(grid_work_out);
    F::free(time_buf);
    F::free(spectrum);
    F::free(work);
    F::free(work_out);
    F::free(weights);
  }

  // Bins [k_lo, k_hi] where the row's Gaussian exceeds the truncation level, and a = s * d(omega)/dk.
  void band(double f_hz, std::size_t& k_lo, std::size_t& k_hi, double& a) const {
    const double L = static_cast<double>(fft_len);
    const double s = cfg.eta0 / (2.0 * std::numbers::pi * f_hz);
    a = s * 2.0 * std::numbers::pi * cfg.sample_rate_hz / L;
    const double k_center = cfg.eta0 / a;
    const double half = band_halfwidth_sd / a;
    const double lo = std::max(0.0, std::ceil(k_center - half));
    const double hi = std::min(static_cast<double>(fft_len / 2), std::floor(k_center + half));
    k_lo = static_cast<std::size_t>(lo);
    k_hi = static_cast<std::size_t>(std::max(lo, hi));
  }

  // Kept band width divided by the row frequency (the band is [f (1 - c/eta0), f (1 + c/eta0)], cut at DC).
  double relative_band_width() const {
    const double r = band_halfwidth_sd / cfg.eta0;
    return (1.0 + r) - std::max(1.0 - r, 0.0);
  }

  // Largest row frequency whose kept band fits into D bins of spacing fs / L: the band of row f spans at
  // most relative_band_width() * f * L / fs + 1 bins.
  double band_limit() const {
    if (dec == 1) return cfg.sample_rate_hz / 2;
    const double f = static_cast<double>(short_len - 1) * cfg.sample_rate_hz /
                     (static_cast<double>(fft_len) * relative_band_width());
    return std::min(cfg.sample_rate_hz / 2, f);
  }

  // weights[i] = (2 / L) exp(-(a (k_lo + i) - eta0)^2 / 2), i < count: the analytic gain 2 of the filter
  // and FFTW's missing 1/L of the inverse transform. kLanes interleaved recurrences with stride m:
  //   g(k + m) = g(k) q(k),  q(k + m) = q(k) exp(-a^2 m^2),  q(k) = exp(-a m (a k - eta0) - a^2 m^2 / 2),
  // each chain taking count / m steps (relative round-off ~ (count/m)^2 eps, < 1e-9 for count < 1e6).
  void fill_weights(std::size_t k_lo, std::size_t count, double a) {
    constexpr std::size_t m = kLanes;
    const double md = static_cast<double>(m);
    const double gain = 2.0 / static_cast<double>(fft_len);
    const double step = std::exp(-a * a * md * md);
    double g[m], q[m];
    for (std::size_t j = 0; j < m; ++j) {
      const double u = a * static_cast<double>(k_lo + j) - cfg.eta0;
      g[j] = gain * std::exp(-0.5 * u * u);
      q[j] = std::exp(-a * md * u - 0.5 * a * a * md * md);
    }
    std::size_t i = 0;
    for (; i + m <= count; i += m) {
      for (std::size_t j = 0; j < m; ++j) {
        weights[i + j] = static_cast<Real>(g[j]);
        g[j] *= q[j];
        q[j] *= step;
      }
    }
    for (std::size_t j = 0; i + j < count; ++j) weights[i + j] = static_cast<Real>(g[j]);
  }

  // dst[i] = weights[i] * src[i] for `count` complex values.
  static void weigh(const Real* w, const typename F::Complex* src, typename F::Complex* dst,
                    std::size_t count) {
    for (std::size_t i = 0; i < count; ++i) {
      dst[i][0] = w[i] * src[i][0];
      dst[i][1] = w[i] * src[i][1];
    }
  }

  // Filter gains of row f: weights[0..count) for bins k_lo.., with the half weights on the jump of the
  // analytic filter (DC, and Nyquist for even L): the DFT of the sampled, periodised analytic kernel
  // takes the mid value there (Fourier series at a jump).
  void row_weights(double f_hz, std::size_t& k_lo, std::size_t& count) {
    std::size_t k_hi = 0;
    double a = 0.0;
    band(f_hz, k_lo, k_hi, a);
    count = k_hi - k_lo + 1;
    if (count > short_len || (half_spec && k_hi > k_used))
      throw std::invalid_argument("MorletCwt::row: frequency " + std::to_string(f_hz) +
                                  " Hz exceeds the band-limited grid (max " +
                                  std::to_string(band_limit()) + " Hz)");
    fill_weights(k_lo, count, a);
    if (!inv_prefilter.empty())
      for (std::size_t i = 0; i < count; ++i) weights[i] *= inv_prefilter[k_lo + i];
    if (k_lo == 0) weights[0] *= Real{0.5};
    if (fft_len % 2 == 0 && k_hi == fft_len / 2) weights[count - 1] *= Real{0.5};
  }

  // spectrum[k] for k = 0..k_used from the half-length complex transform (see half_spec).
  void unpack() {
    const std::size_t h = fft_len / 2;
    const Real* tw = unpack_twiddle.data();
    auto bin = [&](std::size_t k, std::size_t kz, std::size_t kc) {
      const Real zr = half_spec[kz][0], zi = half_spec[kz][1];
      const Real cr = half_spec[kc][0], ci = -half_spec[kc][1];  // conj Z[(h - k) mod h]
      const Real er = Real{0.5} * (zr + cr), ei = Real{0.5} * (zi + ci);
      const Real orr = Real{0.5} * (zi - ci), oi = Real{-0.5} * (zr - cr);  // (Z - conj Zc) / (2i)
      const Real wr = tw[2 * k], wi = tw[2 * k + 1];
      spectrum[k][0] = er + (wr * orr - wi * oi);
      spectrum[k][1] = ei + (wr * oi + wi * orr);
    };
    bin(0, 0, 0);
    const std::size_t last = std::min(k_used, h - 1);
    for (std::size_t k = 1; k <= last; ++k) bin(k, k, h - k);
    if (k_used == h) bin(h, 0, 0);
  }

  void compute_row(double f_hz, std::complex<Real>* out, std::size_t n_out) {
    std::size_t k_lo = 0, count = 0;
    row_weights(f_hz, k_lo, count);
    apply_row(k_lo, count, weights, out, n_out);
  }

  // Configured rows: their gains are made once (cache_grid) and reused by every load.
  std::vector<Real> grid_weights;
  std::vector<std::size_t> grid_offset, grid_k_lo, grid_count;
  void cache_grid() {
    const std::vector<double>& f = cfg.frequencies_hz;
    std::size_t total = 0;
    grid_offset.resize(f.size());
    grid_k_lo.resize(f.size());
    grid_count.resize(f.size());
    for (std::size_t r = 0; r < f.size(); ++r) {
      std::size_t k_hi = 0;
      double a = 0.0;
      band(f[r], grid_k_lo[r], k_hi, a);
      grid_count[r] = k_hi - grid_k_lo[r] + 1;
      grid_offset[r] = total;
      total += grid_count[r];
    }
    if (total > (std::size_t{1} << 22)) {  // > 32 MB: compute per call instead
      grid_offset.clear();
      return;
    }
    grid_weights.resize(total);
    for (std::size_t r = 0; r < f.size(); ++r) {
      std::size_t k_lo = 0, count = 0;
      row_weights(f[r], k_lo, count);
      std::copy(weights, weights + count, grid_weights.begin() + static_cast<std::ptrdiff_t>(grid_offset[r]));
    }
  }
  void compute_grid_row(std::size_t r, std::complex<Real>* out, std::size_t n_out) {
    if (grid_offset.empty()) return compute_row(cfg.frequencies_hz[r], out, n_out);
    apply_row(grid_k_lo[r], grid_count[r], grid_weights.data() + grid_offset[r], out, n_out);
  }

  // Folds the weighted band of a row into the D slots of `dst` (the inverse FFT's input).
  void fold_row(std::size_t k_lo, std::size_t count, const Real* w, typename F::Complex* dst) const {
    // Bin k goes to slot k mod D: the band occupies `count` consecutive slots (mod D) starting at s0,
    // i.e. at most two contiguous runs; only the remaining slots need zeroing.
    const std::size_t s0 = k_lo % short_len;
    const std::size_t first = std::min(count, short_len - s0);
    const std::size_t second = count - first;
    weigh(w, spectrum + k_lo, dst + s0, first);
    weigh(w + first, spectrum + k_lo + first, dst, second);
    if (s0 > second)
      std::memset(static_cast<void*>(dst + second), 0, sizeof(typename F::Complex) * (s0 - second));
    if (second == 0 && s0 + first < short_len)
      std::memset(static_cast<void*>(dst + s0 + first), 0,
                  sizeof(typename F::Complex) * (short_len - s0 - first));
  }

  // All configured rows into out (rows x n_out, row-major) with one batched inverse FFT.
  void compute_grid(std::complex<Real>* out, std::size_t n_out) {
    const std::size_t rows = cfg.frequencies_hz.size();
    if (!grid_backward) {
      for (std::size_t r = 0; r < rows; ++r) compute_grid_row(r, out + r * n_out, n_out);
      return;
    }
    for (std::size_t r = 0; r < rows; ++r)
      fold_row(grid_k_lo[r], grid_count[r], grid_weights.data() + grid_offset[r], grid_work + r * short_len);
    F::execute(grid_backward);
    for (std::size_t r = 0; r < rows; ++r)
      std::memcpy(static_cast<void*>(out + r * n_out), static_cast<const void*>(grid_work_out + r * short_len),
                  sizeof(std::complex<Real>) * n_out);
  }

  void apply_row(std::size_t k_lo, std::size_t count, const Real* w, std::complex<Real>* out, std::size_t n_out) {
    fold_row(k_lo, count, w, work);
    F::execute(backward);
    // fftw_complex and std::complex<Real> have the same layout (both are Real[2]).
    std::memcpy(static_cast<void*>(out), static_cast<const void*>(work_out), sizeof(std::complex<Real>) * n_out);
  }
};

template <typename Real>
typename MorletCwt<Real>::Layout MorletCwt<Real>::layout(const MorletCwtConfig& c) {
  // The same arithmetic as Impl's truncation(), relative_band_width() and band_limit().
  double f_min = c.frequencies_hz.empty() ? 1.0 : c.frequencies_hz.front(), f_max = f_min;
  for (double f : c.frequencies_hz) {
    f_min = std::min(f_min, f);
    f_max = std::max(f_max, f);
  }
  const double truncation = c.truncation != 0.0 ? c.truncation
                            : c.band_limited    ? MorletCwtConfig::kBandLimitedTruncation
                                                : MorletCwtConfig::kFullRateTruncation;
  const double halfwidth_sd = std::sqrt(2.0 * std::log(1.0 / truncation));
  const double rel_r = halfwidth_sd / c.eta0;
  const double rel_width = (1.0 + rel_r) - std::max(1.0 - rel_r, 0.0);
  Layout out;
  auto band_limit = [&] {
    if (out.decimation == 1) return c.sample_rate_hz / 2;
    const double f = static_cast<double>(out.short_length - 1) * c.sample_rate_hz /
                     (static_cast<double>(out.fft_length) * rel_width);
    return std::min(c.sample_rate_hz / 2, f);
  };
  // Zero padding so that the circular convolution never wraps: the kernel at the lowest frequency
  // falls below the truncation level c * s seconds from its centre.
  const double s_max = MorletCwt::kernel_time_sd_s(c.eta0, f_min);
  auto pad = static_cast<std::size_t>(
      std::ceil(halfwidth_sd * s_max * c.sample_rate_hz)) + 2;
  // When eta0 < band_halfwidth_sd the kept band reaches DC, where the analytic filter jumps by
  // 2 exp(-eta0^2/2); its kernel then has a slowly decaying (1/tau) tail that no Gaussian-sized padding
  // contains. Padding by a further max_samples keeps the wrapped part of that tail below ~3e-6 of
  // max |W| even for a DC-dominated record (eta0 = 5; measured in test_morlet_cwt).
  if (c.eta0 < halfwidth_sd) pad += c.max_samples;
  const std::size_t needed = c.max_samples + pad;

  if (c.band_limited) {
    // Largest R (2,3,5,7-smooth, so that L = D R stays a fast r2c length) for which the widest band,
    // that of f_max, fits into D = L / R bins; D itself is the next 2,3,5-smooth length (FFTW's
    // fastest sizes) holding the padded signal.
    const double r_upper = std::floor(c.sample_rate_hz / (rel_width * f_max));
    std::size_t r = prev_fast_size(static_cast<std::size_t>(std::max(1.0, r_upper)));
    for (;;) {
      out.decimation = r;
      out.short_length = next_fast_size((needed + r - 1) / r);
      out.fft_length = out.short_length * r;
      if (r == 1 || band_limit() >= f_max) break;
      r = prev_fast_size(r - 1);
    }
  } else {
    out.decimation = 1;
    out.fft_length = next_fast_size(needed);
    out.short_length = out.fft_length;
  }

  return out;
}

template <typename Real>
MorletCwt<Real>::MorletCwt(MorletCwtConfig config) : impl_(std::make_unique<Impl>()) {
  auto& c = config;
  require(std::isfinite(c.sample_rate_hz) && c.sample_rate_hz > 0, "sample_rate_hz must be > 0");
  if (c.fine_resolution)
    require(std::isfinite(c.eta0) && c.eta0 >= 5.0 && c.eta0 <= 1000.0, "eta0 must be in [5, 1000]");
  else
    require(std::isfinite(c.eta0) && c.eta0 >= 5.0 && c.eta0 <= 50.0, "eta0 must be in [5, 50]");
  require(!c.frequencies_hz.empty(), "frequencies_hz must not be empty");
  require(c.max_samples > 0, "max_samples must be > 0");
  require(c.max_samples < (std::size_t{1} << 30), "max_samples must be < 2^30");
  require(c.truncation == 0.0 ||
              (std::isfinite(c.truncation) && c.truncation >= 1e-14 && c.truncation <= 1e-2),
          "truncation must be 0 (mode default) or in [1e-14, 1e-2]");
  double f_min = c.frequencies_hz.front(), f_max = f_min;
  for (double f : c.frequencies_hz) {
    require(std::isfinite(f) && f > 0 && f < c.sample_rate_hz / 2,
            "every frequency must satisfy 0 < f < sample_rate_hz/2 (got " + std::to_string(f) + ")");
    f_min = std::min(f_min, f);
    f_max = std::max(f_max, f);
  }
  Impl& im = *impl_;
  im.cfg = std::move(config);
  im.truncation = im.cfg.truncation != 0.0 ? im.cfg.truncation
                  : im.cfg.band_limited    ? MorletCwtConfig::kBandLimitedTruncation
                                           : MorletCwtConfig::kFullRateTruncation;
  im.band_halfwidth_sd = std::sqrt(2.0 * std::log(1.0 / im.truncation));

  const Layout lay = layout(im.cfg);
  im.dec = lay.decimation;
  im.fft_len = lay.fft_length;
  im.short_len = lay.short_length;

  std::lock_guard<std::mutex> lock(fftw_planner_mutex());
  using F = typename Impl::F;
  im.time_buf = F::alloc_real(im.fft_len);
  im.spectrum = F::alloc_complex(im.fft_len / 2 + 1);
  im.work = F::alloc_complex(im.short_len);
  im.work_out = F::alloc_complex(im.short_len);
  im.weights = F::alloc_real(std::min(im.short_len, im.fft_len / 2 + 1));
  if (!im.time_buf || !im.spectrum || !im.work || !im.work_out || !im.weights) throw std::bad_alloc();
  if (im.cfg.half_rate_121_input) {
    // Bin k of L at fs is at f = k fs / L; H = cos^2(pi f / (2 fs)) = cos^2(pi k / (2 L)) >= 1/2 up to
    // the Nyquist bin, so the compensation is at most 2.
    im.inv_prefilter.resize(im.fft_len / 2 + 1);
    for (std::size_t k = 0; k < im.inv_prefilter.size(); ++k) {
      const double ck = std::cos(std::numbers::pi * static_cast<double>(k) / (2.0 * static_cast<double>(im.fft_len)));
      im.inv_prefilter[k] = static_cast<Real>(1.0 / (ck * ck));
    }
  }
  const unsigned flags = im.cfg.measure_plans ? FFTW_MEASURE : FFTW_ESTIMATE;
  if (im.cfg.band_limited && im.dec > 1 && im.fft_len % 2 == 0) {
    // Highest bin any row up to band_limit() reads (its band's top), and every configured row's.
    std::size_t k_lo = 0, k_hi = 0;
    double a = 0.0;
    im.band(im.band_limit(), k_lo, k_hi, a);
    im.k_used = k_hi;
    for (double f : im.cfg.frequencies_hz) {
      im.band(f, k_lo, k_hi, a);
      im.k_used = std::max(im.k_used, k_hi);
    }
    im.k_used = std::min(im.k_used, im.fft_len / 2);
    im.unpack_twiddle.resize(2 * (im.k_used + 1));
    for (std::size_t k = 0; k <= im.k_used; ++k) {
      const double ph = -2.0 * std::numbers::pi * static_cast<double>(k) / static_cast<double>(im.fft_len);
      im.unpack_twiddle[2 * k] = static_cast<Real>(std::cos(ph));
      im.unpack_twiddle[2 * k + 1] = static_cast<Real>(std::sin(ph));
    }
    im.half_spec = F::alloc_complex(im.fft_len / 2);
    if (!im.half_spec) throw std::bad_alloc();
    im.forward = F::plan_c2c_forward(static_cast<int>(im.fft_len / 2),
                                     reinterpret_cast<typename F::Complex*>(im.time_buf), im.half_spec, flags);
  } else {
    im.forward = F::plan_r2c(static_cast<int>(im.fft_len), im.time_buf, im.spectrum, flags);
  }
  im.backward = F::plan_c2c_backward(static_cast<int>(im.short_len), im.work, im.work_out, flags);
  if (!im.forward || !im.backward) throw std::runtime_error("MorletCwt: FFTW could not make a plan");
  im.cache_grid();
  // Batched plan for all configured rows, when their gains are cached and the batch is small (the
  // impact analyzer's 14 rows of 80 slots; full transforms keep one row at a time).
  const std::size_t n_rows = im.cfg.frequencies_hz.size();
  if (!im.grid_offset.empty() && n_rows > 1 && n_rows * im.short_len <= (std::size_t{1} << 16)) {
    im.grid_work = F::alloc_complex(n_rows * im.short_len);
    im.grid_work_out = F::alloc_complex(n_rows * im.short_len);
    if (!im.grid_work || !im.grid_work_out) throw std::bad_alloc();
    im.grid_backward = F::plan_c2c_backward_many(static_cast<int>(im.short_len), static_cast<int>(n_rows),
                                                 im.grid_work, im.grid_work_out, flags);
    if (!im.grid_backward) throw std::runtime_error("MorletCwt: FFTW could not make a plan");
  }
}

template <typename Real>
MorletCwt<Real>::~MorletCwt() = default;
template <typename Real>
MorletCwt<Real>::MorletCwt(MorletCwt&&) noexcept = default;
template <typename Real>
MorletCwt<Real>& MorletCwt<Real>::operator=(MorletCwt&&) noexcept = default;

template <typename Real>
void MorletCwt<Real>::load(std::span<const Real> signal) {
  Impl& im = *impl_;
  if (signal.empty() || signal.size() > im.cfg.max_samples)
    throw std::invalid_argument("MorletCwt::load: signal length " + std::to_string(signal.size()) +
                                " outside [1, max_samples=" + std::to_string(im.cfg.max_samples) +
                                "]");
  std::copy(signal.begin(), signal.end(), im.time_buf);
  std::fill(im.time_buf + signal.size(), im.time_buf + im.fft_len, Real{0});
  Impl::F::execute(im.forward);
  if (im.half_spec) im.unpack();
  im.n_loaded = signal.size();
}

template <typename Real>
void MorletCwt<Real>::row(double f_hz, std::span<std::complex<Real>> out) {
  Impl& im = *impl_;
  if (im.n_loaded == 0) throw std::logic_error("MorletCwt::row called before load");
  if (!(f_hz > 0 && f_hz < im.cfg.sample_rate_hz / 2))
    throw std::invalid_argument("MorletCwt::row: frequency must be in (0, fs/2)");
  if (out.size() < columns()) throw std::invalid_argument("MorletCwt::row: output too short");
  im.compute_row(f_hz, out.data(), columns());
}

template <typename Real>
void MorletCwt<Real>::transform(std::span<const Real> signal, Scalogram<Real>& out) {
  load(signal);
  const Impl& im = *impl_;
  out.resize(im.cfg.frequencies_hz.size(), columns());
  out.time_step_s = time_step_s();
  out.decimation = im.dec;
  out.frequencies_hz.assign(im.cfg.frequencies_hz.begin(), im.cfg.frequencies_hz.end());
  for (std::size_t r = 0; r < out.rows; ++r) impl_->compute_grid_row(r, out.data.data() + r * out.cols, out.cols);
}

template <typename Real>
void MorletCwt<Real>::row_at(std::size_t index, std::span<std::complex<Real>> out) {
  Impl& im = *impl_;
  if (im.n_loaded == 0) throw std::logic_error("MorletCwt::row_at called before load");
  if (index >= im.cfg.frequencies_hz.size()) throw std::invalid_argument("MorletCwt::row_at: index out of range");
  if (out.size() < columns()) throw std::invalid_argument("MorletCwt::row_at: output too short");
  im.compute_grid_row(index, out.data(), columns());
}

template <typename Real>
void MorletCwt<Real>::grid_rows(std::span<std::complex<Real>> out) {
  Impl& im = *impl_;
  if (im.n_loaded == 0) throw std::logic_error("MorletCwt::grid_rows called before load");
  if (out.size() < im.cfg.frequencies_hz.size() * columns())
    throw std::invalid_argument("MorletCwt::grid_rows: output too short");
  im.compute_grid(out.data(), columns());
}

template <typename Real>
std::size_t MorletCwt<Real>::columns() const {
  return (impl_->n_loaded + impl_->dec - 1) / impl_->dec;
}
template <typename Real>
std::size_t MorletCwt<Real>::decimation() const {
  return impl_->dec;
}
template <typename Real>
double MorletCwt<Real>::time_step_s() const {
  return static_cast<double>(impl_->dec) / impl_->cfg.sample_rate_hz;
}
template <typename Real>
double MorletCwt<Real>::sample_rate_hz() const {
  return impl_->cfg.sample_rate_hz;
}
template <typename Real>
double MorletCwt<Real>::eta0() const {
  return impl_->cfg.eta0;
}
template <typename Real>
const std::vector<double>& MorletCwt<Real>::frequencies_hz() const {
  return impl_->cfg.frequencies_hz;
}
template <typename Real>
double MorletCwt<Real>::band_limit_hz() const {
  return impl_->band_limit();
}
template <typename Real>
double MorletCwt<Real>::truncation() const {
  return impl_->truncation;
}
template <typename Real>
std::size_t MorletCwt<Real>::fft_length() const {
  return impl_->fft_len;
}
template <typename Real>
double MorletCwt<Real>::kernel_time_sd_s(double eta0, double f_hz) {
  return eta0 / (2.0 * std::numbers::pi * f_hz);
}
template <typename Real>
double MorletCwt<Real>::kernel_freq_sd_hz(double eta0, double f_hz) {
  return f_hz / eta0;
}

template <typename Real>
double MorletCwt<Real>::noise_gain(double f_hz) const {
  const Impl& im = *impl_;
  std::size_t k_lo = 0, k_hi = 0;
  double a = 0.0;
  im.band(f_hz, k_lo, k_hi, a);
  double sum = 0.0;
  for (std::size_t k = k_lo; k <= k_hi; ++k) {
    const double u = a * static_cast<double>(k) - im.cfg.eta0;
    double w = (k == 0 || (im.fft_len % 2 == 0 && k == im.fft_len / 2)) ? 0.25 : 1.0;
    if (im.cfg.half_rate_121_input) {
      // Per unit variance of the full-rate x: y's density (H^2 + H'^2) / 2 over the compensation H^2.
      const double t = std::numbers::pi * static_cast<double>(k) / (2.0 * static_cast<double>(im.fft_len));
      const double h = std::cos(t) * std::cos(t), h_image = std::sin(t) * std::sin(t);
      w *= (h * h + h_image * h_image) / (2.0 * h * h);
    }
    sum += w * 4.0 * std::exp(-u * u);
  }
  return sum / static_cast<double>(im.fft_len);
}

template class MorletCwt<double>;
template class MorletCwt<float>;

}  // namespace ridgewatch::dsp
