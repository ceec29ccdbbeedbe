// The strict JSON readers every protocol/ parser shares: limits enforced while parsing, duplicate
// keys, field readers' messages.
#include "protocol/json_fields.h"

#include <gtest/gtest.h>

#include <string>

namespace octoscope::protocol {
namespace {

std::string Nested(int levels) {
  return std::string(static_cast<size_t>(levels), '[') +
         std::string(static_cast<size_t>(levels), ']');
}

TEST(JsonFieldsTest, ParseLimits) {
  EXPECT_TRUE(ParseJsonObject(R"({"a":[[1]]})", "doc", 100, 3).ok());
  Result<nlohmann::json> deep = ParseJsonObject(R"({"a":[[[1]]]})", "doc", 100, 3);
  ASSERT_FALSE(deep.ok());
  EXPECT_EQ(deep.status().message(), "doc: nested too deeply (more than 3 levels)");

  Result<nlohmann::json> big = ParseJsonObject(R"({"a":1})", "doc", 6, 3);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.status().message(), "doc: 7 bytes, larger than 6");

  Result<nlohmann::json> dup = ParseJsonObject(R"({"a":1,"b":{"a":2},"a":3})", "doc", 100, 3);
  ASSERT_FALSE(dup.ok());
  EXPECT_EQ(dup.status().message(), "doc: duplicate key \"a\"");
  // The same key in different objects is fine.
  EXPECT_TRUE(ParseJsonObject(R"({"a":{"a":{"a":1}},"b":[{"a":1},{"a":2}]})", "doc", 100, 4).ok());

  EXPECT_TRUE(ParseJsonObject(R"({"abc":"defg"})", "doc", 100, 3, 4).ok());
  EXPECT_FALSE(ParseJsonObject(R"({"abc":"defgh"})", "doc", 100, 3, 4).ok());
  EXPECT_FALSE(ParseJsonObject(R"({"abcde":"d"})", "doc", 100, 3, 4).ok());

  Result<nlohmann::json> array = ParseJsonObject("[1]", "doc", 100, 3);
  ASSERT_FALSE(array.ok());
  EXPECT_EQ(array.status().message(), "doc: must be a JSON object, got array");
  Result<nlohmann::json> broken = ParseJsonObject("{\"a\":", "doc", 100, 3);
  ASSERT_FALSE(broken.ok());
  EXPECT_EQ(broken.status().message().rfind("doc: not valid JSON: ", 0), 0u);

  // Files (Zarr metadata): any value, kCorrupt errors.
  EXPECT_TRUE(ParseJsonLimited("[1,2]", 1).ok());
  EXPECT_EQ(ParseJsonLimited(Nested(3), 2).status().code(), StatusCode::kCorrupt);
  EXPECT_EQ(ParseJsonLimited(Nested(100000), 64).status().code(), StatusCode::kCorrupt);
  EXPECT_EQ(ParseJsonLimited("{\"a\":1,\"a\":1}", 4).status().code(), StatusCode::kCorrupt);
  EXPECT_NE(ParseJsonLimited("{", 4).status().message().find("not valid JSON"), std::string::npos);
}

TEST(JsonFieldsTest, FieldReaders) {
  const nlohmann::json doc = nlohmann::json::parse(
      R"({"i":3,"f":3.0,"big":18446744073709551615,"s":"a\tb","b":true,"v":[1,2,3]})");
  EXPECT_EQ(*GetInteger(doc["i"], "x.i", 0, 3), 3);
  EXPECT_EQ(GetInteger(doc["i"], "x.i", 4, 5).status().message(), "x.i: is 3, must be in 4..5");
  EXPECT_EQ(GetInteger(doc["f"], "x.f", 0, 5).status().message(),
            "x.f: must be an integer, got 3.0");
  EXPECT_FALSE(GetInteger(doc["big"], "x.big", 0, INT64_MAX).ok());
  EXPECT_EQ(GetInteger(doc["s"], "x.s", 0, 5).status().message(),
            "x.s: must be an integer, got string");
  EXPECT_EQ(*GetNumberIn(doc["f"], "x.f", 0, 3), 3.0);
  EXPECT_FALSE(GetNumberIn(doc["f"], "x.f", 0, 2.5).ok());
  EXPECT_EQ(*GetString(doc["s"], "x.s"), "a\tb");
  EXPECT_EQ(GetString(doc["s"], "x.s", 100, true).status().message(),
            "x.s: must not contain control characters");
  EXPECT_EQ(GetString(doc["s"], "x.s", 2, false).status().message(),
            "x.s: is 3 bytes long, at most 2");
  EXPECT_TRUE(*GetBool(doc["b"], "x.b"));
  EXPECT_EQ(GetNumbers(doc["v"], "x.v", 3)->at(2), 3);
  EXPECT_EQ(GetNumbers(doc["v"], "x.v", 2).status().message(), "x.v: must have 2 elements, has 3");
  EXPECT_EQ(
      CheckKeys(doc, "x", {"i", "f"}).message().rfind("unknown key \"b\" in x (known: i, f)", 0),
      0u);
  EXPECT_EQ(Require(doc, "x", "nope").status().message(), "x.nope: missing");
  EXPECT_EQ(CheckObject(doc["v"], "x.v").message(), "x.v: must be an object, got array");
  EXPECT_EQ(OneLine("a\nb\x7f"
                    "cdef",
                    5),
            "a b c");
  EXPECT_EQ(Quote("a\"b"), "\"a\\\"b\"");
  EXPECT_EQ(Quote("\xff"), "\"\xef\xbf\xbd\"");  // Invalid UTF-8 replaced, not thrown.
}

}  // namespace
}  // namespace octoscope::protocol
