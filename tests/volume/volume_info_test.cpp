#include "volume/volume_info.h"

#include <gtest/gtest.h>

namespace octoscope::volume {
namespace {

TEST(VolumeInfoTest, ValidateCatchesNonsense) {
  VolumeInfo info;
  info.channels.resize(2);
  info.size = {10, 20, 30};
  EXPECT_TRUE(info.Validate().ok());
  EXPECT_EQ(info.VoxelBytes(), 10u * 20 * 30 * 2 * 2);
  info.size[1] = 0;
  EXPECT_FALSE(info.Validate().ok());
  info.size = {1 << 30, 1 << 30, 1 << 30};
  EXPECT_FALSE(info.Validate().ok());  // Overflows 64 bits.
  info.size = {1, 1, 1};
  info.spacing_um[2] = -1.0;
  EXPECT_FALSE(info.Validate().ok());
  info.spacing_um[2] = 2.0;
  info.time = 3;
  EXPECT_FALSE(info.Validate().ok());
  info.time = 0;
  info.channels.clear();
  EXPECT_FALSE(info.Validate().ok());
}

TEST(VolumeInfoTest, ChannelCountIsLimited) {
  VolumeInfo info;
  info.channels.resize(kMaxChannels);
  EXPECT_TRUE(info.Validate().ok());
  info.channels.resize(kMaxChannels + 1);
  const Status status = info.Validate();
  EXPECT_EQ(status.code(), StatusCode::kResourceExhausted);
  EXPECT_NE(status.message().find("65 channels, more than the 64 Octoscope supports"),
            std::string::npos)
      << status.ToString();
}

}  // namespace
}  // namespace octoscope::volume
