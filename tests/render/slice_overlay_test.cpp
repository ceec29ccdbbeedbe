// Slice-plane overlay (pure CPU) against independent computations: the projection is checked as
// the inverse of Camera::ImageRay, and drawn lines against coverages computed from image-space
// rectangles derived by hand for simple orthographic cameras.
#include "render/slice_overlay.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

namespace octoscope::render {
namespace {

RenderImage Blank(int w, int h) {
  RenderImage img;
  img.width = w;
  img.height = h;
  img.rgba.assign(static_cast<size_t>(w) * h * 4, 0.0f);
  return img;
}

double SegmentDistance(double px, double py, double ax, double ay, double bx, double by) {
  const double ex = bx - ax, ey = by - ay;
  const double len2 = ex * ex + ey * ey;
  const double t = len2 > 0 ? std::clamp(((px - ax) * ex + (py - ay) * ey) / len2, 0.0, 1.0) : 0;
  return std::hypot(px - ax - t * ex, py - ay - t * ey);
}

// Coverage of pixel (x, y) by the outline of the image-space rectangle [x0, x1] x [y0, y1].
double RectangleCoverage(int x, int y, double x0, double y0, double x1, double y1) {
  const double cx = x + 0.5, cy = y + 0.5;
  const double d =
      std::min({SegmentDistance(cx, cy, x0, y0, x1, y0), SegmentDistance(cx, cy, x1, y0, x1, y1),
                SegmentDistance(cx, cy, x1, y1, x0, y1), SegmentDistance(cx, cy, x0, y1, x0, y0)});
  return std::clamp(kOverlayLineWidthPx / 2 + 0.5 - d, 0.0, 1.0);
}

const Box3 kBox{{0, 0, 0}, {32, 24, 16}};

// Orthographic z view (looking +z, image x = +x, rows = +y), 1 µm per pixel, 64x64: world (x, y)
// lands at image (x + 16, y + 20).
Camera OrthoZ() {
  auto cam = Camera::LookAt(Projection::kOrthographic, {16, 12, -10}, {16, 12, 0}, {0, -1, 0}, 64,
                            64, 30, 64);
  EXPECT_TRUE(cam.ok());
  return *cam;
}

TEST(SliceOverlayTest, ProjectionInvertsImageRay) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  for (Projection projection : {Projection::kOrthographic, Projection::kPerspective}) {
    auto cam = Camera::LookAt(projection, {40, -20, 30}, {16, 12, 8}, {0, 0, 1}, 96, 64, 40, 50);
    ASSERT_TRUE(cam.ok());
    for (int i = 0; i < 200; ++i) {
      const double x = u(rng) * 96, y = u(rng) * 64;
      const Ray ray = cam->ImageRay(x, y);
      const auto p = ProjectToImage(*cam, ray.At(1 + 100 * u(rng)));
      ASSERT_TRUE(p.has_value());
      EXPECT_NEAR((*p)[0], x, 1e-8);
      EXPECT_NEAR((*p)[1], y, 1e-8);
    }
    // Behind the camera: not projected.
    EXPECT_FALSE(ProjectToImage(*cam, cam->position() - cam->forward() * 5).has_value());
  }
}

TEST(SliceOverlayTest, CornersOfEachAxis) {
  auto z = SlicePlaneCorners(kBox, {2, 5, {1, 0, 0}});
  ASSERT_TRUE(z.has_value());
  for (const Vec3& c : *z) {
    EXPECT_EQ(c.z, 5);
    EXPECT_TRUE(c.x == 0 || c.x == 32);
    EXPECT_TRUE(c.y == 0 || c.y == 24);
  }
  auto x = SlicePlaneCorners(kBox, {0, 32, {1, 0, 0}});  // On the face: still cuts.
  ASSERT_TRUE(x.has_value());
  for (const Vec3& c : *x) EXPECT_EQ(c.x, 32);
  EXPECT_FALSE(SlicePlaneCorners(kBox, {1, 24.5, {1, 0, 0}}).has_value());
  EXPECT_FALSE(SlicePlaneCorners(kBox, {1, -0.1, {1, 0, 0}}).has_value());
}

// A z plane under an orthographic z view is the box's cross-section outline: every pixel's
// coverage matches the hand-projected rectangle, pixels away from it stay untouched.
TEST(SliceOverlayTest, ZPlaneUnderOrthoZViewIsTheOutline) {
  const Camera cam = OrthoZ();
  RenderImage img = Blank(64, 64);
  const SlicePlane plane{2, 7.5, {1, 0.5, 0}};
  ASSERT_TRUE(DrawSlicePlanes(&img, cam, kBox, {&plane, 1}).ok());
  int touched = 0;
  for (int y = 0; y < 64; ++y) {
    for (int x = 0; x < 64; ++x) {
      const auto p = img.Pixel(x, y);
      const double c = RectangleCoverage(x, y, 16, 20, 48, 44);
      EXPECT_NEAR(p[3], c, 1e-6) << x << "," << y;
      EXPECT_NEAR(p[0], c * 1.0, 1e-6);
      EXPECT_NEAR(p[1], c * 0.5, 1e-6);
      EXPECT_EQ(p[2], 0.0f);
      if (p[3] > 0) ++touched;
    }
  }
  // The outline's rows 19, 20 and 43, 44 and columns 15, 16 and 47, 48 (1.5 px lines centred on
  // pixel edges cover two pixels at 0.75).
  EXPECT_NEAR(img.Pixel(30, 19)[3], 0.75, 1e-6);
  EXPECT_NEAR(img.Pixel(30, 20)[3], 0.75, 1e-6);
  EXPECT_EQ(img.Pixel(30, 18)[3], 0.0f);
  EXPECT_EQ(img.Pixel(30, 30)[3], 0.0f);  // Inside the rectangle: untouched.
  EXPECT_NEAR(img.Pixel(15, 30)[3], 0.75, 1e-6);
  EXPECT_NEAR(img.Pixel(48, 30)[3], 0.75, 1e-6);
  EXPECT_GT(touched, 4 * 50);
  EXPECT_LT(touched, 4 * 80);
}

// An x plane seen edge-on under the z view is a vertical line at its projected x; composited
// over existing pixels.
TEST(SliceOverlayTest, EdgeOnPlaneIsALineCompositedOver) {
  const Camera cam = OrthoZ();
  RenderImage img = Blank(64, 64);
  for (size_t i = 0; i < img.rgba.size(); i += 4) {
    img.rgba[i] = 0.2f;  // Premultiplied grey at alpha 0.5.
    img.rgba[i + 3] = 0.5f;
  }
  const SlicePlane plane{0, 10.5, {0, 1, 0}};  // Image x = 26.5: column 26 centred, full cover.
  ASSERT_TRUE(DrawSlicePlanes(&img, cam, kBox, {&plane, 1}).ok());
  for (int y = 0; y < 64; ++y) {
    const double c = RectangleCoverage(26, y, 26.5, 20, 26.5, 44);
    const auto p = img.Pixel(26, y);
    EXPECT_NEAR(p[1], c, 1e-6);
    EXPECT_NEAR(p[0], 0.2 * (1 - c), 1e-6);
    EXPECT_NEAR(p[3], c + 0.5 * (1 - c), 1e-6);
    EXPECT_EQ(img.Pixel(24, y)[3], 0.5f);  // 2 px away: untouched.
    EXPECT_EQ(img.Pixel(28, y)[3], 0.5f);
  }
  EXPECT_NEAR(img.Pixel(26, 30)[1], 1.0, 1e-6);
  EXPECT_NEAR(img.Pixel(25, 30)[1], 0.25, 1e-6);  // Centre 1 px away: 1.25 - 1.
  EXPECT_EQ(img.Pixel(26, 10)[3], 0.5f);          // Beyond the box's y extent.
}

TEST(SliceOverlayTest, PlaneBehindPerspectiveCameraDrawsNothing) {
  // Looking away from the volume (along -z from z = -10).
  auto away = Camera::LookAt(Projection::kPerspective, {16, 12, -10}, {16, 12, -20}, {0, -1, 0}, 48,
                             48, 60, 1);
  ASSERT_TRUE(away.ok());
  RenderImage img = Blank(48, 48);
  const std::vector<SlicePlane> planes = {
      {0, 16, {1, 1, 1}}, {1, 12, {1, 1, 1}}, {2, 8, {1, 1, 1}}};
  ASSERT_TRUE(DrawSlicePlanes(&img, *away, kBox, planes).ok());
  for (float v : img.rgba) EXPECT_EQ(v, 0.0f);

  // Inside the volume looking +z with a 120 degree field of view: the plane behind (z = 2) draws
  // nothing, the outline of the one 10 µm ahead (half extents 16 and 12 µm) is in view.
  auto inside = Camera::LookAt(Projection::kPerspective, {16, 12, 4}, {16, 12, 20}, {0, -1, 0}, 48,
                               48, 120, 1);
  ASSERT_TRUE(inside.ok());
  const SlicePlane behind{2, 2, {1, 1, 1}};
  ASSERT_TRUE(DrawSlicePlanes(&img, *inside, kBox, {&behind, 1}).ok());
  for (float v : img.rgba) EXPECT_EQ(v, 0.0f);
  const SlicePlane ahead{2, 14, {1, 1, 1}};
  ASSERT_TRUE(DrawSlicePlanes(&img, *inside, kBox, {&ahead, 1}).ok());
  float most = 0;
  for (float v : img.rgba) most = std::max(most, v);
  EXPECT_GT(most, 0.5f);
}

// Planes through the eye, far outside the image, and huge boxes: only pixels of the image are
// written, every value stays finite and in [0, 1].
TEST(SliceOverlayTest, ClipsToImageAndNearPlane) {
  auto inside =
      Camera::LookAt(Projection::kPerspective, {16, 12, 8}, {40, 30, 9}, {0, 0, 1}, 33, 17, 90, 1);
  ASSERT_TRUE(inside.ok());
  RenderImage img = Blank(33, 17);
  std::vector<SlicePlane> planes;
  for (int a = 0; a < 3; ++a) {
    for (double pos : {0.0, 8.0, 12.0, 16.0, 24.0, 32.0}) planes.push_back({a, pos, {1, 0, 1}});
  }
  const Box3 huge{{-1e6, -1e6, -1e6}, {1e6, 1e6, 1e6}};
  ASSERT_TRUE(DrawSlicePlanes(&img, *inside, kBox, planes).ok());
  ASSERT_TRUE(DrawSlicePlanes(&img, *inside, huge, planes).ok());
  // The camera's image size differs from the image's: refused.
  EXPECT_EQ(DrawSlicePlanes(&img, OrthoZ(), kBox, planes).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(img.rgba.size(), size_t{33} * 17 * 4);
  for (float v : img.rgba) {
    EXPECT_TRUE(std::isfinite(v));
    EXPECT_GE(v, 0.0f);
    EXPECT_LE(v, 1.0f);
  }
  const std::vector<float> before = img.rgba;
  const SlicePlane bad{3, 1, {1, 1, 1}};
  EXPECT_EQ(DrawSlicePlanes(&img, *inside, kBox, {&bad, 1}).code(), StatusCode::kInvalidArgument);
  const SlicePlane dark{1, 1, {1.5, 0, 0}};
  EXPECT_EQ(DrawSlicePlanes(&img, *inside, kBox, {&dark, 1}).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(img.rgba, before);
}

}  // namespace
}  // namespace octoscope::render
