// SpscRingBuffer throughput in samples/s: block writes and reads on one thread (the cost of the
// copies and index updates), and a producer/consumer pair on two threads (adds cache-line transfer).
// Run: ./build/bench/bench_ring_buffer  (Release build recommended)
#include <benchmark/benchmark.h>

#include <algorithm>
#include <atomic>
#include <span>
#include <thread>
#include <vector>

#include "core/rt/spsc_ring_buffer.hpp"

namespace {

using Ring = ridgewatch::rt::SpscRingBuffer<float>;

void BM_WriteReadBlock(benchmark::State& state) {
  const auto block = static_cast<std::size_t>(state.range(0));
  Ring ring(1 << 16, 1 << 12);
  std::vector<float> in(block, 0.5f), out(block);
  for (auto _ : state) {
    ring.write(in);
    const auto r = ring.read(out);
    benchmark::DoNotOptimize(r.count);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(block));
}
BENCHMARK(BM_WriteReadBlock)->Arg(64)->Arg(1024)->Arg(8192);

/// Zero-copy consumer path: read_regions + consume (what a pipeline stage reading in place does).
void BM_WriteRegionsConsume(benchmark::State& state) {
  const auto block = static_cast<std::size_t>(state.range(0));
  Ring ring(1 << 16);
  std::vector<float> in(block, 0.5f);
  float sum = 0.0f;
  for (auto _ : state) {
    ring.write(in);
    const auto regions = ring.read_regions();
    sum += regions.first.empty() ? 0.0f : regions.first.front();
    ring.consume(regions.size());
  }
  benchmark::DoNotOptimize(sum);
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(block));
}
BENCHMARK(BM_WriteRegionsConsume)->Arg(1024);

/// Two threads: the benchmark thread produces blocks without loss (writes only what fits), a second
/// thread consumes. Items processed = items actually transferred, timed on the wall clock.
void BM_TwoThreads(benchmark::State& state) {
  const auto block = static_cast<std::size_t>(state.range(0));
  Ring ring(1 << 16);
  std::atomic<bool> stop{false};
  std::thread consumer([&] {
    std::vector<float> out(block);
    while (!stop.load(std::memory_order_relaxed)) {
      if (ring.read(out).count == 0) std::this_thread::yield();
    }
  });
  std::vector<float> in(block, 0.25f);
  const std::span<const float> all(in);
  for (auto _ : state) {
    const std::size_t room = ring.writable_items();
    if (room == 0) std::this_thread::yield();
    benchmark::DoNotOptimize(ring.write(all.first(std::min(room, block))));
  }
  stop.store(true);
  consumer.join();
  state.SetItemsProcessed(static_cast<std::int64_t>(ring.written_items()));
}
BENCHMARK(BM_TwoThreads)->Arg(1024)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
