#include "core/dsp/kernels/isa.hpp"

#include <atomic>

namespace ridgewatch::dsp::kernels {

namespace {

bool cpu_has_avx2() {
#if RIDGEWATCH_HAVE_AVX2_KERNELS
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") != 0;
#else
  return false;
#endif
}

std::atomic<bool> g_baseline_only{false};

}  // namespace

bool use_avx2() {
  static const bool has = cpu_has_avx2();
  return has && !g_baseline_only.load(std::memory_order_relaxed);
}

void limit_kernels_to_baseline(bool on) { g_baseline_only.store(on, std::memory_order_relaxed); }

}  // namespace ridgewatch::dsp::kernels
