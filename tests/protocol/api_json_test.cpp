// HTTP API documents outside the dataset layer (error, health, slab query and answer), query
// strings and view ids.
#include "protocol/api_json.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "protocol/query_string.h"
#include "protocol/view_id.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

TEST(ApiJsonTest, ErrorAndHealthDocuments) {
  EXPECT_EQ(json::parse(HttpErrorJson("no such dataset")),
            json::parse(R"({"error":"no such dataset"})"));
  const json hostile =
      json::parse(HttpErrorJson("line1\nline2 \"q\" \xfe" + std::string(3000, 'x')));
  const std::string message = hostile["error"];
  EXPECT_EQ(message.find('\n'), std::string::npos);
  EXPECT_LE(message.size(), 1010u);

  const json health = json::parse(HealthJson({"0.1.0", 12.25, 2, 1}));
  EXPECT_EQ(health, json::parse(R"({"status":"ok","version":"0.1.0","uptime_s":12.25,
                                    "datasets":2,"sessions":1})"));
}

TEST(ApiJsonTest, SlabQuery) {
  Result<SlabQuery> q = ParseSlabQuery("z=10&depth=4&channel=2");
  ASSERT_TRUE(q.ok()) << q.status().ToString();
  EXPECT_EQ(q->z, 10);
  EXPECT_EQ(q->depth, 4);
  EXPECT_EQ(q->channel, 2);
  EXPECT_TRUE(q->wait);
  Result<SlabQuery> nowait = ParseSlabQuery("channel=0&wait=0&token=abc&depth=1&z=0");
  ASSERT_TRUE(nowait.ok()) << nowait.status().ToString();
  EXPECT_FALSE(nowait->wait);

  const std::pair<std::string, std::string> bad[] = {
      {"depth=4&channel=0", "\"z\""},
      {"z=0&channel=0", "\"depth\""},
      {"z=0&depth=1", "\"channel\""},
      {"z=0&depth=0&channel=0", "\"depth\""},
      {"z=-1&depth=1&channel=0", "\"z\""},
      {"z=+1&depth=1&channel=0", "\"z\""},
      {"z=1e3&depth=1&channel=0", "\"z\""},
      {"z=&depth=1&channel=0", "\"z\""},
      {"z=99999999999999999999&depth=1&channel=0", "\"z\""},
      {"z=65535&depth=2&channel=0", "z + depth"},
      {"z=0&depth=1&channel=64", "\"channel\""},
      {"z=0&depth=1&channel=0&wait=2", "\"wait\""},
      {"z=0&depth=1&channel=0&z=1", "given twice"},
      {"z=0&depth=1&channel=0&zz=1", "\"zz\""},
      {"z=0&depth=1&channel=%zz", "percent"},
  };
  for (const auto& [query, says] : bad) {
    Result<SlabQuery> r = ParseSlabQuery(query);
    ASSERT_FALSE(r.ok()) << query;
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
    EXPECT_NE(r.status().message().find(says), std::string::npos)
        << query << ": " << r.status().message();
  }
  EXPECT_EQ(json::parse(SlabResultJson(8, 6)),
            json::parse(R"({"planes_received":8,"planes_inserted":6})"));
}

TEST(QueryStringTest, DecodesStrictly) {
  EXPECT_EQ(*PercentDecode("a%20b+c%2Fd", true), "a b c/d");
  EXPECT_EQ(*PercentDecode("a+b", false), "a+b");
  EXPECT_EQ(*PercentDecode("%e2%82%AC", false), "\xe2\x82\xac");
  EXPECT_FALSE(PercentDecode("%", false).ok());
  EXPECT_FALSE(PercentDecode("%4", false).ok());
  EXPECT_FALSE(PercentDecode("%4g", false).ok());
  EXPECT_FALSE(PercentDecode("a%00b", false).ok());

  Result<std::vector<QueryParameter>> params = ParseQueryString("a=1&&b&c=x%3Dy&=v");
  ASSERT_TRUE(params.ok());
  ASSERT_EQ(params->size(), 4u);
  EXPECT_EQ((*params)[0].name, "a");
  EXPECT_EQ((*params)[0].value, "1");
  EXPECT_EQ((*params)[1].name, "b");
  EXPECT_EQ((*params)[1].value, "");
  EXPECT_EQ((*params)[2].value, "x=y");
  EXPECT_EQ((*params)[3].name, "");

  std::string many;
  for (size_t i = 0; i <= kMaxQueryParameters; ++i) many += "p=1&";
  EXPECT_FALSE(ParseQueryString(many).ok());

  EXPECT_EQ(RemoveQueryParameter("token=abc&z=1&%74oken=x&depth=2", "token"), "z=1&depth=2");
  EXPECT_EQ(RemoveQueryParameter("token=abc", "token"), "");
  EXPECT_EQ(RemoveQueryParameter("tokens=1", "token"), "tokens=1");
}

TEST(ViewIdTest, NamesAndCodes) {
  for (int code = 0; code < kViewCount; ++code) {
    const ViewId view = static_cast<ViewId>(code);
    EXPECT_EQ(ViewFromName(ViewName(view)), view);
    EXPECT_EQ(ViewFromCode(static_cast<uint8_t>(code)), view);
  }
  EXPECT_EQ(ViewName(ViewId::k3d), "3d");
  EXPECT_EQ(ViewName(ViewId::kZ), "z");
  EXPECT_FALSE(ViewFromName("3D").has_value());
  EXPECT_FALSE(ViewFromName("").has_value());
  EXPECT_FALSE(ViewFromCode(4).has_value());
}

}  // namespace
}  // namespace octoscope::protocol
