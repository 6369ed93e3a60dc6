// Replaces the global allocation functions with counting ones (see counting_allocator.hpp).
#include "storetrack/testing/counting_allocator.hpp"

#include <cerrno>
#include <cstddef>
#include <cstdlib>
#include <new>

// The C allocator is replaced on glibc (which supports it: "Replacing malloc" in its manual) and
// forwarded to glibc's own (__libc_malloc ...). A sanitizer owns malloc: only new is counted.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define STORETRACK_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || \
    __has_feature(memory_sanitizer)
#define STORETRACK_SANITIZED 1
#endif
#endif
#if defined(__GLIBC__) && !defined(STORETRACK_SANITIZED)
#define STORETRACK_COUNT_C_ALLOCATOR 1
#include <malloc.h>
extern "C" {
void* __libc_malloc(std::size_t n);
void* __libc_calloc(std::size_t count, std::size_t n);
void* __libc_realloc(void* p, std::size_t n);
void __libc_free(void* p);
void* __libc_memalign(std::size_t alignment, std::size_t n);
void* __libc_valloc(std::size_t n);
void* __libc_pvalloc(std::size_t n);
}
#endif

// GCC 12 inlines these replacements (notably under -fsanitize) and then flags std::free on
// memory from the replaced operator new as a mismatch: a false positive for a replaced allocator.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif

namespace {

std::atomic<long> g_allocations{0};
thread_local std::atomic<long> t_allocations{0};

void count() {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  t_allocations.fetch_add(1, std::memory_order_relaxed);
}

// Uncounted allocation: each public function counts itself once, then comes here.
void* raw_malloc(std::size_t n) {
#ifdef STORETRACK_COUNT_C_ALLOCATOR
  return __libc_malloc(n);
#else
  return std::malloc(n);
#endif
}

void* raw_aligned(std::size_t alignment, std::size_t n) {
#ifdef STORETRACK_COUNT_C_ALLOCATOR
  return __libc_memalign(alignment, n);
#else
  return std::aligned_alloc(alignment, (n + alignment - 1) / alignment * alignment);
#endif
}

void* new_or_throw(void* p) {
  if (p == nullptr) throw std::bad_alloc();
  return p;
}

}  // namespace

long storetrack::testing::allocation_count() {
  return g_allocations.load(std::memory_order_relaxed);
}

const std::atomic<long>& storetrack::testing::this_thread_allocations() {
  return t_allocations;
}

bool storetrack::testing::c_allocator_counted() {
#ifdef STORETRACK_COUNT_C_ALLOCATOR
  return true;
#else
  return false;
#endif
}

#ifdef STORETRACK_COUNT_C_ALLOCATOR
extern "C" {
void* malloc(std::size_t n) noexcept {
  count();
  return __libc_malloc(n);
}
void* calloc(std::size_t count_, std::size_t n) noexcept {
  count();
  return __libc_calloc(count_, n);
}
void* realloc(void* p, std::size_t n) noexcept {
  count();
  return __libc_realloc(p, n);
}
void free(void* p) noexcept {
  __libc_free(p);
}
void* aligned_alloc(std::size_t alignment, std::size_t n) noexcept {
  count();
  return __libc_memalign(alignment, n);
}
void* memalign(std::size_t alignment, std::size_t n) noexcept {
  count();
  return __libc_memalign(alignment, n);
}
int posix_memalign(void** out, std::size_t alignment, std::size_t n) noexcept {
  count();
  if (alignment % sizeof(void*) != 0 || (alignment & (alignment - 1)) != 0) return EINVAL;
  void* p = __libc_memalign(alignment, n);
  if (p == nullptr) return ENOMEM;
  *out = p;
  return 0;
}
void* valloc(std::size_t n) noexcept {
  count();
  return __libc_valloc(n);
}
void* pvalloc(std::size_t n) noexcept {
  count();
  return __libc_pvalloc(n);
}
}  // extern "C"
#endif

void* operator new(std::size_t n) {
  count();
  return new_or_throw(raw_malloc(n ? n : 1));
}
void* operator new[](std::size_t n) {
  count();
  return new_or_throw(raw_malloc(n ? n : 1));
}
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  count();
  return raw_malloc(n ? n : 1);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  count();
  return raw_malloc(n ? n : 1);
}
void* operator new(std::size_t n, std::align_val_t a) {
  count();
  return new_or_throw(raw_aligned(static_cast<std::size_t>(a), n ? n : 1));
}
void* operator new[](std::size_t n, std::align_val_t a) {
  count();
  return new_or_throw(raw_aligned(static_cast<std::size_t>(a), n ? n : 1));
}
void* operator new(std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  count();
  return raw_aligned(static_cast<std::size_t>(a), n ? n : 1);
}
void* operator new[](std::size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  count();
  return raw_aligned(static_cast<std::size_t>(a), n ? n : 1);
}
// Every delete form, so that each new/delete pair stays matched.
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
void operator delete(void* p, const std::nothrow_t&) noexcept {
  std::free(p);
}
void operator delete[](void* p, const std::nothrow_t&) noexcept {
  std::free(p);
}
void operator delete(void* p, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept {
  std::free(p);
}
