#include "core/survey/band_envelope.hpp"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <stdexcept>

#include "core/dsp/fftw_planner.hpp"

namespace ridgewatch::survey {

std::size_t nice_fft_size(std::size_t n) {
  if (n <= 1) return 1;
  for (std::size_t m = n;; ++m) {
    std::size_t r = m;
    for (std::size_t p : {2u, 3u, 5u})
      while (r % p == 0) r /= p;
    if (r == 1) return m;
  }
}

// One inverse complex plan per envelope length, with its own aligned buffer (FFTW_ESTIMATE: cheap to
// make; the kurtogram asks for a few dozen distinct lengths).
struct RecordSpectrum::Plans {
  struct Plan {
    fftw_complex* buf = nullptr;
    fftw_plan plan = nullptr;
  };
  std::map<std::size_t, Plan> by_size;
  ~Plans() {
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    for (auto& [m, p] : by_size) {
      fftw_destroy_plan(p.plan);
      fftw_free(p.buf);
    }
  }
  Plan& get(std::size_t m) {
    auto it = by_size.find(m);
    if (it != by_size.end()) return it->second;
    Plan p;
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    p.buf = fftw_alloc_complex(m);
    p.plan = fftw_plan_dft_1d(static_cast<int>(m), p.buf, p.buf, FFTW_BACKWARD, FFTW_ESTIMATE);
    return by_size.emplace(m, p).first->second;
  }
};

RecordSpectrum::RecordSpectrum(std::span<const double> x, double sample_rate_hz)
    : fs_(sample_rate_hz), n_(x.size()), plans_(std::make_unique<Plans>()) {
  if (!(sample_rate_hz > 0) || !std::isfinite(sample_rate_hz))
    throw std::invalid_argument("survey: sample rate must be > 0");
  if (x.size() < 64) throw std::invalid_argument("survey: record too short (< 64 samples)");
  np_ = nice_fft_size(n_);
  if (np_ % 2) np_ = nice_fft_size(np_ + 1);  // even: bin Np/2 is fs/2
  double* in = fftw_alloc_real(np_);
  fftw_complex* out = fftw_alloc_complex(np_ / 2 + 1);
  fftw_plan plan;
  {
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    plan = fftw_plan_dft_r2c_1d(static_cast<int>(np_), in, out, FFTW_ESTIMATE);
  }
  std::copy(x.begin(), x.end(), in);
  std::fill(in + n_, in + np_, 0.0);
  fftw_execute(plan);
  spec_.resize(np_ / 2 + 1);
  for (std::size_t k = 0; k <= np_ / 2; ++k) spec_[k] = {out[k][0], out[k][1]};
  {
    std::lock_guard<std::mutex> lock(dsp::fftw_planner_mutex());
    fftw_destroy_plan(plan);
  }
  fftw_free(in);
  fftw_free(out);
}

RecordSpectrum::~RecordSpectrum() = default;

std::vector<std::complex<double>> RecordSpectrum::envelope(double f_lo_hz, double f_hi_hz, double oversample,
                                                           double& rate_hz) const {
  const double df = bin_hz();
  const auto k_max = static_cast<long long>(np_ / 2);
  const long long k_lo = std::clamp(static_cast<long long>(std::ceil(f_lo_hz / df)), 0LL, k_max);
  const long long k_hi = std::clamp(static_cast<long long>(std::ceil(f_hi_hz / df)), 0LL, k_max + 1);
  rate_hz = NAN;
  if (k_hi <= k_lo) return {};
  const auto bins = static_cast<std::size_t>(k_hi - k_lo);
  const std::size_t m = nice_fft_size(static_cast<std::size_t>(std::ceil(static_cast<double>(bins) * std::max(1.0, oversample))));
  Plans::Plan& p = plans_->get(m);
  std::fill(reinterpret_cast<double*>(p.buf), reinterpret_cast<double*>(p.buf) + 2 * m, 0.0);
  for (std::size_t j = 0; j < bins; ++j) {
    const std::complex<double> v = spec_[static_cast<std::size_t>(k_lo) + j];
    p.buf[j][0] = v.real();
    p.buf[j][1] = v.imag();
  }
  fftw_execute(p.plan);
  rate_hz = static_cast<double>(m) * fs_ / static_cast<double>(np_);
  // Envelope sample j lies at time j Np / (M fs): inside the record while j Np / M < N.
  const auto inside = std::min<std::size_t>(
      m, static_cast<std::size_t>(std::floor(static_cast<double>(n_) * static_cast<double>(m) / static_cast<double>(np_))));
  std::vector<std::complex<double>> c(inside);
  for (std::size_t j = 0; j < inside; ++j) c[j] = {p.buf[j][0], p.buf[j][1]};
  return c;
}

std::vector<double> RecordSpectrum::smoothed_power(std::size_t width_bins) const {
  const std::size_t n = spec_.size();
  std::vector<double> p(n), s(n);
  for (std::size_t k = 0; k < n; ++k) p[k] = std::norm(spec_[k]);
  const std::size_t h = width_bins / 2;
  double sum = 0;
  std::size_t lo = 0, hi = 0;  // running window [lo, hi)
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t want_lo = k >= h ? k - h : 0, want_hi = std::min(n, k + h + 1);
    while (hi < want_hi) sum += p[hi++];
    while (lo < want_lo) sum -= p[lo++];
    s[k] = std::max(0.0, sum) / static_cast<double>(hi - lo);
  }
  return s;
}

}  // namespace ridgewatch::survey
