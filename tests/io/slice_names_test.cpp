// The file-name conventions of slice folders: channel and z tokens of plane files as an
// acquisition names them, and channel sub-folders.
#include "io/slice_names.h"

#include <gtest/gtest.h>

namespace octoscope::io {
namespace {

void ExpectPlane(const char* stem, std::optional<uint64_t> channel, uint64_t z) {
  auto name = ParsePlaneName(stem);
  ASSERT_TRUE(name.ok()) << stem << ": " << name.status().ToString();
  EXPECT_EQ(name->channel, channel) << stem;
  EXPECT_EQ(name->z, z) << stem;
}

TEST(SliceNamesTest, PlaneNames) {
  ExpectPlane("img_c0_z12", 0, 12);
  ExpectPlane("ch1-0005", 1, 5);
  ExpectPlane("C01Z005", 1, 5);
  ExpectPlane("scan_w2_z3", 2, 3);
  ExpectPlane("z7_channel3", 3, 7);
  ExpectPlane("plane_0042", std::nullopt, 42);
  ExpectPlane("0001", std::nullopt, 1);
  ExpectPlane("slow5", std::nullopt, 5);      // "w" after a letter is no marker.
  ExpectPlane("run2_t0_c1_z009", 1, 9);       // The z marker wins over other numbers.
  ExpectPlane("run2_0009", std::nullopt, 9);  // Without one: the last number.
  ExpectPlane("c1_99999999999999999999999", 1, UINT64_MAX);  // Saturates, never overflows.
}

TEST(SliceNamesTest, BadPlaneNames) {
  for (const char* stem : {"", "image", "c1", "c1_c2_z3", "z1_z2", "ch0"}) {
    auto name = ParsePlaneName(stem);
    EXPECT_FALSE(name.ok()) << stem;
    if (!name.ok()) {
      EXPECT_EQ(name.status().code(), StatusCode::kInvalidArgument);
      EXPECT_NE(name.status().message().find(stem), std::string::npos) << name.status().ToString();
    }
  }
}

TEST(SliceNamesTest, ChannelFolders) {
  EXPECT_EQ(ChannelFolderNumber("ch1"), 1u);
  EXPECT_EQ(ChannelFolderNumber("C02"), 2u);
  EXPECT_EQ(ChannelFolderNumber("0"), 0u);
  EXPECT_EQ(ChannelFolderNumber("w3"), 3u);
  EXPECT_EQ(ChannelFolderNumber("gfp"), std::nullopt);
  EXPECT_EQ(ChannelFolderNumber("c1_c2"), std::nullopt);
  EXPECT_EQ(ChannelFolderNumber("run5"), std::nullopt);
}

TEST(SliceNamesTest, TiffNames) {
  EXPECT_TRUE(IsTiffName("a.tif"));
  EXPECT_TRUE(IsTiffName("a.TIFF"));
  EXPECT_FALSE(IsTiffName("a.tif.part"));
  EXPECT_FALSE(IsTiffName("tif"));
}

}  // namespace
}  // namespace octoscope::io
