// split_fields / trim against hand-written expectations (the rows the readers must refuse
// depend on the cell count: a trailing separator must not vanish).
#include <gtest/gtest.h>

#include "storetrack/csv/fields.hpp"

namespace storetrack::csv {
namespace {

using Cells = std::vector<std::string>;

TEST(CsvFields, SplitsAtEverySeparatorKeepingEmptyCells) {
  EXPECT_EQ(split_fields("a,b,c"), (Cells{"a", "b", "c"}));
  EXPECT_EQ(split_fields("a,,c"), (Cells{"a", "", "c"}));
  EXPECT_EQ(split_fields("a,b,"), (Cells{"a", "b", ""}));
  EXPECT_EQ(split_fields(",a"), (Cells{"", "a"}));
  EXPECT_EQ(split_fields(","), (Cells{"", ""}));
  EXPECT_EQ(split_fields("single"), (Cells{"single"}));
  EXPECT_TRUE(split_fields("").empty());
}

TEST(CsvFields, KeepsBlanksAndOtherSeparators) {
  EXPECT_EQ(split_fields(" x [m] , y\r"), (Cells{" x [m] ", " y\r"}));
  EXPECT_EQ(split_fields("a;b,c", ';'), (Cells{"a", "b,c"}));
}

TEST(CsvFields, TrimsSpaceTabAndCarriageReturnOnly) {
  EXPECT_EQ(trim("  x_w \t\r"), "x_w");
  EXPECT_EQ(trim("a b"), "a b");
  EXPECT_EQ(trim(" \t\r"), "");
  EXPECT_EQ(trim(""), "");
  EXPECT_EQ(trim("\nx\n"), "\nx\n");
}

}  // namespace
}  // namespace storetrack::csv
