// Morlet CWT throughput on the rig workload: 51.2 kHz x 10 s, eta0 = 7, 200 log-spaced rows 500-1500 Hz,
// one thread. Counters: x_realtime = signal seconds per wall second, rel_err = max |W - W_full| /
// max |W_full| of a band-limited transform against the full-rate double transform sampled on the same
// decimated grid (the full-rate transform itself is validated against the direct time-domain reference in
// tests/test_morlet_cwt.cpp). A band-limited benchmark whose error exceeds 1e-4 reports an error instead
// of a time.
//
// Run: build-cwt/bench/bench_cwt --benchmark_counters_tabular=true

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <map>
#include <numbers>
#include <random>
#include <vector>

#include "core/dsp/morlet_cwt.hpp"

namespace {

using ridgewatch::dsp::GridSpacing;
using ridgewatch::dsp::make_frequency_grid;
using ridgewatch::dsp::MorletCwt;
using ridgewatch::dsp::MorletCwtConfig;
using ridgewatch::dsp::Scalogram;

constexpr double kFs = 51200.0;
constexpr double kDuration_s = 10.0;
constexpr std::size_t kSamples = 512000;  // kFs * kDuration_s
constexpr double kMaxRelError = 1e-4;

// Decaying impacts once per shaft revolution (25 Hz), 854 Hz gear-pair mode with zeta = 0.024 and
// +-20 % amplitude scatter, plus white noise 20 dB below the impact peak.
const std::vector<double>& workload() {
  static const std::vector<double> x = [] {
    std::vector<double> v(kSamples, 0.0);
    std::mt19937_64 rng(42);
    std::normal_distribution<double> noise(0.0, 0.1);
    std::uniform_real_distribution<double> scatter(0.8, 1.2);
    const double f_d = 854.0, zeta = 0.024, sigma = zeta * 2.0 * std::numbers::pi * f_d;
    const auto period = static_cast<std::size_t>(kFs / 25.0);
    for (std::size_t start = 100; start < kSamples; start += period) {
      const double amp = scatter(rng);
      for (std::size_t i = start; i < std::min(kSamples, start + period); ++i) {
        const double t = static_cast<double>(i - start) / kFs;
        v[i] += amp * std::exp(-sigma * t) * std::sin(2.0 * std::numbers::pi * f_d * t);
      }
    }
    for (double& s : v) s += noise(rng);
    return v;
  }();
  return x;
}

MorletCwtConfig workload_config(bool band_limited) {
  MorletCwtConfig cfg;
  cfg.sample_rate_hz = kFs;
  cfg.eta0 = 7.0;
  cfg.frequencies_hz = make_frequency_grid(500.0, 1500.0, 200, GridSpacing::log);
  cfg.max_samples = kSamples;
  cfg.band_limited = band_limited;
  cfg.measure_plans = true;
  return cfg;
}

// Full-rate double rows (default full-rate truncation) sampled every `decimation` samples; cached per
// decimation. Computed row by row so that the 1.6 GB full-rate scalogram is never held.
const std::vector<std::vector<std::complex<double>>>& full_rate_reference(std::size_t decimation) {
  static std::map<std::size_t, std::vector<std::vector<std::complex<double>>>> cache;
  auto it = cache.find(decimation);
  if (it != cache.end()) return it->second;
  MorletCwtConfig cfg = workload_config(false);
  cfg.measure_plans = false;
  MorletCwt<double> cwt(cfg);
  cwt.load(workload());
  std::vector<std::complex<double>> row(cwt.columns());
  std::vector<std::vector<std::complex<double>>> ref;
  for (double f : cfg.frequencies_hz) {
    cwt.row(f, row);
    std::vector<std::complex<double>> decimated;
    for (std::size_t c = 0; c < row.size(); c += decimation) decimated.push_back(row[c]);
    ref.push_back(std::move(decimated));
  }
  return cache.emplace(decimation, std::move(ref)).first->second;
}

template <typename Real>
double relative_error_vs_full_rate(const Scalogram<Real>& w) {
  const auto& ref = full_rate_reference(w.decimation);
  double max_err = 0.0, max_ref = 0.0;
  for (std::size_t r = 0; r < w.rows; ++r) {
    for (std::size_t c = 0; c < w.cols; ++c) {
      const std::complex<double> got(w.at(r, c).real(), w.at(r, c).imag());
      max_err = std::max(max_err, std::abs(got - ref[r][c]));
      max_ref = std::max(max_ref, std::abs(ref[r][c]));
    }
  }
  return max_err / max_ref;
}

template <typename Real>
void set_counters(benchmark::State& state, const MorletCwt<Real>& cwt) {
  state.counters["x_realtime"] =
      benchmark::Counter(kDuration_s * static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["R"] = static_cast<double>(cwt.decimation());
  state.counters["fft_len"] = static_cast<double>(cwt.fft_length());
}

void BM_FullRateDouble(benchmark::State& state) {
  MorletCwt<double> cwt(workload_config(false));
  const std::vector<double>& x = workload();
  Scalogram<double> w;
  cwt.transform(x, w);  // sizes the output (1.6 GB) outside the timed loop
  for (auto _ : state) {
    cwt.transform(x, w);
    benchmark::DoNotOptimize(w.data.data());
    benchmark::ClobberMemory();
  }
  set_counters(state, cwt);
}

template <typename Real>
void BM_BandLimited(benchmark::State& state) {
  MorletCwt<Real> cwt(workload_config(true));
  const std::vector<double>& xd = workload();
  const std::vector<Real> x(xd.begin(), xd.end());
  Scalogram<Real> w;
  cwt.transform(x, w);
  const double err = relative_error_vs_full_rate(w);
  static bool printed = false;  // benchmark re-runs the setup while sizing the iteration count
  if (!printed)
    std::fprintf(stderr, "band-limited %s: R = %zu, D = %zu, L = %zu, rel_err vs full-rate double = %.3g\n",
                 sizeof(Real) == 4 ? "float " : "double", cwt.decimation(), cwt.fft_length() / cwt.decimation(),
                 cwt.fft_length(), err);
  printed = true;
  if (!(err <= kMaxRelError)) {
    state.SkipWithError("band-limited error above 1e-4");
    return;
  }
  for (auto _ : state) {
    cwt.transform(x, w);
    benchmark::DoNotOptimize(w.data.data());
    benchmark::ClobberMemory();
  }
  set_counters(state, cwt);
  state.counters["rel_err"] = err;
}

BENCHMARK(BM_FullRateDouble)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(2);
BENCHMARK_TEMPLATE(BM_BandLimited, float)->Name("BM_BandLimitedFloat")->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_TEMPLATE(BM_BandLimited, double)->Name("BM_BandLimitedDouble")->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
