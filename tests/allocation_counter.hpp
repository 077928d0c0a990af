// Counts calls of the global allocation functions, for tests of the real-time contract ("does not
// allocate on the hot path"). Include in exactly one source file of a test executable: it replaces
// the global operator new/delete of that program.
#pragma once

#include <atomic>
#include <cstdlib>
#include <new>

namespace ridgewatch::test {
inline std::atomic<long> g_allocations{0};
/// Allocations so far in this process.
inline long allocations() { return g_allocations.load(std::memory_order_relaxed); }
}  // namespace ridgewatch::test

void* operator new(std::size_t size) {
  ridgewatch::test::g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t size) {
  ridgewatch::test::g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
// The replacement new above gets its memory from malloc, so free is the matching release; GCC's
// -Wmismatched-new-delete cannot see that pairing once these are inlined.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop
