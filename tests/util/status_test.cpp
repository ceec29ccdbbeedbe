#include "util/status.h"

#include <gtest/gtest.h>

#include "util/checked_math.h"
#include "util/result.h"

namespace octoscope {
namespace {

TEST(StatusTest, DefaultIsOk) {
  Status s;
  EXPECT_TRUE(s.ok());
  EXPECT_EQ(s.ToString(), "OK");
}

TEST(StatusTest, ErrorCarriesCodeAndMessage) {
  Status s = CorruptError("a.tif: strip 3 is truncated");
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.code(), StatusCode::kCorrupt);
  EXPECT_EQ(s.ToString(), "corrupt: a.tif: strip 3 is truncated");
  EXPECT_EQ(s.WithContext("open").message(), "open: a.tif: strip 3 is truncated");
  EXPECT_EQ(s.WithContext("open").code(), StatusCode::kCorrupt);
}

TEST(StatusTest, UnavailableNamesItsKind) {
  Status s = UnavailableError("/c: locked by another process");
  EXPECT_EQ(s.code(), StatusCode::kUnavailable);
  EXPECT_EQ(s.ToString(), "unavailable: /c: locked by another process");
}

Result<int> Half(int v) {
  if (v % 2) return InvalidArgumentError(std::to_string(v) + " is odd");
  return v / 2;
}

Result<int> Quarter(int v) {
  OCTO_ASSIGN_OR_RETURN(int h, Half(v));
  OCTO_ASSIGN_OR_RETURN(int q, Half(h));
  return q;
}

TEST(ResultTest, PropagatesValuesAndErrors) {
  EXPECT_EQ(*Quarter(8), 2);
  Result<int> r = Quarter(6);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().message(), "3 is odd");
}

TEST(ResultTest, OkStatusWithoutValueBecomesInternalError) {
  Result<int> r{Status::Ok()};
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInternal);
}

TEST(CheckedMathTest, DetectsOverflow) {
  EXPECT_EQ(CheckedMul(1u << 31, 4), uint64_t{1} << 33);
  EXPECT_FALSE(CheckedMul(uint64_t{1} << 40, uint64_t{1} << 30).has_value());
  EXPECT_EQ(CheckedProduct({65536, 65536, 65536, 4, 2}), uint64_t{1} << 51);
  EXPECT_FALSE(CheckedProduct({0x7fffffff, 0x7fffffff, 0x7fffffff}).has_value());
  EXPECT_FALSE(CheckedAdd(UINT64_MAX, 1).has_value());
}

}  // namespace
}  // namespace octoscope
