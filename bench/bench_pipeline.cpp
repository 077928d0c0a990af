// End-to-end StreamProcessor (core/pipeline/stream_processor.hpp) over 10 s of the simulated paper rig
// at 51.2 kHz mono (250 impacts, noise 1 % of the peak), float blocks of 4096 samples as `ridgewatch
// analyze` feeds them. Counter real_time_factor = stream seconds per wall second (target >= 2000 on
// one core). Variants: the default estimator (ml), ridge-ls, and the detector alone (per-sample part).
//   ./build-bench/bench/bench_pipeline --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <vector>

#include "core/model/simulator.hpp"
#include "core/pipeline/impact_detector.hpp"
#include "core/pipeline/stream_processor.hpp"

namespace {

namespace rp = ridgewatch::pipeline;
constexpr double kFs = 51200.0;
constexpr double kSeconds = 10.0;

const std::vector<float>& signal() {
  static const std::vector<float> x = [] {
    const ridgewatch::model::RigParameters rig;  // paper rig (Appendix B)
    ridgewatch::model::SimulationSettings s;
    s.duration_s = kSeconds;
    s.sample_rate_hz = kFs;
    const auto r = ridgewatch::model::simulate(rig, {{"noise", {{"std_rel", 0.01}}}}, s);
    return std::vector<float>(r.output.begin(), r.output.end());
  }();
  return x;
}

void run_pipeline(benchmark::State& state, ridgewatch::dsp::DampingMethod method) {
  const auto& x = signal();
  rp::PipelineConfig cfg;
  cfg.sample_rate_hz = kFs;
  cfg.analyzer.method = method;
  std::vector<rp::ImpactEvent> events;
  events.reserve(1024);
  std::size_t n_events = 0, n_ok = 0;
  for (auto _ : state) {
    state.PauseTiming();
    rp::StreamProcessor p(cfg);  // FFTW plans: not part of the streaming cost
    events.clear();
    state.ResumeTiming();
    for (std::size_t i = 0; i < x.size(); i += 4096) {
      const std::size_t len = std::min<std::size_t>(4096, x.size() - i);
      p.process(std::span<const float>(x.data() + i, len), i, events);
    }
    p.flush(events);
    benchmark::DoNotOptimize(events.data());
    n_events = events.size();
    n_ok = 0;
    for (const auto& e : events) n_ok += e.status == rp::ImpactStatus::ok;
  }
  state.counters["real_time_factor"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * kSeconds, benchmark::Counter::kIsRate);
  state.counters["events"] = static_cast<double>(n_events);
  state.counters["ok"] = static_cast<double>(n_ok);
}

void BM_PipelineMl(benchmark::State& state) { run_pipeline(state, ridgewatch::dsp::DampingMethod::ml); }
void BM_PipelineRidgeLs(benchmark::State& state) { run_pipeline(state, ridgewatch::dsp::DampingMethod::ridge_ls); }

void BM_DetectorOnly(benchmark::State& state) {
  const auto& x = signal();
  rp::ImpactDetectorConfig cfg;
  std::size_t onsets = 0;
  for (auto _ : state) {
    state.PauseTiming();
    rp::ImpactDetector d(cfg, kFs, 4096);
    state.ResumeTiming();
    onsets = 0;
    for (float v : x) {
      d.push(v);
      while (d.has_onset()) {
        d.pop_onset();
        ++onsets;
      }
    }
  }
  state.counters["real_time_factor"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * kSeconds, benchmark::Counter::kIsRate);
  state.counters["onsets"] = static_cast<double>(onsets);
}

}  // namespace

BENCHMARK(BM_PipelineMl)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_PipelineRidgeLs)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_DetectorOnly)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
