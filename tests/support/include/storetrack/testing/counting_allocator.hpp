// Counting global allocator for tests of the no-allocation guarantee (firmware per-frame path,
// frame sources). Linking storetrack::counting_allocator replaces, in the test executable, every
// allocation function: operator new / new[] in all their forms (plain, nothrow, aligned, aligned
// nothrow) and the C allocator (malloc, calloc, realloc, aligned_alloc, posix_memalign, memalign,
// valloc, pvalloc; glibc's documented way of replacing malloc). Each call counts once.
//
//   const long before = storetrack::testing::allocation_count();
//   ... per-frame work ...
//   EXPECT_EQ(storetrack::testing::allocation_count() - before, 0);
//
// Under AddressSanitizer / ThreadSanitizer the C allocator belongs to the sanitizer and is not
// replaced: only operator new is counted there (c_allocator_counted() says which).
#pragma once

#include <atomic>

namespace storetrack::testing {

/// Allocation calls in this process since start (thread-safe).
long allocation_count();

/// The allocation calls made by the calling thread; another thread may read it (relaxed) while
/// this one lives, so a test can count one thread's allocations while other threads (a sampler,
/// a server) allocate as they may.
const std::atomic<long>& this_thread_allocations();

/// True when malloc and friends are counted too (not under a sanitizer).
bool c_allocator_counted();

}  // namespace storetrack::testing
