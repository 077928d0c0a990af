// End-to-end StreamProcessor (core/pipeline/stream_processor.hpp) over 10 s of the simulated paper rig
// at 51.2 kHz mono (250 impacts, noise 1 % of the peak), float blocks of 4096 samples as `ridgewatch
// analyze` feeds them. Counter real_time_factor = stream seconds per wall second (target >= 2000 on
// one core). Variants: the default estimator (ml), ridge-ls, and the detector alone (per-sample part).
// BM_Analyzer* time ImpactAnalyzer::analyze alone on the same 249 impact windows (onsets from one
// pipeline run); counter s_per_impact = wall seconds per analysed window (printed with an SI prefix, u = microseconds).
//   ./build-bench/bench/bench_pipeline --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "core/model/simulator.hpp"
#include "core/pipeline/impact_analyzer.hpp"
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

void run_analyzer(benchmark::State& state, ridgewatch::dsp::DampingMethod method) {
  const auto& xf = signal();
  const std::vector<double> x(xf.begin(), xf.end());
  rp::PipelineConfig cfg;
  cfg.sample_rate_hz = kFs;
  cfg.analyzer.method = method;
  std::vector<rp::ImpactEvent> found;
  {
    rp::StreamProcessor p(cfg);
    p.process(xf, 0, found);
    p.flush(found);
  }
  // The analyzer StreamProcessor uses for these windows (39.5 ms from the onset to the next impact):
  // its ladder's shortest maximum that holds them, window_s / 2^4.5 = 44.19 ms, made one sample longer
  // (2264 samples) for the half-rate analysis.
  rp::ImpactAnalyzerConfig ac = cfg.analyzer;
  ac.window_s = 2264.0 / kFs;
  rp::ImpactAnalyzer a(ac, kFs);
  // Windows as StreamProcessor cuts them: [onset - pretrigger, onset + window), cut 0.5 ms before the
  // next onset; noise from the 1 ms before the window (white-equivalent, as the pipeline's estimate).
  std::vector<rp::ImpactWindow> windows;
  const auto guard = static_cast<std::uint64_t>(std::ceil(0.0005 * kFs));
  const auto noise_span = static_cast<std::uint64_t>(std::ceil(0.001 * kFs));
  for (std::size_t i = 0; i < found.size(); ++i) {
    const std::uint64_t o = found[i].sample_index;
    if (o < a.pretrigger_samples() + noise_span) continue;
    const std::uint64_t w0 = o - a.pretrigger_samples();
    std::uint64_t end = std::min<std::uint64_t>(o + a.window_samples(), x.size());
    rp::ImpactWindow w;
    if (i + 1 < found.size() && found[i + 1].sample_index < end + guard) {
      end = found[i + 1].sample_index - guard;
      w.end = rp::WindowEnd::next_impact;
    }
    w.samples = std::span<const float>(xf.data() + w0, end - w0);
    w.onset_offset = a.pretrigger_samples();
    w.onset_index = o;
    double ms = 0;
    for (std::uint64_t k = w0 - noise_span; k < w0; ++k) ms += x[k] * x[k];
    w.noise_var = ms / static_cast<double>(noise_span);
    windows.push_back(w);
  }
  std::size_t n_ok = 0;
  for (auto _ : state) {
    n_ok = 0;
    for (const auto& w : windows) {
      const rp::ImpactEvent e = a.analyze(w);
      n_ok += e.status == rp::ImpactStatus::ok;
      benchmark::DoNotOptimize(e.zeta);
    }
  }
  state.counters["s_per_impact"] = benchmark::Counter(static_cast<double>(state.iterations() * windows.size()),
                                                     benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["windows"] = static_cast<double>(windows.size());
  state.counters["ok"] = static_cast<double>(n_ok);
}

void BM_AnalyzerMl(benchmark::State& state) { run_analyzer(state, ridgewatch::dsp::DampingMethod::ml); }
void BM_AnalyzerRidgeLs(benchmark::State& state) { run_analyzer(state, ridgewatch::dsp::DampingMethod::ridge_ls); }

}  // namespace

BENCHMARK(BM_AnalyzerMl)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_AnalyzerRidgeLs)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_PipelineMl)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_PipelineRidgeLs)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_DetectorOnly)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
