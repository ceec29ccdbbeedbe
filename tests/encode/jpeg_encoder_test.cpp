#include "encode/jpeg_encoder.h"

#include <gtest/gtest.h>
#include <turbojpeg.h>

#include <cmath>
#include <vector>

namespace octoscope::encode {
namespace {

// A smooth premultiplied RGBA image.
std::vector<float> Gradient(int w, int h) {
  std::vector<float> rgba(static_cast<size_t>(w) * h * 4);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      float* p = &rgba[(static_cast<size_t>(y) * w + x) * 4];
      p[0] = static_cast<float>(x) / w;
      p[1] = static_cast<float>(y) / h;
      p[2] = 0.5f;
      p[3] = 1;
    }
  }
  return rgba;
}

// Decodes with libturbojpeg's decompressor; max |decoded − expected byte| over RGB.
int MaxError(std::span<const uint8_t> jpeg, const std::vector<float>& rgba, int w, int h) {
  tjhandle tj = tjInitDecompress();
  std::vector<uint8_t> rgb(static_cast<size_t>(w) * h * 3);
  EXPECT_EQ(tjDecompress2(tj, jpeg.data(), jpeg.size(), rgb.data(), w, 0, h, TJPF_RGB, 0), 0);
  tjDestroy(tj);
  int worst = 0;
  for (size_t i = 0; i < static_cast<size_t>(w) * h; ++i) {
    for (int c = 0; c < 3; ++c) {
      const int expected = static_cast<int>(std::lround(rgba[i * 4 + c] * 255));
      worst = std::max(worst, std::abs(rgb[i * 3 + c] - expected));
    }
  }
  return worst;
}

TEST(JpegEncoderTest, EncodesFramesOfChangingSizesWithOneHandleAndBuffer) {
  auto encoder = JpegEncoder::Create();
  ASSERT_TRUE(encoder.ok());
  for (auto [w, h] :
       {std::pair{64, 48}, std::pair{320, 200}, std::pair{17, 5}, std::pair{64, 48}}) {
    const auto rgba = Gradient(w, h);
    for (bool accurate : {false, true}) {
      auto jpeg = (*encoder)->Encode(rgba.data(), w, h, 95, accurate);
      ASSERT_TRUE(jpeg.ok()) << jpeg.status().ToString();
      EXPECT_EQ((*jpeg)[0], 0xFF);
      EXPECT_EQ((*jpeg)[1], 0xD8);
      EXPECT_LE(MaxError(*jpeg, rgba, w, h), 8) << w << "x" << h;
    }
  }
}

TEST(JpegEncoderTest, RefusesBadQualityAndSizes) {
  auto encoder = JpegEncoder::Create();
  ASSERT_TRUE(encoder.ok());
  const auto rgba = Gradient(8, 8);
  EXPECT_FALSE((*encoder)->Encode(rgba.data(), 8, 8, 0, false).ok());
  EXPECT_FALSE((*encoder)->Encode(rgba.data(), 0, 8, 90, false).ok());
}

TEST(JpegEncoderTest, PoolReusesReturnedEncoders) {
  JpegEncoderPool pool;
  JpegEncoder* first = nullptr;
  {
    auto lease = pool.Acquire();
    ASSERT_TRUE(lease.ok());
    first = lease->operator->();
  }
  auto again = pool.Acquire();
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->operator->(), first);
  auto second = pool.Acquire();
  ASSERT_TRUE(second.ok());
  EXPECT_NE(second->operator->(), first);
}

}  // namespace
}  // namespace octoscope::encode
