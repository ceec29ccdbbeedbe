// Tests for octree/node_encoding.h: exact bit positions, round trips, limits, and the node
// capacity arithmetic of docs/octree_format.md ("Device node buffer").
#include "octree/node_encoding.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

namespace octoscope::octree {
namespace {

BrickGeometry Make(Vec3 size, Vec3 brick, int channels = 1) {
  Result<BrickGeometry> g = BrickGeometry::Create({size, brick, channels, 2});
  EXPECT_TRUE(g.ok()) << g.status().ToString();
  return *g;
}

TEST(NodeEncodingTest, WordsPerNode) {
  EXPECT_EQ(NodeWords(1), 4);
  EXPECT_EQ(NodeWords(2), 5);
  EXPECT_EQ(NodeWords(3), 7);
  EXPECT_EQ(NodeWords(4), 8);
  EXPECT_EQ(NodeWords(5), 10);
  EXPECT_EQ(NodeWords(kMaxChannels), 98);
  EXPECT_EQ(NodeRangeWord(1), 3);
  EXPECT_EQ(NodeRangeWord(3), 4);
  EXPECT_EQ(NodeRangeWord(4), 4);
  EXPECT_EQ(ChildNodeId(1, 0), 8u);
  EXPECT_EQ(ChildNodeId(2, 7), 23u);
  EXPECT_EQ(ChildNodeId(kMaxChildGroup, 7), (uint64_t{1} << 33) - 1);
  EXPECT_EQ(NodeWordOffset(23, 3), 23u * 7u);
}

TEST(NodeEncodingTest, BitPositionsAreExact) {
  std::vector<uint32_t> w(7, 0xdeadbeef);
  DeviceNode node{.in_buffer = true,
                  .has_brick = true,
                  .child_group = 0x2aaaaaaa,
                  .brick_slot = 0x89abcdef,
                  .averages = {0x1234, 0xabcd, 0x0f0f}};
  ASSERT_TRUE(EncodeNode(node, w).ok());
  EXPECT_EQ(w[0], 0xeaaaaaaau);  // bits 31, 30 set; 0x2aaaaaaa below.
  EXPECT_EQ(w[1], 0x89abcdefu);
  EXPECT_EQ(w[2], 0xabcd1234u);  // Channel 0 low half, channel 1 high half.
  EXPECT_EQ(w[3], 0x00000f0fu);  // Channel 2 low half; the unused high half is 0.
  // No ranges given: every channel's range is the whole stored range (nothing skippable).
  EXPECT_EQ(w[4], 0xffff0000u);
  EXPECT_EQ(w[5], 0xffff0000u);
  EXPECT_EQ(w[6], 0xffff0000u);
  // Ranges: min in the low half, max in the high half, one word per channel.
  node.range_min = {1, 0x0100, 0xfffe};
  node.range_max = {0x00ff, 0x1234, 0xffff};
  ASSERT_TRUE(EncodeNode(node, w).ok());
  EXPECT_EQ(w[4], 0x00ff0001u);
  EXPECT_EQ(w[5], 0x12340100u);
  EXPECT_EQ(w[6], 0xfffffffeu);

  // Only has_brick: bit 30 alone; not in the buffer, so the slot is written as 0.
  node = {.has_brick = true, .brick_slot = 77, .averages = {1, 2, 3}};
  ASSERT_TRUE(EncodeNode(node, w).ok());
  EXPECT_EQ(w[0], 0x40000000u);
  EXPECT_EQ(w[1], 0u);
  EXPECT_EQ(w[2], 0x00020001u);
  EXPECT_EQ(w[3], 0x00000003u);

  // The largest child group fills exactly bits 0..29.
  node = {.child_group = kMaxChildGroup, .averages = {0xffff, 0xffff, 0xffff}};
  ASSERT_TRUE(EncodeNode(node, w).ok());
  EXPECT_EQ(w[0], 0x3fffffffu);
  EXPECT_EQ(w[2], 0xffffffffu);
  EXPECT_EQ(w[3], 0x0000ffffu);

  EXPECT_EQ(EncodeWord0(true, false, 0), 0x80000000u);
  EXPECT_EQ(EncodeWord0(false, true, 0), 0x40000000u);
  EXPECT_EQ(EncodeWord0(false, false, 5), 5u);
  EXPECT_TRUE(Word0InBuffer(0x80000000u));
  EXPECT_FALSE(Word0InBuffer(0x7fffffffu));
  EXPECT_TRUE(Word0HasBrick(0x40000000u));
  EXPECT_FALSE(Word0HasBrick(0xbfffffffu));
  EXPECT_EQ(Word0ChildGroup(0xffffffffu), kMaxChildGroup);
  EXPECT_EQ(Word0ChildGroup(0xc0000001u), 1u);
}

TEST(NodeEncodingTest, DocumentedExample) {
  // docs/octree_format.md, "Device node buffer": the worked example.
  std::vector<uint32_t> w(NodeWords(3));
  ASSERT_TRUE(EncodeNode({.in_buffer = true,
                          .has_brick = true,
                          .child_group = 5,
                          .brick_slot = 42,
                          .range_min = {90, 1000, 65535},
                          .range_max = {120, 3000, 65535},
                          .averages = {100, 2000, 65535}},
                         w)
                  .ok());
  EXPECT_EQ(w, (std::vector<uint32_t>{0xC0000005u, 0x0000002Au, 0x07D00064u, 0x0000FFFFu,
                                      0x0078005Au, 0x0BB803E8u, 0xFFFFFFFFu}));
}

TEST(NodeEncodingTest, RoundTripsRandomNodes) {
  std::mt19937 rng(17);
  std::uniform_int_distribution<uint32_t> u32;
  std::uniform_int_distribution<int> u16(0, 65535);
  for (int channels = 1; channels <= 9; ++channels) {
    for (int trial = 0; trial < 200; ++trial) {
      DeviceNode node;
      node.has_brick = (trial & 1) != 0;
      node.in_buffer = node.has_brick && (trial & 2) != 0;
      node.child_group = trial < 3 ? std::vector<uint32_t>{0, 1, kMaxChildGroup}[trial]
                                   : u32(rng) & kNodeChildGroupMask;
      node.brick_slot = node.in_buffer ? (trial == 2 ? 0xffffffffu : u32(rng)) : 0;
      for (int c = 0; c < channels; ++c) {
        node.averages.push_back(static_cast<uint16_t>(trial == 0   ? 0
                                                      : trial == 1 ? 65535
                                                                   : u16(rng)));
        const int a = u16(rng);
        const int b = u16(rng);
        node.range_min.push_back(static_cast<uint16_t>(std::min(a, b)));
        node.range_max.push_back(static_cast<uint16_t>(std::max(a, b)));
      }
      std::vector<uint32_t> words(NodeWords(channels));
      ASSERT_TRUE(EncodeNode(node, words).ok());
      EXPECT_EQ(DecodeNode(words, channels), node) << "channels " << channels << " trial " << trial;
    }
  }
}

TEST(NodeEncodingTest, RejectsUnencodableNodesWithoutWriting) {
  std::vector<uint32_t> words(4, 0x5a5a5a5a);
  const std::vector<uint32_t> untouched = words;

  Status s = EncodeNode({.child_group = kMaxChildGroup + 1, .averages = {1}}, words);
  EXPECT_EQ(s.code(), StatusCode::kOutOfRange);
  EXPECT_NE(s.message().find("1073741824"), std::string::npos) << s.message();
  s = EncodeNode({.child_group = 0xffffffffu, .averages = {1}}, words);
  EXPECT_EQ(s.code(), StatusCode::kOutOfRange);
  s = EncodeNode({.in_buffer = true, .has_brick = false, .averages = {1}}, words);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  s = EncodeNode({.averages = {}}, words);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  s = EncodeNode({.averages = {1, 2, 3}}, words);  // 3 channels need 7 words.
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("need 7 words, got 4"), std::string::npos) << s.message();
  s = EncodeNode({.range_min = {5}, .range_max = {4}, .averages = {1}}, words);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  s = EncodeNode({.range_min = {5}, .averages = {1}}, words);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(words, untouched);
}

TEST(NodeEncodingTest, QuantizedAveragesAreRoundedToNearestAndLossless) {
  EXPECT_EQ(QuantizeAverage(2.5, 2), 3);  // Ties round up.
  EXPECT_EQ(QuantizeAverage(2.4999, 2), 2);
  EXPECT_EQ(QuantizeAverage(2.5001, 1), 3);
  EXPECT_EQ(QuantizeAverage(-3.0, 2), 0);
  EXPECT_EQ(QuantizeAverage(70000.0, 2), 65535);
  EXPECT_EQ(QuantizeAverage(65534.5, 2), 65535);
  EXPECT_EQ(QuantizeAverage(254.6, 1), 255);
  EXPECT_EQ(QuantizeAverage(300.0, 1), 255);
  EXPECT_EQ(QuantizeAverage(std::nan(""), 2), 0);
  EXPECT_EQ(QuantizeAverage(std::numeric_limits<double>::infinity(), 2), 65535);
  // Every stored value survives exactly (lossless for uint8 and uint16 data).
  for (int v = 0; v <= 65535; ++v) ASSERT_EQ(QuantizeAverage(v, 2), v);
  for (int v = 0; v <= 255; ++v) ASSERT_EQ(QuantizeAverage(v, 1), v);
  // A mean from an integer sum rounds like the integer rule (sum + n/2) / n used for parents —
  // checked for n up to a full 64^3 brick (n even and odd).
  std::mt19937_64 rng(23);
  for (int trial = 0; trial < 20000; ++trial) {
    const uint64_t n = std::uniform_int_distribution<uint64_t>(1, 64 * 64 * 64)(rng);
    const uint64_t sum = std::uniform_int_distribution<uint64_t>(0, n * 65535)(rng);
    const double mean = static_cast<double>(sum) / static_cast<double>(n);
    ASSERT_EQ(QuantizeAverage(mean, 2), (sum + n / 2) / n) << sum << "/" << n;
  }
}

TEST(NodeEncodingTest, WriteAndReadNodesInABuffer) {
  constexpr int kChannels = 3;
  std::vector<uint32_t> buffer(NodeWords(kChannels) * 17, 0);
  for (uint64_t id = 0; id < 17; ++id) {
    DeviceNode node{.has_brick = id % 2 == 1,
                    .child_group = static_cast<uint32_t>(id * 3),
                    .averages = {static_cast<uint16_t>(id), static_cast<uint16_t>(id + 100),
                                 static_cast<uint16_t>(id + 200)}};
    ASSERT_TRUE(WriteNode(buffer, id, node).ok());
  }
  for (uint64_t id = 0; id < 17; ++id) {
    Result<DeviceNode> node = ReadNode(buffer, id, kChannels);
    ASSERT_TRUE(node.ok());
    EXPECT_EQ(node->has_brick, id % 2 == 1);
    EXPECT_EQ(node->child_group, id * 3);
    EXPECT_EQ(node->averages,
              (std::vector<uint16_t>{static_cast<uint16_t>(id), static_cast<uint16_t>(id + 100),
                                     static_cast<uint16_t>(id + 200)}));
    // Words land exactly at node_id * NodeWords.
    EXPECT_EQ(buffer[NodeWordOffset(id, kChannels)], id * 3 | (id % 2 == 1 ? kNodeHasBrickBit : 0));
  }
  const DeviceNode any{.averages = {1, 2, 3}};
  EXPECT_EQ(WriteNode(buffer, 17, any).code(), StatusCode::kOutOfRange);
  EXPECT_EQ(WriteNode(buffer, std::numeric_limits<uint64_t>::max(), any).code(),
            StatusCode::kOutOfRange);
  EXPECT_EQ(
      WriteNode(std::span<uint32_t>(buffer).first(NodeWords(kChannels) * 2 - 1), 1, any).code(),
      StatusCode::kOutOfRange);
  EXPECT_EQ(ReadNode(buffer, 17, kChannels).status().code(), StatusCode::kOutOfRange);
  EXPECT_EQ(ReadNode(buffer, (uint64_t{1} << 62), kChannels).status().code(),
            StatusCode::kOutOfRange);
  EXPECT_EQ(ReadNode(buffer, 0, 0).status().code(), StatusCode::kInvalidArgument);
}

// Brute force: the root's pseudo-group plus one group per non-virtual node above level 0.
uint64_t CountChildGroups(const BrickGeometry& g) {
  uint64_t groups = 1;
  for (int l = 1; l < g.level_count(); ++l) {
    const int64_t n = g.NodesPerAxis(l);
    for (int64_t z = 0; z < n; ++z)
      for (int64_t y = 0; y < n; ++y)
        for (int64_t x = 0; x < n; ++x) groups += g.IsVirtual({l, {x, y, z}}) ? 0 : 1;
  }
  return groups;
}

TEST(NodeEncodingTest, ChildGroupCapacity) {
  // docs/octree_format.md: a full 65536^3 volume with 64^3 bricks needs
  // (65536/64)^3 * 8/7 / 8 ~= 153,391,689.1 groups, i.e. 1 + (8^10 - 1) / 7 exactly.
  const BrickGeometry full = Make({65536, 65536, 65536}, {64, 64, 64}, 4);
  EXPECT_EQ(MaxChildGroups(full), 1 + ((uint64_t{1} << 30) - 1) / 7);
  EXPECT_EQ(MaxChildGroups(full), 153'391'690u);
  EXPECT_EQ(MaxChildGroups(full),
            static_cast<uint64_t>(std::ceil(std::pow(65536.0 / 64.0, 3) * 8.0 / 7.0 / 8.0)));
  EXPECT_LT(MaxChildGroups(full), kChildGroupCapacity);
  EXPECT_TRUE(FitsDeviceEncoding(full));
  // Every node id of that tree fits the 8 * 2^30 id space: (groups) * 8 nodes.
  EXPECT_LE(ChildNodeId(static_cast<uint32_t>(MaxChildGroups(full) - 1), 7), uint64_t{8} << 30);
  // 32^3 bricks add a level: 1 + (8^11 - 1) / 7 = 1,227,133,514 > 2^30.
  const BrickGeometry deep = Make({65536, 65536, 65536}, {32, 32, 32});
  EXPECT_EQ(MaxChildGroups(deep), 1 + ((uint64_t{1} << 33) - 1) / 7);
  EXPECT_FALSE(FitsDeviceEncoding(deep));
  // Flat volumes only count non-virtual nodes: 65536 x 65536 x 16 with 32^3 bricks fits.
  EXPECT_TRUE(FitsDeviceEncoding(Make({65536, 65536, 16}, {32, 32, 32})));
  // Brute force on small geometries with virtual parts.
  for (const BrickGeometry& g :
       {Make({67, 33, 5}, {2, 2, 2}), Make({67, 33, 5}, {64, 32, 16}), Make({1, 1, 1}, {2, 2, 2}),
        Make({1, 1, 40}, {2, 2, 2}), Make({100, 60, 30}, {8, 4, 2})}) {
    EXPECT_EQ(MaxChildGroups(g), CountChildGroups(g)) << g.ToString();
    EXPECT_TRUE(FitsDeviceEncoding(g));
  }
}

}  // namespace
}  // namespace octoscope::octree
