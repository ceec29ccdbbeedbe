// BilinearUpsample (server/render/bilinear_upsample.h) against closed forms: an affine image is
// reproduced exactly between the outer pixel centres and clamped beyond them; an integer ratio
// puts input pixel centres on output pixels and blends neighbours by distance.
#include "render/bilinear_upsample.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

namespace octoscope::render {
namespace {

RenderImage Affine(int w, int h) {
  RenderImage image;
  image.width = w;
  image.height = h;
  image.rgba.resize(static_cast<size_t>(w) * h * 4);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      float* p = image.rgba.data() + (static_cast<size_t>(y) * w + x) * 4;
      p[0] = 0.1f * x;
      p[1] = 0.05f * y;
      p[2] = 0.02f * x + 0.03f * y;
      p[3] = 1;
    }
  }
  return image;
}

TEST(BilinearUpsampleTest, SameSizeIsTheIdentity) {
  const RenderImage image = Affine(5, 3);
  EXPECT_EQ(BilinearUpsample(image, 5, 3).rgba, image.rgba);
}

TEST(BilinearUpsampleTest, AffineImagesAreReproducedAndClampedAtTheEdges) {
  const int w = 7, h = 5, W = 29, H = 13;  // Non-integer ratios.
  const RenderImage out = BilinearUpsample(Affine(w, h), W, H);
  ASSERT_EQ(out.width, W);
  ASSERT_EQ(out.height, H);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      // The input coordinates of the output centre, clamped to [0, n - 1].
      const double sx = std::clamp((x + 0.5) * w / W - 0.5, 0.0, w - 1.0);
      const double sy = std::clamp((y + 0.5) * h / H - 0.5, 0.0, h - 1.0);
      const auto p = out.Pixel(x, y);
      EXPECT_NEAR(p[0], 0.1 * sx, 1e-5) << x << "," << y;
      EXPECT_NEAR(p[1], 0.05 * sy, 1e-5) << x << "," << y;
      EXPECT_NEAR(p[2], 0.02 * sx + 0.03 * sy, 1e-5) << x << "," << y;
      EXPECT_NEAR(p[3], 1, 1e-6);
    }
  }
}

TEST(BilinearUpsampleTest, DoublingBlendsNeighboursAFourthAndThreeFourths) {
  RenderImage image;
  image.width = 2;
  image.height = 1;
  image.rgba = {0, 0, 0, 0, 1, 1, 1, 1};
  const RenderImage out = BilinearUpsample(image, 4, 2);
  // Output centres at input x = -0.25 (clamped to 0), 0.25, 0.75, 1.25 (clamped to 1).
  const float expected[4] = {0, 0.25f, 0.75f, 1};
  for (int y = 0; y < 2; ++y) {
    for (int x = 0; x < 4; ++x) {
      for (int k = 0; k < 4; ++k) EXPECT_FLOAT_EQ(out.Pixel(x, y)[k], expected[x]);
    }
  }
}

}  // namespace
}  // namespace octoscope::render
