#include "render/camera.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace octoscope::render {
namespace {

constexpr double kEps = 1e-12;

void ExpectVecNear(const Vec3& a, const Vec3& b, double eps = kEps) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

// Where point p lands on the image, in pixel units (continuous), by independent projection.
std::pair<double, double> Project(const Camera& c, const Vec3& p) {
  const Vec3 d = p - c.position();
  const double depth = Dot(d, c.forward());
  double x = Dot(d, c.right());
  double y = Dot(d, c.up());
  double pixel;
  if (c.projection() == Projection::kOrthographic) {
    pixel = c.ortho_height() / c.height();
  } else {
    const double tan_half = std::tan(c.fov_y_degrees() * std::numbers::pi / 360);
    x /= depth;
    y /= depth;
    pixel = 2 * tan_half / c.height();
  }
  return {c.width() / 2.0 + x / pixel, c.height() / 2.0 - y / pixel};
}

TEST(CameraTest, StandardZOrthoPutsPixelCentresOnVoxelColumns) {
  const Box3 box = PhysicalBounds({7, 5, 6}, {0.5, 0.5, 3});
  auto cam = Camera::Standard(StandardView::kZ, Projection::kOrthographic, box, 7, 5);
  ASSERT_TRUE(cam.ok()) << cam.status().ToString();
  for (int py = 0; py < 5; ++py) {
    for (int px = 0; px < 7; ++px) {
      const Ray r = cam->PixelRay(px, py);
      EXPECT_EQ(r.direction, (Vec3{0, 0, 1}));
      EXPECT_NEAR(r.origin.x, (px + 0.5) * 0.5, kEps);
      EXPECT_NEAR(r.origin.y, (py + 0.5) * 0.5, kEps);
      EXPECT_LT(r.origin.z, 0);  // In front of the box.
    }
  }
}

TEST(CameraTest, StandardViewsImageAxes) {
  const Box3 box = PhysicalBounds({4, 6, 8}, {1, 1, 1});
  struct Case {
    StandardView view;
    int w, h;
    Vec3 forward, right, down;
  };
  const Case cases[] = {
      {StandardView::kZ, 4, 6, {0, 0, 1}, {1, 0, 0}, {0, 1, 0}},
      {StandardView::kY, 4, 8, {0, -1, 0}, {1, 0, 0}, {0, 0, 1}},
      {StandardView::kX, 6, 8, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(std::string(StandardViewName(c.view)));
    auto cam = Camera::Standard(c.view, Projection::kOrthographic, box, c.w, c.h);
    ASSERT_TRUE(cam.ok());
    ExpectVecNear(cam->forward(), c.forward);
    ExpectVecNear(cam->right(), c.right);
    ExpectVecNear(cam->up(), -c.down);
    // The image is exactly the box's face: one pixel per voxel.
    EXPECT_NEAR(cam->ortho_height(), c.h, kEps);
    const Ray first = cam->PixelRay(0, 0);
    const Ray next_x = cam->PixelRay(1, 0);
    const Ray next_y = cam->PixelRay(0, 1);
    ExpectVecNear(next_x.origin - first.origin, c.right);
    ExpectVecNear(next_y.origin - first.origin, c.down);
  }
}

TEST(CameraTest, StandardViewsFitTheBox) {
  const Box3 box = PhysicalBounds({30, 20, 10}, {0.2, 0.2, 1.5});
  for (StandardView v :
       {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      SCOPED_TRACE(std::string(StandardViewName(v)) + " " + std::string(ProjectionName(p)));
      auto cam = Camera::Standard(v, p, box, 64, 48, 40);
      ASSERT_TRUE(cam.ok()) << cam.status().ToString();
      double min_x = 1e30, max_x = -1e30, min_y = 1e30, max_y = -1e30;
      for (int corner = 0; corner < 8; ++corner) {
        const Vec3 q{corner & 1 ? box.hi.x : box.lo.x, corner & 2 ? box.hi.y : box.lo.y,
                     corner & 4 ? box.hi.z : box.lo.z};
        EXPECT_GT(Dot(q - cam->position(), cam->forward()), 0);  // In front of the camera.
        auto [x, y] = Project(*cam, q);
        min_x = std::min(min_x, x);
        max_x = std::max(max_x, x);
        min_y = std::min(min_y, y);
        max_y = std::max(max_y, y);
      }
      EXPECT_GE(min_x, -1e-9);
      EXPECT_LE(max_x, 64 + 1e-9);
      EXPECT_GE(min_y, -1e-9);
      EXPECT_LE(max_y, 48 + 1e-9);
      if (p == Projection::kOrthographic) {
        // Tight: the projection touches two opposite image edges.
        EXPECT_TRUE(std::fabs(min_x) < 1e-9 || std::fabs(min_y) < 1e-9);
      }
      // The box centre is at the image centre.
      auto [cx, cy] = Project(*cam, box.Center());
      EXPECT_NEAR(cx, 32, 1e-9);
      EXPECT_NEAR(cy, 24, 1e-9);
    }
  }
}

TEST(CameraTest, PerspectiveRaysSpanTheFieldOfView) {
  auto cam =
      Camera::LookAt(Projection::kPerspective, {1, 2, 3}, {1, 2, 13}, {0, -1, 0}, 40, 20, 60, 1);
  ASSERT_TRUE(cam.ok());
  // The image centre looks straight ahead; the top edge centre is fov/2 off-axis.
  const Ray centre = cam->ImageRay(20, 10);
  ExpectVecNear(centre.origin, {1, 2, 3});
  ExpectVecNear(centre.direction, {0, 0, 1});
  const Ray top = cam->ImageRay(20, 0);
  EXPECT_NEAR(std::acos(Dot(top.direction, cam->forward())), std::numbers::pi / 6, 1e-12);
  EXPECT_LT(top.direction.y, 0);  // Up is -y.
  // Square pixels: the right edge centre is atan(2 tan 30°) off-axis.
  const Ray right = cam->ImageRay(40, 10);
  EXPECT_NEAR(std::acos(Dot(right.direction, cam->forward())),
              std::atan(2 * std::tan(std::numbers::pi / 6)), 1e-12);
  EXPECT_GT(right.direction.x, 0);
  for (int py = 0; py < 20; ++py) {
    for (int px = 0; px < 40; ++px) {
      EXPECT_NEAR(Length(cam->PixelRay(px, py).direction), 1, 1e-14);
    }
  }
}

TEST(CameraTest, ViewMatrixRoundTrip) {
  for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
    auto cam = Camera::LookAt(p, {5, -3, 2}, {1, 1, 1}, {0, 0, 1}, 32, 24, 45, 10);
    ASSERT_TRUE(cam.ok());
    const Mat4 view = cam->ViewMatrix();
    // The eye maps to the origin, the target onto the -Z axis.
    ExpectVecNear(view.TransformPoint(cam->position()), {0, 0, 0});
    const Vec3 target = view.TransformPoint({1, 1, 1});
    EXPECT_NEAR(target.x, 0, kEps);
    EXPECT_NEAR(target.y, 0, kEps);
    EXPECT_NEAR(target.z, -Length(Vec3{4, -4, 1}), kEps);
    auto back = Camera::FromViewMatrix(p, view, 32, 24, 45, 10);
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ExpectVecNear(back->position(), cam->position());
    ExpectVecNear(back->forward(), cam->forward());
    ExpectVecNear(back->up(), cam->up());
    for (int py : {0, 11, 23}) {
      for (int px : {0, 17, 31}) {
        ExpectVecNear(back->PixelRay(px, py).origin, cam->PixelRay(px, py).origin, 1e-12);
        ExpectVecNear(back->PixelRay(px, py).direction, cam->PixelRay(px, py).direction, 1e-12);
      }
    }
  }
}

TEST(CameraTest, RejectsBadInput) {
  const Vec3 o{0, 0, 0}, z{0, 0, 1}, y{0, 1, 0};
  const auto ortho = Projection::kOrthographic;
  EXPECT_FALSE(Camera::LookAt(ortho, o, z, z, 8, 8, 30, 1).ok());  // Up parallel.
  EXPECT_FALSE(Camera::LookAt(ortho, o, o, y, 8, 8, 30, 1).ok());  // No direction.
  EXPECT_FALSE(Camera::LookAt(ortho, o, z, y, 0, 8, 30, 1).ok());  // Empty image.
  EXPECT_FALSE(Camera::LookAt(ortho, o, z, y, 8, kMaxImageSize + 1, 30, 1).ok());
  EXPECT_FALSE(Camera::LookAt(ortho, o, z, y, 8, 8, 180, 1).ok());  // Field of view.
  EXPECT_FALSE(Camera::LookAt(ortho, o, z, y, 8, 8, 30, 0).ok());   // Ortho height.
  EXPECT_FALSE(Camera::LookAt(ortho, o, {NAN, 0, 1}, y, 8, 8, 30, 1).ok());
  EXPECT_FALSE(Camera::FromViewMatrix(ortho, Mat4::Scale({2, 1, 1}), 8, 8, 30, 1).ok());
  EXPECT_FALSE(Camera::FromViewMatrix(ortho, Mat4::Scale({1, 1, -1}), 8, 8, 30, 1).ok());
  EXPECT_FALSE(Camera::Standard(StandardView::kZ, ortho, Box3{{0, 0, 0}, {1, 0, 1}}, 8, 8).ok());
  EXPECT_TRUE(Camera::FromViewMatrix(ortho, Mat4::Identity(), 8, 8, 30, 1).ok());
}

TEST(CameraTest, Names) {
  for (StandardView v :
       {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
    EXPECT_EQ(StandardViewFromName(StandardViewName(v)), v);
  }
  for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
    EXPECT_EQ(ProjectionFromName(ProjectionName(p)), p);
  }
  EXPECT_FALSE(StandardViewFromName("w").has_value());
  EXPECT_FALSE(ProjectionFromName("fisheye").has_value());
}

TEST(CameraTest, PhysicalBoundsUseSpacingWithUnknownAsOne) {
  volume::VolumeInfo info;
  info.size = {10, 20, 30};
  info.spacing_um = {0.5, std::nullopt, 2.0};
  const Box3 b = PhysicalBounds(info);
  ExpectVecNear(b.lo, {0, 0, 0});
  ExpectVecNear(b.hi, {5, 20, 60});
}

}  // namespace
}  // namespace octoscope::render
