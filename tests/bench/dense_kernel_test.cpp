// The dense OpenCL baseline (bench/baseline/dense_kernel.h) against the independent
// double-precision reference renderer and against the octree renderer at level 0: the same images
// within the tolerance the renderer's level-0 images meet (2/255), for DVR, MIP and MinIP, 1 and 3
// channels, orthographic and perspective views, fractional steps, anisotropic spacing, LUTs,
// gamma, clipping planes and channel transforms; the same sample count as the reference; errors
// for invalid volumes and parameters.
#include "baseline/dense_kernel.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include "render/camera.h"
#include "render/cl_test_env.h"
#include "render/device.h"
#include "render/reference_renderer.h"
#include "render/render_fixture.h"
#include "render/render_params.h"
#include "render/volume_renderer_rig.h"

namespace octoscope::render {
namespace {

using ::octoscope::bench::DenseKernel;
using ::octoscope::bench::DenseKernelStats;
using testing::ClTestEnv;
using testing::CompareImages;
using testing::Describe;
using testing::kTol;
using testing::Rig;
using testing::SceneSpec;
using testing::SharedClTestEnv;

// A bright off-centre ball over a gradient and hashed noise, different per channel, with an
// empty corner (brickless leaves in the octree).
SceneSpec Spec(std::array<int64_t, 3> size, Vec3 spacing, int channels) {
  SceneSpec spec;
  spec.size = size;
  spec.spacing = spacing;
  spec.brick = {8, 8, 8};
  spec.channels = channels;
  spec.value = [size](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    if (x < size[0] / 4 && y < size[1] / 4) return 0;
    const double dx = x - size[0] * (0.4 + 0.1 * c), dy = y - size[1] * 0.55,
                 dz = z - size[2] * 0.5;
    const double r2 = (dx * dx + dy * dy + dz * dz) / (size[0] * size[0] * 0.06);
    return static_cast<uint16_t>(40000 * std::exp(-r2) + 150 * x + 100 * z +
                                 testing::Hash(x, y, z, c) % 3000);
  };
  return spec;
}

RenderParams Params(int channels, RenderMode mode, double step) {
  RenderParams params = DefaultRenderParams(channels, volume::DataType::kUint16, mode);
  params.step_voxels = step;
  static constexpr double kColours[3][3] = {{1, 0.2, 0.1}, {0.1, 0.8, 1}, {0.3, 1, 0.2}};
  for (int c = 0; c < channels; ++c) {
    ChannelParams& cp = params.channels[c];
    cp.color = {kColours[c][0], kColours[c][1], kColours[c][2]};
    cp.window = 30000 + 5000 * c;
    cp.level = 18000 + 2000 * c;
    cp.opacity_scale = 0.3 - 0.1 * c;
  }
  params.background = {0.1, 0.2, 0.3, 0.5};
  return params;
}

std::unique_ptr<DenseKernel> MakeDense(const Rig& rig) {
  std::vector<std::span<const uint16_t>> channels;
  for (const std::vector<uint16_t>& ch : rig.scene->voxels) channels.emplace_back(ch);
  const ClTestEnv& env = SharedClTestEnv();
  auto dense = DenseKernel::Create(env.context, env.programs, rig.scene->spec.size,
                                   rig.scene->spec.spacing, channels);
  EXPECT_TRUE(dense.ok()) << dense.status().ToString();
  if (!dense.ok()) return nullptr;
  return std::make_unique<DenseKernel>(std::move(*dense));
}

RenderImage Dense(DenseKernel& dense, const Camera& camera, const RenderParams& params,
                  DenseKernelStats* stats = nullptr) {
  auto image = dense.Render(camera, params, stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  return image.ok() ? *image : RenderImage{};
}

// The renderer refined at level 0 everywhere (what the benchmark compares against).
FrameOptions LevelZero() {
  FrameOptions options = testing::Refine();
  options.lod_bias = -32;
  return options;
}

TEST(DenseKernelTest, EveryModeViewAndChannelCountMatchesTheReferenceAndTheRenderer) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (int channels : {1, 3}) {
    auto rig = testing::MakeRig(Spec({28, 24, 20}, {0.5, 0.5, 1.25}, channels));
    ASSERT_NE(rig, nullptr);
    auto dense = MakeDense(*rig);
    ASSERT_NE(dense, nullptr);
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
      for (double step : {1.0, 0.7}) {
        const RenderParams params = Params(channels, mode, step);
        for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
          for (Projection projection : {Projection::kOrthographic, Projection::kPerspective}) {
            const Camera camera = testing::Standard(*rig, view, projection, 30, 26);
            const RenderImage image = Dense(*dense, camera, params);
            const RenderImage reference = testing::Reference(*rig, camera, params);
            const RenderImage octree = testing::Gpu(*rig, camera, params, LevelZero());
            const std::string where =
                std::to_string(channels) + " channels, " + std::string(RenderModeName(mode)) +
                " step " + std::to_string(step) + " " + std::string(StandardViewName(view)) + " " +
                std::string(ProjectionName(projection)) + ": ";
            EXPECT_TRUE(testing::AllFinite(image)) << where;
            EXPECT_LE(CompareImages(image, reference).max_abs, kTol)
                << where << Describe(CompareImages(image, reference));
            // Same arguments, rays and formulas as the renderer: only float rounding differs.
            EXPECT_LE(CompareImages(image, octree).max_abs, 1e-3)
                << where << Describe(CompareImages(image, octree));
          }
        }
      }
    }
  }
}

TEST(DenseKernelTest, ImagesAreNotTrivial) {
  // Guards the comparisons: the images hold structure, not just background.
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = testing::MakeRig(Spec({24, 24, 16}, {1, 1, 1}, 1));
  ASSERT_NE(rig, nullptr);
  auto dense = MakeDense(*rig);
  ASSERT_NE(dense, nullptr);
  const Camera camera =
      testing::Standard(*rig, StandardView::kZ, Projection::kOrthographic, 24, 24);
  const RenderImage image = Dense(*dense, camera, Params(1, RenderMode::kMip, 1));
  float lo = 1, hi = 0;
  for (size_t i = 0; i < image.rgba.size(); i += 4) {
    lo = std::min(lo, image.rgba[i]);
    hi = std::max(hi, image.rgba[i]);
  }
  EXPECT_GT(hi - lo, 0.3);
}

TEST(DenseKernelTest, LutGammaClipPlanesAndTransformsMatchTheReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = testing::MakeRig(Spec({24, 20, 16}, {1, 1, 2}, 3));
  ASSERT_NE(rig, nullptr);
  auto dense = MakeDense(*rig);
  ASSERT_NE(dense, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = Params(3, mode, 0.8);
    std::array<volume::Rgba, kLutEntries> lut;
    for (int i = 0; i < kLutEntries; ++i) {
      lut[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(255 - i),
                static_cast<uint8_t>((i * 7) % 256), static_cast<uint8_t>(i / 2)};
    }
    params.channels[0].lut = lut;
    params.channels[0].gamma = 0.6;
    params.channels[1].transform =
        Mat4::Translation({1.3, -0.7, 0.9}) * Mat4::Scale({1.02, 1, 0.98});
    params.channels[2].enabled = false;
    params.clip_planes = {{{1, 0.3, 0}, 18}, {{0, 0, -1}, -5}};
    for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
      const Camera camera = testing::Standard(*rig, view, Projection::kOrthographic, 28, 28);
      const RenderImage image = Dense(*dense, camera, params);
      const RenderImage reference = testing::Reference(*rig, camera, params);
      EXPECT_LE(CompareImages(image, reference).max_abs, kTol)
          << RenderModeName(mode) << " " << StandardViewName(view) << ": "
          << Describe(CompareImages(image, reference));
    }
  }
}

TEST(DenseKernelTest, CountsTheSameSamplesAsTheReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = testing::MakeRig(Spec({20, 20, 20}, {1, 1, 1}, 3));
  ASSERT_NE(rig, nullptr);
  auto dense = MakeDense(*rig);
  ASSERT_NE(dense, nullptr);
  const Camera camera =
      testing::Standard(*rig, StandardView::kIso, Projection::kOrthographic, 32, 32);
  RenderParams params = Params(3, RenderMode::kMip, 1);
  params.channels[1].enabled = false;
  DenseKernelStats stats;
  Dense(*dense, camera, params, &stats);
  RenderStats reference_stats;
  testing::Reference(*rig, camera, params, &reference_stats);
  EXPECT_EQ(stats.rays, 32u * 32u);
  EXPECT_EQ(stats.samples, reference_stats.channel_samples[0] + reference_stats.channel_samples[2]);
  EXPECT_EQ(reference_stats.channel_samples[1], 0u);
  EXPECT_GT(stats.samples, 32u * 32u * 5 * 2);
  EXPECT_GE(stats.ms_kernel, 0);
  EXPECT_GE(stats.ms_total, stats.ms_kernel);
  EXPECT_EQ(dense->volume_bytes(), 20u * 20 * 20 * 3 * 2);
}

// Eight rays per work item (where the device has 8-lane vectors) or one: the same samples, early
// termination included, and the same pixels up to float rounding.
TEST(DenseKernelTest, PacketsOfRaysTakeTheSameSamplesAsSingleRays) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  if (render::RunLanes(SharedClTestEnv().context->device()) < 8) {
    GTEST_SKIP() << "this device casts one ray per work item (RunLanes < 8): nothing to compare";
  }
  for (const Vec3 spacing : {Vec3{1, 1, 1}, Vec3{0.5, 0.5, 1.25}}) {
    auto rig = testing::MakeRig(Spec({28, 24, 20}, spacing, 2));
    ASSERT_NE(rig, nullptr);
    auto dense = MakeDense(*rig);
    ASSERT_NE(dense, nullptr);
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
      RenderParams params = Params(2, mode, 0.7);
      for (ChannelParams& cp : params.channels) cp.opacity_scale = 1;  // Rays terminate.
      // 30 x 25: blocks of 4 x 2 pixels cut at the right and bottom edges.
      const Camera camera =
          testing::Standard(*rig, StandardView::kIso, Projection::kPerspective, 30, 25);
      DenseKernelStats packed_stats;
      DenseKernelStats single_stats;
      dense->set_packets(true);
      const RenderImage packed = Dense(*dense, camera, params, &packed_stats);
      dense->set_packets(false);
      const RenderImage single = Dense(*dense, camera, params, &single_stats);
      EXPECT_EQ(packed_stats.samples, single_stats.samples) << RenderModeName(mode);
      EXPECT_EQ(packed_stats.rays, 30u * 25u);
      // The two forms really ran (the stats say which, and bench render reports it).
      EXPECT_TRUE(packed_stats.packets);
      EXPECT_FALSE(single_stats.packets);
      EXPECT_LE(CompareImages(packed, single).max_abs, 1e-5) << RenderModeName(mode);
      if (mode == RenderMode::kDvr) {
        // Early termination happened: fewer samples than MIP's full rays.
        DenseKernelStats mip_stats;
        Dense(*dense, camera, Params(2, RenderMode::kMip, 0.7), &mip_stats);
        EXPECT_LT(packed_stats.samples, mip_stats.samples);
      }
    }
  }
}

TEST(DenseKernelTest, RejectsInvalidVolumesAndParams) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ClTestEnv& env = SharedClTestEnv();
  const std::vector<uint16_t> eight(8, 5);
  const std::vector<std::span<const uint16_t>> one{eight};
  EXPECT_FALSE(DenseKernel::Create(env.context, env.programs, {0, 2, 2}, {1, 1, 1}, one).ok());
  EXPECT_FALSE(DenseKernel::Create(env.context, env.programs, {2, 2, 1}, {1, 1, 1}, one).ok());
  EXPECT_FALSE(DenseKernel::Create(env.context, env.programs, {2, 2, 2}, {1, 1, 1}, {}).ok());
  // A plane too large for the kernel's 32-bit offsets: refused before any allocation.
  EXPECT_FALSE(
      DenseKernel::Create(env.context, env.programs, {1 << 17, 1 << 16, 1}, {1, 1, 1}, one).ok());
  auto dense = DenseKernel::Create(env.context, env.programs, {2, 2, 2}, {1, 1, 1}, one);
  ASSERT_TRUE(dense.ok()) << dense.status().ToString();
  const Camera camera = *Camera::Standard(StandardView::kZ, Projection::kOrthographic,
                                          PhysicalBounds({2, 2, 2}, {1, 1, 1}), 4, 4);
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kMip);
  EXPECT_FALSE(dense->Render(camera, params).ok());  // Two channel params for one channel.
  params.channels.pop_back();
  params.step_voxels = 0;
  EXPECT_FALSE(dense->Render(camera, params).ok());
  params.step_voxels = 1;
  EXPECT_TRUE(dense->Render(camera, params).ok());
}

}  // namespace
}  // namespace octoscope::render
