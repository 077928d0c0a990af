// ImpactDetector alone (core/pipeline/impact_detector.hpp) over 10 s of the simulated paper rig (noise
// 1 %, 250 impacts) at 25.6 and 51.2 kHz: samples pushed one by one (as StreamProcessor does) or as
// spans of 4096. Counter ns_per_sample uses the benchmark's CPU time (the library prints inverted
// rates with an "s" suffix: "2.7s" reads 2.7 ns per sample); the budget at 51.2 kHz is <= 2.5 ns/sample
// for the detector (<= 1.3 ms per 10 s of stream: the daemon's 2000x real time on one core). Spans
// are copied in runs up to the next processing run (ImpactDetector::push(span)), as StreamProcessor
// feeds the detector.
//   ./build-bench/bench/bench_detector --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <map>
#include <span>
#include <vector>

#include "core/model/simulator.hpp"
#include "core/pipeline/impact_detector.hpp"
#include "core/pipeline/stream_processor.hpp"

namespace {

namespace rp = ridgewatch::pipeline;
constexpr double kSeconds = 10.0;

const std::vector<float>& signal(double fs) {
  static std::map<double, std::vector<float>> cache;
  auto it = cache.find(fs);
  if (it == cache.end()) {
    const ridgewatch::model::RigParameters rig;  // paper rig (Appendix B)
    ridgewatch::model::SimulationSettings s;
    s.duration_s = kSeconds;
    s.sample_rate_hz = fs;
    const auto r = ridgewatch::model::simulate(rig, {{"noise", {{"std_rel", 0.01}}}}, s);
    it = cache.emplace(fs, std::vector<float>(r.output.begin(), r.output.end())).first;
  }
  return it->second;
}

void run(benchmark::State& state, double fs, bool spans) {
  const auto& x = signal(fs);
  rp::ImpactDetector d(rp::ImpactDetectorConfig{}, fs, 4096);
  std::size_t onsets = 0;
  for (auto _ : state) {
    d.restart(0);
    onsets = 0;
    if (spans) {
      for (std::size_t i = 0; i < x.size(); i += 4096) {
        d.push(std::span<const float>(x.data() + i, std::min<std::size_t>(4096, x.size() - i)));
        while (d.has_onset()) {
          d.pop_onset();
          ++onsets;
        }
      }
    } else {
      for (float v : x) {
        d.push(v);
        while (d.has_onset()) {
          d.pop_onset();
          ++onsets;
        }
      }
    }
    d.finish();
    benchmark::DoNotOptimize(onsets);
  }
  state.counters["onsets"] = static_cast<double>(onsets);
  state.counters["ns_per_sample"] = benchmark::Counter(
      static_cast<double>(state.iterations()) * static_cast<double>(x.size()) * 1e-9,
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["real_time_factor"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * kSeconds, benchmark::Counter::kIsRate);
}

void BM_Detector51k2PerSample(benchmark::State& state) { run(state, 51200.0, false); }
void BM_Detector51k2Spans(benchmark::State& state) { run(state, 51200.0, true); }
void BM_Detector25k6PerSample(benchmark::State& state) { run(state, 25600.0, false); }

}  // namespace

BENCHMARK(BM_Detector51k2PerSample)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Detector51k2Spans)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Detector25k6PerSample)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
