// Replaces the global allocation functions with counting ones (see counting_allocator.hpp).
#include "storetrack/testing/counting_allocator.hpp"

#include <atomic>
#include <cstdlib>
#include <new>

// GCC 12 inlines these replacements (notably under -fsanitize) and then flags std::free on
// memory from the replaced operator new as a mismatch: a false positive for a replaced allocator.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif

namespace {
std::atomic<long> g_allocations{0};
}  // namespace

long storetrack::testing::allocation_count() {
  return g_allocations.load(std::memory_order_relaxed);
}

void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
// The array and sized forms too, so that every new/delete pair stays matched.
void* operator new[](std::size_t n) {
  return operator new(n);
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete[](void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::size_t) noexcept {
  std::free(p);
}
