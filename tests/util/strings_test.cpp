#include "util/strings.h"

#include <gtest/gtest.h>

#include <algorithm>

namespace octoscope {
namespace {

TEST(StringsTest, ParseInt64IsStrict) {
  EXPECT_EQ(ParseInt64("42"), 42);
  EXPECT_EQ(ParseInt64(" -7 "), -7);
  EXPECT_EQ(ParseInt64("+3"), 3);
  EXPECT_FALSE(ParseInt64("").has_value());
  EXPECT_FALSE(ParseInt64("12abc").has_value());
  EXPECT_FALSE(ParseInt64("1.5").has_value());
  EXPECT_FALSE(ParseInt64("99999999999999999999").has_value());
}

TEST(StringsTest, ParseDoubleIsStrict) {
  EXPECT_DOUBLE_EQ(*ParseDouble("0.512"), 0.512);
  EXPECT_DOUBLE_EQ(*ParseDouble("1e-3"), 1e-3);
  EXPECT_FALSE(ParseDouble("0.5um").has_value());
  EXPECT_FALSE(ParseDouble("").has_value());
}

TEST(StringsTest, NaturalOrderSortsNumbersByValue) {
  std::vector<std::string> names = {"z10.tif", "z2.tif", "z1.tif", "Z3.tif", "z02b.tif", "a.tif"};
  std::sort(names.begin(), names.end(),
            [](const std::string& a, const std::string& b) { return NaturalLess(a, b); });
  EXPECT_EQ(names, (std::vector<std::string>{"a.tif", "z1.tif", "z2.tif", "z02b.tif", "Z3.tif",
                                             "z10.tif"}));
}

TEST(StringsTest, NaturalOrderIsStrictWeak) {
  EXPECT_FALSE(NaturalLess("a1", "a1"));
  // Equal by value but different spelling: still a total order.
  EXPECT_NE(NaturalLess("a01", "a1"), NaturalLess("a1", "a01"));
  EXPECT_TRUE(NaturalLess("ch00009", "ch00010"));
  EXPECT_TRUE(NaturalLess("x", "x0"));
}

TEST(StringsTest, SplitKeepsEmptyPieces) {
  auto parts = Split("1,,3", ',');
  ASSERT_EQ(parts.size(), 3u);
  EXPECT_EQ(parts[1], "");
  EXPECT_EQ(parts[2], "3");
}

TEST(StringsTest, PrintableEscapesAndTruncates) {
  EXPECT_EQ(Printable(std::string("a\x01z", 3)), "a\\x01z");
  EXPECT_EQ(Printable(std::string(100, 'x'), 4), "xxxx...");
}

TEST(StringsTest, CaseInsensitiveHelpers) {
  EXPECT_TRUE(EndsWithIgnoreCase("a.OME.TIF", ".ome.tif"));
  EXPECT_FALSE(EndsWithIgnoreCase("tif", ".tif"));
  EXPECT_TRUE(EqualsIgnoreCase("Float", "float"));
  EXPECT_EQ(ToLower("MiCrOn"), "micron");
}

}  // namespace
}  // namespace octoscope
