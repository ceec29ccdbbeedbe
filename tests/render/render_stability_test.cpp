// Numerical stability of the ray caster (kernels/raycast.cl) in the cases where float arithmetic,
// box clipping and brick boundaries are most fragile: rays exactly along axes, volume faces and
// brick faces; grazing rays; a camera inside the volume; degenerate volumes (1x1xN, NxNx1,
// 1x1x1); the type's extreme values; a constant volume pruned to one node; positions near the
// 65536-voxel end of an axis; step-size independence of DVR; determinism. Every image is checked
// for NaN/Inf and compared with the CPU reference renderer or a direct computation from voxels.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "cl_test_env.h"
#include "render/camera.h"
#include "render/volume_renderer.h"
#include "render_fixture.h"
#include "volume_renderer_rig.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::AllFinite;
using ::octoscope::render::testing::CompareImages;
using ::octoscope::render::testing::Describe;
using ::octoscope::render::testing::Gpu;
using ::octoscope::render::testing::Hash;
using ::octoscope::render::testing::ImageDiff;
using ::octoscope::render::testing::kTol;
using ::octoscope::render::testing::MakeRig;
using ::octoscope::render::testing::Reference;
using ::octoscope::render::testing::Refine;
using ::octoscope::render::testing::Rig;
using ::octoscope::render::testing::SceneSpec;
using ::octoscope::render::testing::Standard;

SceneSpec Noise(std::array<int64_t, 3> size, octree::Vec3 brick = {8, 8, 8}) {
  SceneSpec spec;
  spec.size = size;
  spec.brick = brick;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(10000 + Hash(x, y, z, c) % 50000);
  };
  return spec;
}

RenderParams Params(RenderMode mode, volume::DataType type = volume::DataType::kUint16) {
  RenderParams params = DefaultRenderParams(1, type, mode);
  params.channels[0].opacity_scale = 0.1;
  return params;
}

// Renders with refinement and checks finiteness and agreement with the reference.
void ExpectMatchesReference(Rig& rig, const Camera& camera, const RenderParams& params,
                            const std::string& what, double tolerance = kTol) {
  FrameStats stats;
  const RenderImage gpu = Gpu(rig, camera, params, Refine(), &stats);
  EXPECT_TRUE(stats.final) << what;
  EXPECT_TRUE(AllFinite(gpu)) << what;
  const ImageDiff d = CompareImages(gpu, Reference(rig, camera, params));
  EXPECT_LE(d.max_abs, tolerance) << what << ": " << Describe(d);
}

Camera Ortho(const Vec3& position, const Vec3& target, const Vec3& up, int w, int h,
             double height) {
  Result<Camera> c =
      Camera::LookAt(Projection::kOrthographic, position, target, up, w, h, 30, height);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return *c;
}

TEST(RenderStabilityTest, RaysAlongAxesVolumeFacesAndBrickFaces) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(Noise({24, 24, 20}));
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    // Pixel centres on voxel centres (standard views at the voxel counts).
    ExpectMatchesReference(*rig,
                           Standard(*rig, StandardView::kZ, Projection::kOrthographic, 24, 24),
                           Params(mode), "z centres");
    ExpectMatchesReference(*rig,
                           Standard(*rig, StandardView::kX, Projection::kOrthographic, 24, 20),
                           Params(mode), "x centres");
    // Pixel centres on integer coordinates: rays along the volume's faces (0 and 24), its edges,
    // and the brick faces (8, 16), looking along z, x and y.
    ExpectMatchesReference(*rig, Ortho({12, 12, -30}, {12, 12, 10}, {0, -1, 0}, 25, 25, 25),
                           Params(mode), "z faces");
    ExpectMatchesReference(*rig, Ortho({-30, 12, 10}, {12, 12, 10}, {0, 0, -1}, 25, 21, 21),
                           Params(mode), "x faces");
    ExpectMatchesReference(*rig, Ortho({12, 60, 10}, {12, 12, 10}, {0, 0, -1}, 25, 21, 21),
                           Params(mode), "-y faces");
  }
}

TEST(RenderStabilityTest, GrazingRays) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(Noise({24, 20, 16}));
  ASSERT_NE(rig, nullptr);
  // Nearly parallel to the z = 0 and y = 0 faces, entering through the thin edge regions.
  const std::vector<Vec3> directions = {
      {1, 1e-3, 0}, {1, 0, 1e-4}, {1, 1e-5, 1e-5}, {0.3, 1, 2e-3}};
  for (const Vec3& d : directions) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
      const Vec3 target{12, 10, 8};
      const Camera camera = Ortho(target - Normalize(d) * 60, target, {0, 0, -1}, 32, 32, 24);
      ExpectMatchesReference(*rig, camera, Params(mode), "grazing " + std::to_string(d.y));
    }
  }
}

TEST(RenderStabilityTest, PerspectiveCameraInsideTheVolume) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(Noise({32, 32, 32}));
  ASSERT_NE(rig, nullptr);
  const Vec3 eye{15.3, 16.7, 14.1};
  const std::vector<Vec3> targets = {{40, 16.7, 14.1}, {15.3, -5, 14.1}, {0, 0, 0}, {30, 31, 2}};
  for (const Vec3& target : targets) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
      Result<Camera> camera =
          Camera::LookAt(Projection::kPerspective, eye, target, {0, 0, 1}, 40, 40, 60, 1);
      ASSERT_TRUE(camera.ok());
      ExpectMatchesReference(*rig, *camera, Params(mode), "inside");
    }
  }
}

TEST(RenderStabilityTest, DegenerateVolumes) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (const std::array<int64_t, 3>& size :
       std::vector<std::array<int64_t, 3>>{{1, 1, 37}, {20, 20, 1}, {1, 1, 1}, {1, 19, 1}}) {
    auto rig = MakeRig(Noise(size));
    ASSERT_NE(rig, nullptr);
    for (StandardView view :
         {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
      for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
        for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
          ExpectMatchesReference(*rig, Standard(*rig, view, p, 48, 48), Params(mode),
                                 std::to_string(size[0]) + "x" + std::to_string(size[1]) + "x" +
                                     std::to_string(size[2]) + " " +
                                     std::string(StandardViewName(view)) + " " +
                                     std::string(ProjectionName(p)));
        }
      }
    }
  }
}

TEST(RenderStabilityTest, SingleBrightVoxelVisibleFromEveryDirection) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {33, 30, 31};
  // Two voxels away from every brick face: the pruned empty neighbours never touch its support.
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return x == 19 && y == 11 && z == 21 ? 65535 : 0;
  };
  spec.brick = {8, 8, 8};
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const RenderParams params = Params(RenderMode::kMip);
  const Vec3 voxel{19.5, 11.5, 21.5};
  std::vector<Camera> cameras;
  for (StandardView view :
       {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
    cameras.push_back(Standard(*rig, view, Projection::kOrthographic, 40, 40));
    cameras.push_back(Standard(*rig, view, Projection::kPerspective, 64, 64));
  }
  for (const Vec3& from : std::vector<Vec3>{{-40, 5, 3}, {60, 70, -20}, {16, -50, 80}}) {
    Result<Camera> c =
        Camera::LookAt(Projection::kPerspective, from, voxel, {0, 0, 1}, 64, 64, 25, 1);
    ASSERT_TRUE(c.ok());
    cameras.push_back(*c);
  }
  for (size_t i = 0; i < cameras.size(); ++i) {
    const RenderImage gpu = Gpu(*rig, cameras[i], params, Refine());
    const RenderImage ref = Reference(*rig, cameras[i], params);
    ASSERT_TRUE(AllFinite(gpu));
    const ImageDiff d = CompareImages(gpu, ref);
    EXPECT_LE(d.max_abs, kTol) << "camera " << i << ": " << Describe(d);
    // Full detail: some sample lies within about half a voxel of the centre on every axis, where
    // the trilinear weight is far from 0 (a level-1 sample would dilute it 8-fold or more).
    float brightest = 0;
    for (size_t k = 0; k < gpu.rgba.size(); k += 4) brightest = std::max(brightest, gpu.rgba[k]);
    EXPECT_GT(brightest, 0.1f) << "camera " << i;
  }
}

TEST(RenderStabilityTest, ExtremeValuesUint8AndUint16) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (volume::DataType type : {volume::DataType::kUint8, volume::DataType::kUint16}) {
    const uint16_t max = static_cast<uint16_t>(volume::TypeMax(type));
    SceneSpec spec;
    spec.size = {24, 20, 18};
    spec.stored_type = type;
    // Blocks of 0 and the maximum, plus single extreme voxels.
    spec.value = [max](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
      if (((x / 5) + (y / 3) + (z / 4)) % 2 == 0) return max;
      return Hash(x, y, z, 0) % 7 == 0 ? max : 0;
    };
    auto rig = MakeRig(spec);
    ASSERT_NE(rig, nullptr);
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
      for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
        ExpectMatchesReference(*rig, Standard(*rig, view, Projection::kOrthographic, 32, 32),
                               Params(mode, type), std::string(volume::NumpyName(type)));
      }
    }
    // Along z through voxel centres every column holds both extremes: MIP 1, MinIP 0, exactly.
    const Camera z = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 24, 20);
    const RenderImage mip = Gpu(*rig, z, Params(RenderMode::kMip, type), Refine());
    const RenderImage minip = Gpu(*rig, z, Params(RenderMode::kMinIp, type), Refine());
    for (size_t k = 0; k < mip.rgba.size(); ++k) {
      ASSERT_NEAR(mip.rgba[k], 1.0f, 1e-6);
      ASSERT_NEAR(minip.rgba[k], k % 4 == 3 ? 1.0f : 0.0f, 1e-6);
    }
  }
}

TEST(RenderStabilityTest, ConstantVolumePrunedToOneNode) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {40, 36, 30};
  spec.value = [](int, int64_t, int64_t, int64_t) -> uint16_t { return 21000; };
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const auto root = rig->scene->tree->GetNode(0u);
  ASSERT_TRUE(root.has_value());
  EXPECT_FALSE(root->has_children());
  EXPECT_FALSE(root->has_brick());
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      FrameStats stats;
      const Camera camera = Standard(*rig, StandardView::kIso, p, 32, 32);
      const RenderImage gpu = Gpu(*rig, camera, Params(mode), Refine(), &stats);
      EXPECT_EQ(stats.passes, 1);  // Nothing to wait for.
      EXPECT_EQ(stats.bricks_uploaded, 0u);
      const ImageDiff d = CompareImages(gpu, Reference(*rig, camera, Params(mode)));
      EXPECT_LE(d.max_abs, kTol) << Describe(d);
    }
  }
}

// 2x2x65536 voxels: float positions near z = 65536 keep 1/128-voxel resolution; sample positions
// computed from the index (never accumulated) must still hit the right voxels.
TEST(RenderStabilityTest, NoDriftAlongA65536VoxelAxis) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {2, 2, 65536};
  spec.brick = {2, 2, 1024};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(Hash(x, y, z, 0) & 0xffff);
  };
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  // Looking along +x at the far end of z, one pixel per voxel: the MIP of each (y, z) row.
  const double z0 = 65536 - 24;
  const Camera far_end = Ortho({-10, 1, z0 + 12}, {1, 1, z0 + 12}, {0, 0, -1}, 2, 24, 24);
  FrameStats stats;
  const RenderImage image = Gpu(*rig, far_end, Params(RenderMode::kMip), Refine(), &stats);
  ASSERT_EQ(image.height, 24);
  for (int py = 0; py < 24; ++py) {
    for (int px = 0; px < 2; ++px) {
      // Image x = camera right = +y here (forward +x, up -z); row 0 is the top = smallest z.
      const int64_t y = px;
      const int64_t z = static_cast<int64_t>(z0) + py;
      const uint16_t expected = std::max(spec.value(0, 0, y, z), spec.value(0, 1, y, z));
      ASSERT_NEAR(image.Pixel(px, py)[0], expected / 65535.0, 1e-5) << px << "," << py;
    }
  }
  ExpectMatchesReference(*rig, far_end, Params(RenderMode::kDvr), "far end dvr");
  // Along the whole axis: 65536 samples per ray, the column maximum.
  const Camera along = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 2, 2);
  const RenderImage column = Gpu(*rig, along, Params(RenderMode::kMip), Refine(), &stats);
  // Every position sampled or skipped (MIP skips nodes whose maximum the ray already reached).
  EXPECT_EQ(stats.samples + stats.samples_skipped, 4u * 65536);
  for (int py = 0; py < 2; ++py) {
    for (int px = 0; px < 2; ++px) {
      uint16_t expected = 0;
      for (int64_t z = 0; z < 65536; ++z) expected = std::max(expected, spec.value(0, px, py, z));
      EXPECT_NEAR(column.Pixel(px, py)[0], expected / 65535.0, 1e-5);
    }
  }
}

TEST(RenderStabilityTest, DvrNearlyIndependentOfStep) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {32, 32, 32};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(30000 + 25000 * std::sin(0.2 * x) * std::cos(0.15 * y + 0.1 * z));
  };
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kIso, Projection::kOrthographic, 40, 40);
  std::vector<RenderImage> images;
  for (double step : {1.0, 0.5, 0.25}) {
    RenderParams params = Params(RenderMode::kDvr);
    params.channels[0].opacity_scale = 0.05;
    params.step_voxels = step;
    images.push_back(Gpu(*rig, camera, params, Refine()));
    const ImageDiff d = CompareImages(images.back(), Reference(*rig, camera, params));
    EXPECT_LE(d.max_abs, kTol) << "step " << step << ": " << Describe(d);
  }
  // Opacity correction: halving the step changes a smooth volume's image only slightly.
  EXPECT_LT(CompareImages(images[0], images[1]).max_abs, 0.02);
  EXPECT_LT(CompareImages(images[1], images[2]).max_abs, 0.01);
}

TEST(RenderStabilityTest, RepeatedRunsAreBitIdentical) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(Noise({24, 24, 24}));
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    const Camera camera = Standard(*rig, StandardView::kIso, Projection::kPerspective, 48, 48);
    const RenderImage a = Gpu(*rig, camera, Params(mode), Refine());
    const RenderImage b = Gpu(*rig, camera, Params(mode), Refine());
    EXPECT_EQ(a.rgba, b.rgba);
    // Full frames once everything is resident: the same image again.
    const RenderImage c = Gpu(*rig, camera, Params(mode), FrameOptions{});
    EXPECT_EQ(a.rgba, c.rgba);
  }
}

}  // namespace
}  // namespace octoscope::render
