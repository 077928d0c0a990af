// Simulated seconds per wall second of the gear-pair model (core/model/simulator.hpp) for the paper's
// rig at 51.2 kHz output (RK4 at 204.8 kHz), without and with effects that need event location.
#include <benchmark/benchmark.h>

#include "core/model/simulator.hpp"

namespace rm = ridgewatch::model;

static void run(benchmark::State& state, const std::vector<rm::EffectSpec>& effects) {
  const rm::RigParameters rig;  // paper rig (Appendix B)
  rm::SimulationSettings settings;
  settings.duration_s = 1.0;
  settings.sample_rate_hz = 51200.0;
  for (auto _ : state) {
    auto r = rm::simulate(rig, effects, settings);
    benchmark::DoNotOptimize(r.output.data());
  }
  // items/s = simulated seconds per wall second.
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()) * static_cast<int64_t>(settings.duration_s));
  state.counters["sim_s_per_wall_s"] =
      benchmark::Counter(static_cast<double>(state.iterations()) * settings.duration_s, benchmark::Counter::kIsRate);
}

static void BM_SimulatePaperRig(benchmark::State& state) { run(state, {}); }
static void BM_SimulatePaperRigMeshVariation(benchmark::State& state) { run(state, {{"mesh_stiffness_variation", {}}}); }
static void BM_SimulatePaperRigFrictionEvents(benchmark::State& state) {
  run(state, {{"mesh_stiffness_variation", {}}, {"coulomb_friction", {}}, {"noise", {}}});
}

BENCHMARK(BM_SimulatePaperRig)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_SimulatePaperRigMeshVariation)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_SimulatePaperRigFrictionEvents)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
