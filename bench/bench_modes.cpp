// Mode identification speed on the paper's Table-1 signal (10 kHz, 1 s, 3 modes, SNR 20 dB):
// the whole `ridgewatch modes` computation (CWT profile, ridges, three estimators, joint ML fit)
// without file I/O, and the ML fit alone.
#include <benchmark/benchmark.h>

#include "core/dsp/ml_fit.hpp"
#include "core/dsp/modes.hpp"
#include "core/dsp/synthetic.hpp"

namespace {

using namespace ridgewatch::dsp;

std::vector<double> table1_signal() {
  auto x = damped_sum(paper_table1_components(), 10000.0, 10000);
  add_white_noise(x, 20.0, 1);
  return x;
}

void BM_IdentifyModesTable1(benchmark::State& state) {
  const auto x = table1_signal();
  ModeSearchOptions opt;
  std::size_t modes = 0;
  for (auto _ : state) {
    const ModeSearchResult r = identify_modes(x, 10000.0, opt);
    modes = r.modes.size();
    benchmark::DoNotOptimize(r.modes.data());
  }
  state.counters["modes"] = static_cast<double>(modes);
  state.counters["x_realtime"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * 1.0, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_IdentifyModesTable1)->Unit(benchmark::kMillisecond);

void BM_MlFitTable1(benchmark::State& state) {
  const auto x = table1_signal();
  SpectralModeFitter fitter(x.size(), 10000.0);
  const std::vector<ModeGuess> guesses = {{250.2, 0.0203}, {499.5, 0.044}, {1250.1, 0.00505}};
  MlFitOptions o;
  o.f_lo_hz = 20;
  o.f_hi_hz = 4500;
  for (auto _ : state) {
    const MlFitResult r = fitter.fit(x, guesses, o);
    benchmark::DoNotOptimize(r.modes.data());
  }
}
BENCHMARK(BM_MlFitTable1)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
