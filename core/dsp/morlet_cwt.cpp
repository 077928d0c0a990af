#include "core/dsp/morlet_cwt.hpp"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <numbers>
#include <stdexcept>
#include <string>

namespace ridgewatch::dsp {

namespace {

// FFTW's planner is not thread-safe; plan creation and destruction are serialised here so that
// transforms may be constructed from any thread. Executing plans is thread-safe.
std::mutex& planner_mutex() {
  static std::mutex m;
  return m;
}

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
  static Plan plan_c2c_backward(int n, Complex* inout, unsigned flags) {
    return fftw_plan_dft_1d(n, inout, inout, FFTW_BACKWARD, flags);
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
  static Plan plan_c2c_backward(int n, Complex* inout, unsigned flags) {
    return fftwf_plan_dft_1d(n, inout, inout, FFTW_BACKWARD, flags);
  }
  static void execute(Plan p) { fftwf_execute(p); }
  static void destroy(Plan p) { fftwf_destroy_plan(p); }
};

bool is_fast_size(std::size_t n) {
  for (std::size_t p : {2u, 3u, 5u, 7u}) {
    while (n % p == 0) n /= p;
  }
  return n == 1;
}

// Smallest n' >= n whose only prime factors are 2, 3, 5, 7 (sizes FFTW handles with its fast codelets).
std::size_t next_fast_size(std::size_t n) {
  if (n <= 1) return 1;
  while (!is_fast_size(n)) ++n;
  return n;
}

// Largest r <= limit (r >= 1) with only prime factors 2, 3, 5, 7.
std::size_t prev_fast_size(std::size_t limit) {
  std::size_t r = std::max<std::size_t>(limit, 1);
  while (!is_fast_size(r)) --r;
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

template <typename Real>
struct MorletCwt<Real>::Impl {
  using F = Fftw<Real>;
  MorletCwtConfig cfg;
  std::size_t fft_len = 0;  // L
  std::size_t dec = 1;      // R
  std::size_t short_len = 0;  // D = L / R
  double band_halfwidth_sd = 0.0;  // c: Gaussian kept within +-c standard deviations
  std::size_t n_loaded = 0;

  Real* time_buf = nullptr;                  // L reals
  typename F::Complex* spectrum = nullptr;   // L/2 + 1
  typename F::Complex* work = nullptr;       // D
  typename F::Plan forward = nullptr;
  typename F::Plan backward = nullptr;

  ~Impl() {
    std::lock_guard<std::mutex> lock(planner_mutex());
    if (forward) F::destroy(forward);
    if (backward) F::destroy(backward);
    F::free(time_buf);
    F::free(spectrum);
    F::free(work);
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

  double band_width_hz(double f_hz) const {
    const double f_hi = std::min(f_hz * (1.0 + band_halfwidth_sd / cfg.eta0), cfg.sample_rate_hz / 2);
    const double f_lo = std::max(f_hz * (1.0 - band_halfwidth_sd / cfg.eta0), 0.0);
    return f_hi - f_lo;
  }

  void compute_row(double f_hz, std::complex<Real>* out, std::size_t n_out) {
    std::size_t k_lo = 0, k_hi = 0;
    double a = 0.0;
    band(f_hz, k_lo, k_hi, a);
    if (k_hi - k_lo + 1 > short_len)
      throw std::invalid_argument("MorletCwt::row: frequency " + std::to_string(f_hz) +
                                  " Hz exceeds the band-limited grid (max " +
                                  std::to_string(band_limit()) + " Hz)");
    std::memset(static_cast<void*>(work), 0, sizeof(typename F::Complex) * short_len);
    // Gaussian exp(-(a k - eta0)^2 / 2) by recurrence: g(k+1) = g(k) r(k), r(k+1) = r(k) exp(-a^2).
    const double u0 = a * static_cast<double>(k_lo) - cfg.eta0;
    double g = std::exp(-0.5 * u0 * u0);
    double r = std::exp(-a * u0 - 0.5 * a * a);
    const double c = std::exp(-a * a);
    const double gain = 2.0 / static_cast<double>(fft_len);  // analytic gain 2, FFTW's missing 1/L
    std::size_t slot = k_lo % short_len;
    for (std::size_t k = k_lo; k <= k_hi; ++k) {
      const double w = gain * g;
      work[slot][0] = static_cast<Real>(w * static_cast<double>(spectrum[k][0]));
      work[slot][1] = static_cast<Real>(w * static_cast<double>(spectrum[k][1]));
      g *= r;
      r *= c;
      if (++slot == short_len) slot = 0;
    }
    // Bins on the jump of the analytic filter (DC, and Nyquist for even L) take half weight.
    for (std::size_t k : {k_lo, k_hi}) {
      if (k == 0 || (fft_len % 2 == 0 && k == fft_len / 2)) {
        work[k % short_len][0] *= Real{0.5};
        work[k % short_len][1] *= Real{0.5};
      }
    }
    F::execute(backward);
    for (std::size_t m = 0; m < n_out; ++m) out[m] = {work[m][0], work[m][1]};
  }

  double band_limit() const {
    if (dec == 1) return cfg.sample_rate_hz / 2;
    // Largest f whose band width stays below fs / R with the same margin used in the constructor.
    const double max_width = 0.95 * cfg.sample_rate_hz / static_cast<double>(dec);
    return std::min(cfg.sample_rate_hz / 2, max_width / (2.0 * band_halfwidth_sd / cfg.eta0));
  }
};

template <typename Real>
MorletCwt<Real>::MorletCwt(MorletCwtConfig config) : impl_(std::make_unique<Impl>()) {
  auto& c = config;
  require(std::isfinite(c.sample_rate_hz) && c.sample_rate_hz > 0, "sample_rate_hz must be > 0");
  require(std::isfinite(c.eta0) && c.eta0 >= 5.0 && c.eta0 <= 50.0, "eta0 must be in [5, 50]");
  require(!c.frequencies_hz.empty(), "frequencies_hz must not be empty");
  require(c.max_samples > 0, "max_samples must be > 0");
  require(c.max_samples < (std::size_t{1} << 30), "max_samples must be < 2^30");
  require(std::isfinite(c.truncation) && c.truncation >= 1e-14 && c.truncation <= 1e-2,
          "truncation must be in [1e-14, 1e-2]");
  double f_min = c.frequencies_hz.front(), f_max = f_min;
  for (double f : c.frequencies_hz) {
    require(std::isfinite(f) && f > 0 && f < c.sample_rate_hz / 2,
            "every frequency must satisfy 0 < f < sample_rate_hz/2 (got " + std::to_string(f) + ")");
    f_min = std::min(f_min, f);
    f_max = std::max(f_max, f);
  }
  Impl& im = *impl_;
  im.cfg = std::move(config);
  im.band_halfwidth_sd = std::sqrt(2.0 * std::log(1.0 / im.cfg.truncation));

  // Zero padding so that the circular convolution never wraps: the kernel at the lowest frequency
  // falls below the truncation level c * s seconds from its centre.
  const double s_max = MorletCwt::kernel_time_sd_s(im.cfg.eta0, f_min);
  auto pad = static_cast<std::size_t>(
      std::ceil(im.band_halfwidth_sd * s_max * im.cfg.sample_rate_hz)) + 2;
  // When eta0 < band_halfwidth_sd the kept band reaches DC, where the analytic filter jumps by
  // 2 exp(-eta0^2/2); its kernel then has a slowly decaying (1/tau) tail that no Gaussian-sized padding
  // contains. Padding by a further max_samples keeps the wrapped part of that tail below ~3e-6 of
  // max |W| even for a DC-dominated record (eta0 = 5; measured in test_morlet_cwt).
  if (im.cfg.eta0 < im.band_halfwidth_sd) pad += im.cfg.max_samples;
  const std::size_t needed = im.cfg.max_samples + pad;

  if (im.cfg.band_limited) {
    double max_width = 0.0;
    for (double f : im.cfg.frequencies_hz) max_width = std::max(max_width, im.band_width_hz(f));
    // R <= fs / width keeps every row's band inside D = L / R bins; 5 % margin for bin rounding.
    const double r_limit = std::floor(0.95 * im.cfg.sample_rate_hz / max_width);
    im.dec = prev_fast_size(static_cast<std::size_t>(std::max(1.0, r_limit)));
    im.short_len = next_fast_size((needed + im.dec - 1) / im.dec);
    im.fft_len = im.short_len * im.dec;
  } else {
    im.dec = 1;
    im.fft_len = next_fast_size(needed);
    im.short_len = im.fft_len;
  }

  std::lock_guard<std::mutex> lock(planner_mutex());
  using F = typename Impl::F;
  im.time_buf = F::alloc_real(im.fft_len);
  im.spectrum = F::alloc_complex(im.fft_len / 2 + 1);
  im.work = F::alloc_complex(im.short_len);
  if (!im.time_buf || !im.spectrum || !im.work) throw std::bad_alloc();
  const unsigned flags = im.cfg.measure_plans ? FFTW_MEASURE : FFTW_ESTIMATE;
  im.forward = F::plan_r2c(static_cast<int>(im.fft_len), im.time_buf, im.spectrum, flags);
  im.backward = F::plan_c2c_backward(static_cast<int>(im.short_len), im.work, flags);
  if (!im.forward || !im.backward) throw std::runtime_error("MorletCwt: FFTW could not make a plan");
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
  for (std::size_t r = 0; r < out.rows; ++r)
    impl_->compute_row(im.cfg.frequencies_hz[r], out.data.data() + r * out.cols, out.cols);
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
    const double w = (k == 0 || (im.fft_len % 2 == 0 && k == im.fft_len / 2)) ? 0.25 : 1.0;
    sum += w * 4.0 * std::exp(-u * u);
  }
  return sum / static_cast<double>(im.fft_len);
}

template class MorletCwt<double>;
template class MorletCwt<float>;

}  // namespace ridgewatch::dsp
