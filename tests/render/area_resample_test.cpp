// AreaResample against an independent reference: each output pixel's footprint integrated by
// dense supersampling of the input (nearest input pixel per sample point).
#include "render/area_resample.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace octoscope::render {
namespace {

RenderImage RandomImage(int w, int h, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0, 1);
  RenderImage image{w, h, std::vector<float>(static_cast<size_t>(w) * h * 4)};
  for (float& v : image.rgba) v = u(rng);
  return image;
}

// The mean of the input over output pixel (x, y)'s footprint, by n x n sample points per output
// pixel placed at the centres of a regular grid.
std::array<double, 4> Reference(const RenderImage& in, int w, int h, int x, int y, int n) {
  std::array<double, 4> sum{};
  const double sx = static_cast<double>(in.width) / w, sy = static_cast<double>(in.height) / h;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double px = (x + (i + 0.5) / n) * sx, py = (y + (j + 0.5) / n) * sy;
      const auto p = in.Pixel(static_cast<int>(px), static_cast<int>(py));
      for (int c = 0; c < 4; ++c) sum[c] += p[c];
    }
  }
  for (double& v : sum) v /= n * n;
  return sum;
}

TEST(AreaResampleTest, IntegerRatiosAreExactBoxAverages) {
  const RenderImage in = RandomImage(8, 6, 1);
  const RenderImage out = AreaResample(in, 4, 3);
  ASSERT_EQ(out.width, 4);
  ASSERT_EQ(out.height, 3);
  ASSERT_EQ(out.rgba.size(), 4u * 3 * 4);
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 4; ++x) {
      for (int c = 0; c < 4; ++c) {
        const double mean = (in.Pixel(2 * x, 2 * y)[c] + in.Pixel(2 * x + 1, 2 * y)[c] +
                             in.Pixel(2 * x, 2 * y + 1)[c] + in.Pixel(2 * x + 1, 2 * y + 1)[c]) /
                            4;
        EXPECT_NEAR(out.Pixel(x, y)[c], mean, 1e-6);
      }
    }
  }
}

TEST(AreaResampleTest, FractionalRatiosMatchTheSupersampledFootprint) {
  const RenderImage in = RandomImage(37, 23, 2);
  for (auto [w, h] : {std::pair{20, 13}, std::pair{36, 22}, std::pair{1, 1}, std::pair{37, 5}}) {
    const RenderImage out = AreaResample(in, w, h);
    // 240 x 240 sample points per output pixel keep the reference error below 1e-2.
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const auto ref = Reference(in, w, h, x, y, 240);
        for (int c = 0; c < 4; ++c) EXPECT_NEAR(out.Pixel(x, y)[c], ref[c], 1e-2) << w << "x" << h;
      }
    }
  }
}

TEST(AreaResampleTest, TheSameSizeIsACopyAndConstantsStayConstant) {
  const RenderImage in = RandomImage(5, 4, 3);
  EXPECT_EQ(AreaResample(in, 5, 4).rgba, in.rgba);
  RenderImage flat{9, 7, std::vector<float>(9 * 7 * 4, 0.25f)};
  for (float v : AreaResample(flat, 4, 3).rgba) EXPECT_NEAR(v, 0.25f, 1e-6);
}

}  // namespace
}  // namespace octoscope::render
