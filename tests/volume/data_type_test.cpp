#include "volume/data_type.h"

#include <gtest/gtest.h>

namespace octoscope::volume {
namespace {

TEST(DataTypeTest, NamesRoundTrip) {
  for (DataType t : {DataType::kUint8, DataType::kInt8, DataType::kUint16, DataType::kInt16,
                     DataType::kUint32, DataType::kInt32, DataType::kFloat32, DataType::kFloat64}) {
    EXPECT_EQ(DataTypeFromNumpyName(NumpyName(t)), t);
  }
  EXPECT_EQ(DataTypeFromOmeName("float"), DataType::kFloat32);
  EXPECT_EQ(DataTypeFromOmeName("double"), DataType::kFloat64);
  EXPECT_FALSE(DataTypeFromOmeName("bit").has_value());
  EXPECT_EQ(BytesPerSample(DataType::kFloat64), 8u);
}

}  // namespace
}  // namespace octoscope::volume
