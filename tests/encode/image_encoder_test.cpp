#include "encode/image_encoder.h"

#include <gtest/gtest.h>
#include <turbojpeg.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "encode/png_test_decoder.h"

namespace octoscope::encode {
namespace {

using octoscope::testing::DecodedPng;
using octoscope::testing::DecodeTestPng;
using octoscope::testing::ReadBe32;
using octoscope::testing::TestCrc32;

Rgba8Image RandomImage(int w, int h, uint32_t seed) {
  std::mt19937 rng(seed);
  Rgba8Image image{w, h, std::vector<uint8_t>(static_cast<size_t>(w) * h * 4)};
  for (auto& b : image.pixels) b = static_cast<uint8_t>(rng());
  return image;
}

// A smooth image (gradients plus a blob): what JPEG is meant for, and rows where every PNG
// filter type wins somewhere.
Rgba8Image SmoothImage(int w, int h) {
  Rgba8Image image{w, h, std::vector<uint8_t>(static_cast<size_t>(w) * h * 4)};
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      uint8_t* p = &image.pixels[(static_cast<size_t>(y) * w + x) * 4];
      const double r2 = (x - w / 2.0) * (x - w / 2.0) + (y - h / 3.0) * (y - h / 3.0);
      p[0] = static_cast<uint8_t>(255.0 * x / (w - 1));
      p[1] = static_cast<uint8_t>(255.0 * y / (h - 1));
      p[2] = static_cast<uint8_t>(255.0 * std::exp(-r2 / (w * h / 8.0)));
      p[3] = 255;
    }
  }
  return image;
}

TEST(ToRgba8Test, RoundsClampsAndKeepsPremultipliedColour) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  // Two pixels: a half-transparent premultiplied colour, and out-of-range / non-finite values.
  const std::vector<float> rgba = {0.25f, 0.5f, 0.0f, 0.5f, -0.1f, 1.7f, nan, inf};
  const Rgba8Image image = ToRgba8(rgba.data(), 2, 1, AlphaMode::kOverBlack);
  ASSERT_EQ(image.width, 2);
  ASSERT_EQ(image.height, 1);
  // round(0.25 * 255) = 64 (63.75), round(0.5 * 255) = 128 (127.5 rounds half away from zero).
  EXPECT_EQ(image.pixels, (std::vector<uint8_t>{64, 128, 0, 128, 0, 255, 0, 255}));
}

// PNG needs straight alpha: premultiplied (0.25, 0.5, 0, 0.5) is the colour (0.5, 1, 0) at 50 %;
// a fully transparent pixel has no colour; an opaque one is unchanged.
TEST(ToRgba8Test, StraightAlphaDividesTheColourByAlpha) {
  const std::vector<float> rgba = {0.25f, 0.5f, 0.0f, 0.5f, 0.0f, 0.0f, 0.0f, 0.0f,
                                   0.2f,  0.4f, 0.6f, 1.0f, 0.1f, 0.0f, 0.0f, 0.2f};
  const Rgba8Image image = ToRgba8(rgba.data(), 4, 1, AlphaMode::kStraight);
  EXPECT_EQ(image.pixels, (std::vector<uint8_t>{128, 255, 0, 128, 0, 0, 0, 0,  //
                                                51, 102, 153, 255, 128, 0, 0, 51}));
}

TEST(ToRgba8Test, EveryByteValueIsReachableFromItsOwnFraction) {
  std::vector<float> rgba(256 * 4);
  for (int v = 0; v < 256; ++v) {
    for (int c = 0; c < 4; ++c) rgba[v * 4 + c] = v / 255.0f;
  }
  const Rgba8Image image = ToRgba8(rgba.data(), 256, 1, AlphaMode::kOverBlack);
  for (int v = 0; v < 256; ++v) {
    for (int c = 0; c < 4; ++c) ASSERT_EQ(image.pixels[v * 4 + c], v) << v;
  }
}

TEST(EncodePngTest, DecodesBackExactlyWithValidStructure) {
  for (const Rgba8Image& image : {RandomImage(37, 23, 1), SmoothImage(64, 48), RandomImage(1, 1, 2),
                                  RandomImage(300, 2, 3)}) {
    auto png = EncodePng(image);
    ASSERT_TRUE(png.ok()) << png.status().ToString();
    const DecodedPng decoded = DecodeTestPng(*png);
    ASSERT_TRUE(decoded.ok) << decoded.error;
    EXPECT_EQ(decoded.width, image.width);
    EXPECT_EQ(decoded.height, image.height);
    EXPECT_EQ(decoded.channels, 4);
    EXPECT_EQ(decoded.pixels, image.pixels);
    ASSERT_GE(decoded.chunk_types.size(), 3u);
    EXPECT_EQ(decoded.chunk_types.front(), "IHDR");
    EXPECT_EQ(decoded.chunk_types.back(), "IEND");
  }
}

TEST(EncodePngTest, IhdrBytesAndCrcAreThoseOfTheSpec) {
  auto png = EncodePng(RandomImage(513, 7, 4));
  ASSERT_TRUE(png.ok());
  const std::vector<uint8_t>& f = *png;
  const std::vector<uint8_t> signature = {0x89, 0x50, 0x4E, 0x47, 0x0D, 0x0A, 0x1A, 0x0A};
  ASSERT_GT(f.size(), 33u);
  EXPECT_TRUE(std::equal(signature.begin(), signature.end(), f.begin()));
  EXPECT_EQ(ReadBe32(&f[8]), 13u);
  EXPECT_EQ(std::string(reinterpret_cast<const char*>(&f[12]), 4), "IHDR");
  EXPECT_EQ(ReadBe32(&f[16]), 513u);
  EXPECT_EQ(ReadBe32(&f[20]), 7u);
  EXPECT_EQ((std::vector<uint8_t>(f.begin() + 24, f.begin() + 29)),
            (std::vector<uint8_t>{8, 6, 0, 0, 0}));
  EXPECT_EQ(ReadBe32(&f[29]), TestCrc32(&f[12], 17));
  // IEND is the last 12 bytes with its well-known CRC.
  const std::vector<uint8_t> iend = {0, 0, 0, 0, 'I', 'E', 'N', 'D', 0xAE, 0x42, 0x60, 0x82};
  EXPECT_TRUE(std::equal(iend.begin(), iend.end(), f.end() - 12));
}

TEST(EncodePngTest, LargeImageSpansSeveralIdatChunksAndCompressesSmoothData) {
  // 1024 x 1024 random pixels do not compress: > 4 MiB of IDAT data, several chunks.
  const Rgba8Image random = RandomImage(1024, 1024, 5);
  auto png = EncodePng(random);
  ASSERT_TRUE(png.ok());
  const DecodedPng decoded = DecodeTestPng(*png);
  ASSERT_TRUE(decoded.ok) << decoded.error;
  EXPECT_EQ(decoded.pixels, random.pixels);
  EXPECT_GE(std::count(decoded.chunk_types.begin(), decoded.chunk_types.end(), "IDAT"), 4);
  // Gradients filter to near-constant residuals and compress far below the raw size.
  const Rgba8Image smooth = SmoothImage(256, 256);
  auto smooth_png = EncodePng(smooth);
  ASSERT_TRUE(smooth_png.ok());
  EXPECT_LT(smooth_png->size(), smooth.pixels.size() / 8);
}

TEST(EncodePngTest, BadSizesAreErrors) {
  EXPECT_EQ(EncodePng(Rgba8Image{0, 5, {}}).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodePng(Rgba8Image{5, -1, {}}).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodePng(Rgba8Image{kMaxEncodeSize + 1, 1, {}}).status().code(),
            StatusCode::kInvalidArgument);
  // Pixel count disagreeing with the size.
  Rgba8Image short_image = RandomImage(4, 4, 6);
  short_image.pixels.pop_back();
  EXPECT_EQ(EncodePng(short_image).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeJpeg(short_image, 90).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeJpeg(Rgba8Image{0, 0, {}}, 90).status().code(), StatusCode::kInvalidArgument);
}

// Decodes a JPEG with libturbojpeg into RGB.
std::vector<uint8_t> DecodeJpeg(const std::vector<uint8_t>& jpeg, int* width, int* height) {
  tjhandle tj = tjInitDecompress();
  int subsampling = 0, colourspace = 0;
  std::vector<uint8_t> rgb;
  if (tjDecompressHeader3(tj, jpeg.data(), jpeg.size(), width, height, &subsampling,
                          &colourspace) == 0) {
    rgb.resize(static_cast<size_t>(*width) * *height * 3);
    if (tjDecompress2(tj, jpeg.data(), jpeg.size(), rgb.data(), *width, 0, *height, TJPF_RGB, 0) !=
        0) {
      rgb.clear();
    }
  }
  tjDestroy(tj);
  return rgb;
}

TEST(EncodeJpegTest, DecodesBackWithinJpegTolerance) {
  const Rgba8Image image = SmoothImage(96, 64);
  auto jpeg = EncodeJpeg(image, 95);
  ASSERT_TRUE(jpeg.ok()) << jpeg.status().ToString();
  ASSERT_GE(jpeg->size(), 4u);
  EXPECT_EQ((*jpeg)[0], 0xFF);  // SOI marker.
  EXPECT_EQ((*jpeg)[1], 0xD8);
  int w = 0, h = 0;
  const std::vector<uint8_t> rgb = DecodeJpeg(*jpeg, &w, &h);
  ASSERT_EQ(w, 96);
  ASSERT_EQ(h, 64);
  ASSERT_EQ(rgb.size(), 96u * 64 * 3);
  double sum_abs = 0;
  int max_abs = 0;
  for (size_t p = 0; p < 96u * 64; ++p) {
    for (int c = 0; c < 3; ++c) {
      const int e = std::abs(int{rgb[p * 3 + c]} - int{image.pixels[p * 4 + c]});
      sum_abs += e;
      max_abs = std::max(max_abs, e);
    }
  }
  EXPECT_LT(sum_abs / (96.0 * 64 * 3), 2.0);  // Mean error of a quality-95 smooth image.
  EXPECT_LE(max_abs, 16);
}

TEST(EncodeJpegTest, IgnoresAlphaAndChecksQuality) {
  // The same colours with different alphas encode identically (RGB over black only).
  Rgba8Image a = SmoothImage(32, 32), b = a;
  for (size_t i = 3; i < b.pixels.size(); i += 4) b.pixels[i] = static_cast<uint8_t>(i);
  auto ja = EncodeJpeg(a, 80), jb = EncodeJpeg(b, 80);
  ASSERT_TRUE(ja.ok() && jb.ok());
  EXPECT_EQ(*ja, *jb);
  // Lower quality, smaller file.
  auto low = EncodeJpeg(a, 20);
  ASSERT_TRUE(low.ok());
  EXPECT_LT(low->size(), ja->size());
  EXPECT_EQ(EncodeJpeg(a, 0).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(EncodeJpeg(a, 101).status().code(), StatusCode::kInvalidArgument);
}

TEST(ImageFormatTest, FromExtension) {
  EXPECT_EQ(*ImageFormatFromPath("out/a.png"), ImageFormat::kPng);
  EXPECT_EQ(*ImageFormatFromPath("A.PNG"), ImageFormat::kPng);
  EXPECT_EQ(*ImageFormatFromPath("x.jpg"), ImageFormat::kJpeg);
  EXPECT_EQ(*ImageFormatFromPath("x.JPEG"), ImageFormat::kJpeg);
  EXPECT_FALSE(ImageFormatFromPath("x.tif").ok());
  EXPECT_FALSE(ImageFormatFromPath("dir.png/file").ok());
  EXPECT_FALSE(ImageFormatFromPath("png").ok());
}

}  // namespace
}  // namespace octoscope::encode
