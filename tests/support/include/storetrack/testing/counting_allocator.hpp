// Counting global allocator for tests of the no-allocation guarantee (firmware per-frame path,
// frame sources). Linking storetrack::counting_allocator replaces the global operator new /
// delete of the test executable; allocation_count() is the number of operator new calls so far.
//
//   const long before = storetrack::testing::allocation_count();
//   ... per-frame work ...
//   EXPECT_EQ(storetrack::testing::allocation_count() - before, 0);
#pragma once

namespace storetrack::testing {

/// operator new / new[] calls in this process since start (thread-safe).
long allocation_count();

}  // namespace storetrack::testing
