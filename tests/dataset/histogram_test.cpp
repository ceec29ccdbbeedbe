// Histogram against a direct count and a sort of the same values (independent references).
#include "dataset/histogram.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <vector>

#include "volume/value_map.h"

namespace octoscope::dataset {
namespace {

std::span<const std::byte> Bytes(const std::vector<uint16_t>& v) {
  return std::as_bytes(std::span<const uint16_t>(v));
}

// Same channels, stored types and counts.
void ExpectSameCounts(const Histogram& a, const Histogram& b) {
  ASSERT_EQ(a.channels(), b.channels());
  for (int c = 0; c < a.channels(); ++c) {
    EXPECT_EQ(a.value_maps()[c].stored_type, b.value_maps()[c].stored_type);
    EXPECT_EQ(a.total(c), b.total(c));
    EXPECT_TRUE(
        std::equal(a.counts(c).begin(), a.counts(c).end(), b.counts(c).begin(), b.counts(c).end()))
        << "channel " << c;
  }
}

// The q-quantile as Histogram::Percentile defines it: the value at rank ceil(q * n) (>= 1).
double NthOfSorted(std::vector<double> values, double q) {
  std::sort(values.begin(), values.end());
  size_t rank = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
  rank = std::max<size_t>(rank, 1);
  return values[rank - 1];
}

TEST(HistogramTest, CountsEqualDirectCount) {
  std::mt19937 rng(7);
  std::vector<uint16_t> values(100000);
  for (auto& v : values)
    v = static_cast<uint16_t>(
        std::min<double>(65535, std::abs(std::normal_distribution<>(3000, 800)(rng))));
  Histogram h({volume::FixedValueMap(volume::DataType::kUint16)});
  h.Add(0, Bytes(values));
  std::map<uint16_t, uint64_t> direct;
  for (uint16_t v : values) ++direct[v];
  EXPECT_EQ(h.total(0), values.size());
  for (uint32_t v = 0; v < 65536; ++v) {
    const auto it = direct.find(static_cast<uint16_t>(v));
    ASSERT_EQ(h.counts(0)[v], it == direct.end() ? 0u : it->second) << v;
  }
  EXPECT_EQ(*h.MinStored(0), direct.begin()->first);
  EXPECT_EQ(*h.MaxStored(0), direct.rbegin()->first);
  const std::vector<double> as_double(values.begin(), values.end());
  for (double q : {0.0, 0.001, 0.5, 0.999, 1.0}) {
    EXPECT_EQ(*h.Percentile(0, q), NthOfSorted(as_double, q)) << q;
  }
  // Subtracting half leaves exactly the other half.
  const std::vector<uint16_t> first(values.begin(), values.begin() + 50000);
  const std::vector<uint16_t> second(values.begin() + 50000, values.end());
  h.Subtract(0, Bytes(first));
  Histogram expected({volume::FixedValueMap(volume::DataType::kUint16)});
  expected.Add(0, Bytes(second));
  ExpectSameCounts(h, expected);
}

TEST(HistogramTest, SignedPercentilesInFileUnits) {
  std::mt19937 rng(3);
  std::vector<int16_t> values(20000);
  for (auto& v : values)
    v = static_cast<int16_t>(std::uniform_int_distribution<int>(-30000, 1200)(rng));
  const volume::ValueMap map = volume::FixedValueMap(volume::DataType::kInt16);
  // Stored samples as the octree holds them.
  std::vector<uint16_t> stored;
  for (int16_t v : values) stored.push_back(static_cast<uint16_t>(map.ToStored(v)));
  Histogram h({map});
  h.Add(0, Bytes(stored));
  const std::vector<double> as_double(values.begin(), values.end());
  for (double q : {0.001, 0.25, 0.999}) {
    EXPECT_EQ(*h.Percentile(0, q), NthOfSorted(as_double, q)) << q;
  }
  EXPECT_FALSE(Histogram({map}).Percentile(0, 0.5).has_value());
}

TEST(HistogramTest, FileRoundTripAndDamage) {
  const std::vector<volume::ValueMap> maps{volume::FixedValueMap(volume::DataType::kUint8),
                                           volume::FixedValueMap(volume::DataType::kUint16)};
  Histogram h(maps);
  std::vector<uint8_t> a{1, 2, 2, 255};
  h.Add(0, std::as_bytes(std::span<const uint8_t>(a)));
  h.Add(1, Bytes(std::vector<uint16_t>{9, 9, 40000}));
  const octree::SourceIdentity source{0x1234, 99};
  const std::string bytes = SerializeHistogram(h, source);
  auto parsed = ParseHistogram(bytes, source, maps);
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  ExpectSameCounts(*parsed, h);
  EXPECT_FALSE(ParseHistogram(bytes, octree::SourceIdentity{0x1235, 99}, maps).ok());
  EXPECT_FALSE(ParseHistogram(bytes.substr(0, bytes.size() - 1), source, maps).ok());
  EXPECT_FALSE(ParseHistogram(bytes, source, {maps[0]}).ok());
  for (size_t i = 0; i < bytes.size(); i += 97) {
    std::string damaged = bytes;
    damaged[i] = static_cast<char>(damaged[i] ^ 0x5a);
    auto r = ParseHistogram(damaged, source, maps);
    if (r.ok()) {
      ExpectSameCounts(*r, h);  // Never anything else than the original.
    }
  }
}

}  // namespace
}  // namespace octoscope::dataset
