#include "volume/value_map.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <vector>

namespace octoscope::volume {
namespace {

template <typename In, typename Out>
std::vector<Out> Convert(const ValueMap& map, const std::vector<In>& in) {
  std::vector<Out> out(in.size());
  ConvertToStored(map, std::as_bytes(std::span(in)), std::as_writable_bytes(std::span(out)));
  return out;
}

TEST(ValueMapTest, NarrowUnsignedTypesAreIdentity) {
  ValueMap m = FixedValueMap(DataType::kUint16);
  EXPECT_EQ(m.stored_type, DataType::kUint16);
  EXPECT_TRUE(m.exact());
  auto out = Convert<uint16_t, uint16_t>(m, {0, 1, 65535});
  EXPECT_EQ(out, (std::vector<uint16_t>{0, 1, 65535}));
  EXPECT_EQ(FixedValueMap(DataType::kUint8).stored_type, DataType::kUint8);
}

TEST(ValueMapTest, SignedTypesShiftExactly) {
  ValueMap m8 = FixedValueMap(DataType::kInt8);
  EXPECT_EQ(m8.stored_type, DataType::kUint8);
  EXPECT_EQ((Convert<int8_t, uint8_t>(m8, {-128, 0, 127})), (std::vector<uint8_t>{0, 128, 255}));
  EXPECT_DOUBLE_EQ(m8.ToFile(0), -128);
  ValueMap m16 = FixedValueMap(DataType::kInt16);
  EXPECT_EQ((Convert<int16_t, uint16_t>(m16, {-32768, -1, 32767})),
            (std::vector<uint16_t>{0, 32767, 65535}));
  for (int v = -32768; v <= 32767; v += 97) EXPECT_DOUBLE_EQ(m16.ToFile(m16.ToStored(v)), v);
}

TEST(ValueMapTest, FloatRangeMapsOntoFullUint16) {
  auto m = ValueMapForRange(DataType::kFloat32, -1.5f, 2.5f);
  ASSERT_TRUE(m.ok());
  EXPECT_FALSE(m->exact());
  float nan = std::numeric_limits<float>::quiet_NaN();
  auto out = Convert<float, uint16_t>(*m, {-1.5f, 2.5f, 0.5f, nan, -100.f, 100.f});
  EXPECT_EQ(out[0], 0);
  EXPECT_EQ(out[1], 65535);
  EXPECT_EQ(out[2], 32768);  // (0.5 + 1.5) / 4 * 65535 = 32767.5 rounds to even.
  EXPECT_EQ(out[3], 0);      // NaN.
  EXPECT_EQ(out[4], 0);      // Clamped below.
  EXPECT_EQ(out[5], 65535);  // Clamped above.
  // Round-trip error is at most half a step.
  for (double v = -1.5; v <= 2.5; v += 0.01) {
    EXPECT_NEAR(m->ToFile(m->ToStored(v)), v, m->scale / 2 + 1e-12);
  }
}

TEST(ValueMapTest, ConstantRangeAndBadRange) {
  auto m = ValueMapForRange(DataType::kUint32, 7, 7);
  ASSERT_TRUE(m.ok());
  EXPECT_EQ((Convert<uint32_t, uint16_t>(*m, {7})), (std::vector<uint16_t>{0}));
  EXPECT_FALSE(ValueMapForRange(DataType::kFloat32, 2, 1).ok());
  EXPECT_FALSE(ValueMapForRange(DataType::kFloat64, 0, INFINITY).ok());
}

}  // namespace
}  // namespace octoscope::volume
