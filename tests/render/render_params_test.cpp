// Display defaults: distinct channel colours and auto-contrast windows.
#include "render/render_params.h"

#include <gtest/gtest.h>

#include <array>
#include <set>

#include "volume/volume_info.h"

namespace octoscope::render {
namespace {

TEST(DisplayDefaultsTest, ChannelsWithoutColoursGetDistinctOnes) {
  volume::VolumeInfo info;
  info.channels.resize(1);
  EXPECT_EQ(DefaultChannelColor(info, 0), (std::array<double, 3>{1, 1, 1}));
  info.channels.resize(2);
  EXPECT_EQ(DefaultChannelColor(info, 0), (std::array<double, 3>{0, 1, 0}));
  EXPECT_EQ(DefaultChannelColor(info, 1), (std::array<double, 3>{1, 0, 1}));
  info.channels.resize(3);
  std::set<std::array<double, 3>> distinct;
  for (int c = 0; c < 3; ++c) distinct.insert(DefaultChannelColor(info, c));
  EXPECT_EQ(distinct.size(), 3u);
  // A colour the file names wins; black (nothing visible) does not.
  info.channels[1].color = volume::Rgba{255, 128, 0, 255};
  EXPECT_EQ(DefaultChannelColor(info, 1), (std::array<double, 3>{1, 128 / 255.0, 0}));
  info.channels[2].color = volume::Rgba{0, 0, 0, 255};
  EXPECT_EQ(DefaultChannelColor(info, 2), (std::array<double, 3>{0, 0, 1}));
}

TEST(DisplayDefaultsTest, SetWindowMapsLoAndHiToZeroAndOne) {
  ChannelParams c;
  SetWindow(c, 100, 4095);
  EXPECT_DOUBLE_EQ(WindowedValue(c, 100), 0.0);
  EXPECT_DOUBLE_EQ(WindowedValue(c, 4095), 1.0);
  SetWindow(c, 7, 7);  // A constant channel: a one-unit window, never zero.
  EXPECT_GT(c.window, 0);
}

}  // namespace
}  // namespace octoscope::render
