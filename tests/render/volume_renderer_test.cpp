// VolumeRenderer (kernels/raycast.cl) against independent oracles: the CPU reference renderer
// (double precision, full resolution, no octree) on the SAME voxels, and direct computations from
// the voxels (column maxima, brick means). The device is never its own oracle, except where the
// claim is "identical" (skipping on/off, roomy vs tiny brick buffer, full frame vs refinement).
//
// Tolerances: the GPU works in float. Positions agree with the reference to ~1e-5 voxels, the
// transfer functions to ~1e-6; DVR compositing of <= ~100 samples in float accumulates ~1e-5; and
// the early-termination threshold 0.999 may be crossed one sample apart, which moves a pixel by
// at most 0.001 of the remaining light. 2/255 per component therefore has a wide margin while
// still catching any wrong voxel, level, step or compositing rule (those give errors >= 0.05).
#include "render/volume_renderer.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cl_test_env.h"
#include "render/cell_ranges.h"
#include "render/device_octree.h"
#include "render/program_cache.h"
#include "render/reference_renderer.h"
#include "render/render_frame.h"
#include "render/render_params.h"
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
using ::octoscope::render::testing::kTestBuildOptions;
using ::octoscope::render::testing::kTol;
using ::octoscope::render::testing::MakeRig;
using ::octoscope::render::testing::Reference;
using ::octoscope::render::testing::Refine;
using ::octoscope::render::testing::Rig;
using ::octoscope::render::testing::SceneSpec;
using ::octoscope::render::testing::Standard;

// Noise with some structure: smooth gradients plus per-voxel noise.
SceneSpec NoiseSpec(std::array<int64_t, 3> size, int channels, octree::Vec3 brick = {16, 16, 16}) {
  SceneSpec spec;
  spec.size = size;
  spec.channels = channels;
  spec.brick = brick;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    const double smooth = 0.5 + 0.5 * std::sin(0.3 * x + 0.2 * y * (c + 1) + 0.25 * z);
    return static_cast<uint16_t>(40000 * smooth + (Hash(x, y, z, c) % 25000));
  };
  return spec;
}

TEST(VolumeRendererTest, ContractMipEqualsColumnMaxAlongZ) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {40, 24, 20};
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(Hash(x, y, z, c) & 0xffff);
  };
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 40, 24);
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  FrameStats stats;
  const RenderImage image = Gpu(*rig, camera, params, Refine(), &stats);
  ASSERT_EQ(image.width, 40);
  EXPECT_TRUE(stats.final);
  for (int y = 0; y < 24; ++y) {
    for (int x = 0; x < 40; ++x) {
      uint16_t max = 0;
      for (int z = 0; z < 20; ++z) max = std::max(max, spec.value(0, x, y, z));
      const auto px = image.Pixel(x, y);
      for (int k = 0; k < 3; ++k) ASSERT_NEAR(px[k], max / 65535.0, 1.0 / 255) << x << "," << y;
      ASSERT_EQ(px[3], 1.0f);
    }
  }
  // Every sample position is either sampled or skipped (MIP skips nodes whose maximum the ray
  // already reached).
  EXPECT_EQ(stats.samples + stats.samples_skipped, 40u * 24 * 20);
}

struct ViewCase {
  RenderMode mode;
  Projection projection;
  StandardView view;
};

class ViewsTest : public ::testing::TestWithParam<ViewCase> {};

TEST_P(ViewsTest, RefinementMatchesReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ViewCase& c = GetParam();
  auto rig = MakeRig(NoiseSpec({32, 24, 28}, 1));
  ASSERT_NE(rig, nullptr);
  // Perspective views need more pixels to keep the far side's footprint below 2 voxels.
  const int size = c.projection == Projection::kOrthographic ? 32 : 56;
  const Camera camera = Standard(*rig, c.view, c.projection, size, size);
  RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, c.mode);
  params.channels[0].opacity_scale = 0.08;
  params.background = {0.2, 0.3, 0.4, 1};
  FrameStats stats;
  const RenderImage gpu = Gpu(*rig, camera, params, Refine(), &stats);
  const RenderImage ref = Reference(*rig, camera, params);
  EXPECT_TRUE(stats.final);
  EXPECT_TRUE(AllFinite(gpu));
  const ImageDiff d = CompareImages(gpu, ref);
  EXPECT_LE(d.max_abs, kTol) << Describe(d);
}

std::vector<ViewCase> AllViews() {
  std::vector<ViewCase> cases;
  for (RenderMode m : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      for (StandardView v :
           {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
        cases.push_back({m, p, v});
      }
    }
  }
  return cases;
}

INSTANTIATE_TEST_SUITE_P(All, ViewsTest, ::testing::ValuesIn(AllViews()),
                         [](const ::testing::TestParamInfo<ViewCase>& info) {
                           return std::string(RenderModeName(info.param.mode)) + "_" +
                                  std::string(ProjectionName(info.param.projection)) + "_" +
                                  std::string(StandardViewName(info.param.view));
                         });

RenderParams ColourParams(RenderMode mode) {
  RenderParams params = DefaultRenderParams(3, volume::DataType::kUint16, mode);
  params.channels[0].color = {1, 0.2, 0.1};
  params.channels[0].gamma = 1.7;
  params.channels[0].window = 30000;
  params.channels[0].level = 40000;
  params.channels[0].opacity_scale = 0.1;
  params.channels[1].color = {0.1, 1, 0.3};
  params.channels[1].gamma = 0.6;
  params.channels[1].opacity_scale = 0.05;
  std::array<volume::Rgba, kLutEntries> lut;
  for (int i = 0; i < kLutEntries; ++i) {
    lut[i] = {static_cast<uint8_t>(255 - i), static_cast<uint8_t>((i * 7) % 256),
              static_cast<uint8_t>(i), static_cast<uint8_t>(i / 3)};
  }
  params.channels[2].lut = lut;
  params.channels[2].opacity_scale = 0.3;
  return params;
}

TEST(VolumeRendererTest, MultiChannelColoursLutGamma) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({24, 20, 16}, 3));
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      const Camera camera = Standard(*rig, StandardView::kIso, p, 40, 40);
      const RenderParams params = ColourParams(mode);
      const RenderImage gpu = Gpu(*rig, camera, params, Refine());
      const ImageDiff d = CompareImages(gpu, Reference(*rig, camera, params));
      EXPECT_LE(d.max_abs, kTol) << RenderModeName(mode) << " " << ProjectionName(p) << ": "
                                 << Describe(d);
    }
  }
}

TEST(VolumeRendererTest, ClipPlanes) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({24, 24, 24}, 1));
  ASSERT_NE(rig, nullptr);
  const std::vector<ClipPlane> planes = {
      {{1, 0, 0}, 15.3}, {{-0.3, 1, 0.2}, 12}, {{0, -1, -1}, -10}};
  for (size_t count = 1; count <= 3; ++count) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
      RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, mode);
      params.channels[0].opacity_scale = 0.1;
      params.clip_planes.assign(planes.begin(), planes.begin() + static_cast<long>(count));
      for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
        const Camera camera = Standard(*rig, view, Projection::kOrthographic, 32, 32);
        const RenderImage gpu = Gpu(*rig, camera, params, Refine());
        const RenderImage ref = Reference(*rig, camera, params);
        const ImageDiff d = CompareImages(gpu, ref);
        EXPECT_LE(d.max_abs, kTol) << count << " planes, " << RenderModeName(mode) << ", "
                                   << StandardViewName(view) << ": " << Describe(d);
      }
    }
  }
}

TEST(VolumeRendererTest, PerChannelTransformAndAnisotropicSpacing) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec({24, 20, 16}, 2);
  spec.spacing = {0.5, 0.5, 1.5};
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    params.channels[0].opacity_scale = 0.1;
    params.channels[1].color = {0, 1, 0};
    params.channels[1].opacity_scale = 0.1;
    // Translation plus a slight scale: part of the channel's positions leave the box.
    params.channels[1].transform =
        Mat4::Translation({0.8, -0.6, 1.1}) * Mat4::Scale({1.03, 0.97, 1});
    for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
      const Camera camera = Standard(*rig, view, Projection::kOrthographic, 40, 40);
      const ImageDiff d =
          CompareImages(Gpu(*rig, camera, params, Refine()), Reference(*rig, camera, params));
      EXPECT_LE(d.max_abs, kTol) << RenderModeName(mode) << " " << StandardViewName(view) << ": "
                                 << Describe(d);
    }
  }
}

TEST(VolumeRendererTest, DisabledChannelCostsNoSamples) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({24, 20, 16}, 3));
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kIso, Projection::kOrthographic, 32, 32);
  RenderParams all = ColourParams(RenderMode::kMip);
  FrameStats all_stats;
  Gpu(*rig, camera, all, Refine(), &all_stats);
  RenderParams two = all;
  two.channels[1].enabled = false;
  FrameStats two_stats;
  const RenderImage gpu = Gpu(*rig, camera, two, Refine(), &two_stats);
  RenderStats ref_stats;
  const RenderImage ref = Reference(*rig, camera, two, &ref_stats);
  // MIP walks every segment: the samples are exactly the enabled channels' share.
  EXPECT_EQ(two_stats.samples * 3, all_stats.samples * 2);
  EXPECT_EQ(two_stats.samples, ref_stats.channel_samples[0] + ref_stats.channel_samples[2]);
  EXPECT_EQ(ref_stats.channel_samples[1], 0u);
  const ImageDiff d = CompareImages(gpu, ref);
  EXPECT_LE(d.max_abs, kTol) << Describe(d);
}

TEST(VolumeRendererTest, FullFrameConvergesToRefinement) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({32, 32, 32}, 1, {8, 8, 8}));
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kIso, Projection::kPerspective, 48, 48);
  RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.1;
  FrameOptions full;
  full.upload.max_bricks = 8;  // Several frames until everything is resident.
  FrameStats stats;
  Result<RenderImage> first = rig->renderer->RenderFullFrame(camera, params, full, &stats);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  EXPECT_TRUE(AllFinite(*first));
  EXPECT_FALSE(stats.final);
  EXPECT_GT(stats.requests, 0u);
  // The coarse first frame already resembles the reference (same overall opacity).
  const RenderImage ref = Reference(*rig, camera, params);
  EXPECT_LT(CompareImages(*first, ref).max_abs, 0.5);
  RenderImage last = *first;
  int frames = 1;
  while (!stats.final && frames < 200) {
    Result<RenderImage> next = rig->renderer->RenderFullFrame(camera, params, full, &stats);
    ASSERT_TRUE(next.ok()) << next.status().ToString();
    EXPECT_TRUE(AllFinite(*next));
    last = std::move(*next);
    ++frames;
  }
  EXPECT_TRUE(stats.final);
  EXPECT_GT(frames, 2);
  const RenderImage refined = Gpu(*rig, camera, params, Refine());
  EXPECT_LE(CompareImages(last, refined).max_abs, 1e-6);
  EXPECT_LE(CompareImages(last, ref).max_abs, kTol) << Describe(CompareImages(last, ref));
}

// Full frame with nothing resident on a deep tree: the root is more than two levels above the
// wanted leaves, so every sample uses its leaf's AVERAGE (fallback rule) — checked against block
// means computed from the voxels.
TEST(VolumeRendererTest, FullFrameFallbackUsesWantedAverages) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec({64, 64, 64}, 1, {8, 8, 8});
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  ASSERT_EQ(rig->device->geometry().root_level(), 3);
  const Camera camera = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 64, 64);
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  FrameOptions full;
  full.upload.max_bricks = 1;
  FrameStats stats;
  Result<RenderImage> image = rig->renderer->RenderFullFrame(camera, params, full, &stats);
  ASSERT_TRUE(image.ok()) << image.status().ToString();
  // Per 8x8 column of blocks: the maximum over z of the block means.
  for (int by = 0; by < 8; ++by) {
    for (int bx = 0; bx < 8; ++bx) {
      double best = 0;
      for (int bz = 0; bz < 8; ++bz) {
        double sum = 0;
        for (int z = 0; z < 8; ++z)
          for (int y = 0; y < 8; ++y)
            for (int x = 0; x < 8; ++x) sum += spec.value(0, bx * 8 + x, by * 8 + y, bz * 8 + z);
        best = std::max(best, sum / 512);
      }
      for (int y = 0; y < 8; ++y) {
        for (int x = 0; x < 8; ++x) {
          ASSERT_NEAR(image->Pixel(bx * 8 + x, by * 8 + y)[0], best / 65535, 1.0 / 65535 + 1e-6)
              << bx << "," << by;
        }
      }
    }
  }
  EXPECT_GE(stats.requests, 64u);
}

TEST(VolumeRendererTest, PreloadedCoarseLevelsMakeTheFirstFrameFinalAtTheirLevel) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    SCOPED_TRACE(RenderModeName(mode));
    auto rig = MakeRig(NoiseSpec({64, 64, 64}, 2, {8, 8, 8}));
    ASSERT_NE(rig, nullptr);
    ASSERT_EQ(rig->device->geometry().root_level(), 3);
    const Camera camera = Standard(*rig, StandardView::kIso, Projection::kPerspective, 64, 64);
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    // A fresh mirror: its first frame at the root level shows node averages and asks for bricks.
    auto fresh = MakeRig(NoiseSpec({64, 64, 64}, 2, {8, 8, 8}));
    ASSERT_NE(fresh, nullptr);
    FrameOptions coarse;
    coarse.lod_bias = 3;
    FrameStats stats;
    ASSERT_TRUE(fresh->renderer->RenderFullFrame(camera, params, coarse, &stats).ok());
    EXPECT_FALSE(stats.final);
    // With the two coarsest levels (1 + 8 bricks) preloaded it is final at once: the image the
    // refinement gives at that level.
    UploadStats upload;
    ASSERT_TRUE(
        rig->device->UploadCoarseLevels(9 * rig->device->device_brick_bytes(), &upload).ok());
    EXPECT_EQ(upload.uploaded, 9u);
    Result<RenderImage> first = rig->renderer->RenderFullFrame(camera, params, coarse, &stats);
    ASSERT_TRUE(first.ok()) << first.status().ToString();
    EXPECT_TRUE(stats.final);
    EXPECT_EQ(stats.requests, 0u);
    FrameOptions refine = Refine();
    refine.lod_bias = 3;
    const RenderImage refined = Gpu(*rig, camera, params, refine);
    EXPECT_LE(CompareImages(*first, refined).max_abs, 1e-6);
  }
}

// Full frames that fall back on a resident ancestor 1 or 2 levels up (the wanted level-0 bricks
// missing) march it in the same tight loop as resident bricks (kernels/raycast.cl, "Brick-local
// marching"). Scenes of 16^3 bricks with something bright in each (so no level-0 node is inert)
// in dim, transparent noise; an oblique orthographic view, one pixel per µm.
class FallbackTest : public ::testing::Test {
 protected:
  // A small blob at the centre of each 16^3 brick (levels 0..2: 64, 8, 1 bricks); with `dots`,
  // 8^3 bricks (levels 0..3) with one bright voxel each per channel: above level 0 it averages
  // below a window from 9000 (one level up: at most (65000 + 7 * 999) / 8) or from 2500 (two
  // up), so those levels' cells are inert — and, 8 voxels of an ancestor 1 or 2 levels up being
  // 16 or 32 level-0 voxels, they reach beyond the wanted 8^3 box.
  static SceneSpec Spec(bool dots = false) {
    SceneSpec spec;
    spec.size = {64, 64, 64};
    const int64_t b = dots ? 8 : 16;
    spec.brick = {b, b, b};
    spec.channels = 2;
    spec.value = [dots, b](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
      const int64_t dx = x % b - (dots ? 3 + c : 7 + c), dy = y % b - (dots ? 3 : 8),
                    dz = z % b - (dots ? 3 : 8);
      if (dx * dx + dy * dy + dz * dz < (dots ? 1 : 5)) {
        return static_cast<uint16_t>(40000 + Hash(x, y, z, c) % 25000);
      }
      return static_cast<uint16_t>(200 + Hash(x, y, z, c) % 800);
    };
    return spec;
  }
  // Oblique, or (grazing) nearly along x, so that rays run along the faces y = 0 and z = 0 within
  // the outer half voxel, where positions clamp.
  static Camera View(bool grazing = false) {
    const Vec3 centre{32, 32, 32};
    const Vec3 dir = Normalize(grazing ? Vec3{1, 0.004, 0.003} : Vec3{1, 0.7, 2});
    Result<Camera> camera = Camera::LookAt(Projection::kOrthographic, centre - dir * 200, centre,
                                           {0, -1, 0}, 64, 64, 30, 64);
    EXPECT_TRUE(camera.ok()) << camera.status().ToString();
    return *camera;
  }
  // The window starts at `lo`: 2000 makes the dim noise transparent (DVR); for the dots, above.
  static RenderParams Params(RenderMode mode, double lo = 2000) {
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    for (ChannelParams& ch : params.channels) {
      ch.window = 20000;
      ch.level = lo + 10000;
      ch.opacity_scale = 0.3;
    }
    return params;
  }
  // A fresh rig whose resident bricks are those of level `level` (and the root), plus every
  // other level-0 brick when `checkerboard`.
  static std::unique_ptr<Rig> Resident(int level, bool checkerboard, bool dots = false) {
    return Resident(Spec(dots), level, checkerboard);
  }
  static std::unique_ptr<Rig> Resident(const SceneSpec& spec, int level, bool checkerboard) {
    auto rig = MakeRig(spec);
    if (rig == nullptr) return nullptr;
    std::vector<uint32_t> ids;
    for (uint32_t id = 0; id < rig->device->node_capacity(); ++id) {
      const std::optional<octree::NodeSnapshot> n = rig->scene->tree->GetNode(id);
      if (!n || !n->has_brick()) continue;
      const auto& k = n->key;
      if (k.level == level ||
          (checkerboard && k.level == 0 && (k.index[0] + k.index[1] + k.index[2]) % 2 == 0)) {
        ids.push_back(id);
      }
    }
    EXPECT_FALSE(ids.empty());
    EXPECT_TRUE(rig->device->UploadAll(ids, 0).ok());
    return rig;
  }
  static RenderImage Frame(Rig& rig, const RenderParams& params, const FrameOptions& options,
                           FrameStats* stats, bool grazing = false) {
    Result<RenderImage> image =
        rig.renderer->RenderFullFrame(View(grazing), params, options, stats);
    EXPECT_TRUE(image.ok()) << image.status().ToString();
    return image.ok() ? std::move(*image) : RenderImage{};
  }
  // A full frame falling back on level `level` (plus every other level-0 brick when
  // `checkerboard`): bit-identical with and without skipping, and (`expect_skips`) skipping.
  static void ExpectFallbackSkippingLossless(const SceneSpec& spec, int level, bool checkerboard,
                                             const RenderParams& params, bool expect_skips,
                                             const std::string& what) {
    auto on = Resident(spec, level, checkerboard);
    auto off = Resident(spec, level, checkerboard);
    ASSERT_TRUE(on != nullptr && off != nullptr);
    FrameOptions plain;
    plain.skip_empty_space = false;
    FrameStats on_stats, off_stats;
    const RenderImage a = Frame(*on, params, FrameOptions{}, &on_stats);
    const RenderImage b = Frame(*off, params, plain, &off_stats);
    EXPECT_FALSE(on_stats.final) << what;
    if (expect_skips) {
      EXPECT_GT(on_stats.samples_skipped, 0u) << what;
    }
    EXPECT_EQ(a.rgba, b.rgba) << what << ": " << Describe(CompareImages(a, b));
  }
};

// Without skipping, the fallback image is the frame AT the ancestor's level with the step scaled
// down to the same sample spacing (same arcs, the same positions after the exact power-of-two
// scaling, the same opacity ratio), which reads that level resident: bit for bit.
TEST_F(FallbackTest, EqualsTheAncestorLevelAtTheSameSpacing) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (const int shift : {1, 2}) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
      for (const bool grazing : {false, true}) {
        const std::string what = std::string(RenderModeName(mode)) + ", " + std::to_string(shift) +
                                 " level(s) up" + (grazing ? ", grazing" : "");
        FrameOptions plain;
        plain.skip_empty_space = false;
        auto rig = Resident(shift, false);
        ASSERT_NE(rig, nullptr);
        FrameStats stats;
        const RenderImage fallback = Frame(*rig, Params(mode), plain, &stats, grazing);
        EXPECT_FALSE(stats.final) << what;  // It asked for the level-0 bricks.
        auto at_level = Resident(shift, false);
        ASSERT_NE(at_level, nullptr);
        RenderParams scaled = Params(mode);
        scaled.step_voxels = std::ldexp(1.0, -shift);
        FrameOptions coarse = plain;
        coarse.lod_bias = shift;
        const RenderImage expected = Frame(*at_level, scaled, coarse, &stats, grazing);
        EXPECT_TRUE(stats.final) << what;
        EXPECT_EQ(fallback.rgba, expected.rgba)
            << what << ": " << Describe(CompareImages(fallback, expected));
      }
    }
  }
}

// Cell skipping in an ancestor's brick is lossless for what the fallback shows, and stops at the
// wanted node's box: with every other level-0 brick resident (and so their ancestors), a skip
// through a level-1 cell that is inert (the dots averaged below the window) into a resident
// neighbour would drop that neighbour's dot. Two levels up: level 2 (and the root) resident.
TEST_F(FallbackTest, CellSkippingIsLosslessAndStopsAtTheWantedBox) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  for (const int shift : {1, 2}) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
      const std::string what =
          std::string(RenderModeName(mode)) + ", " + std::to_string(shift) + " level(s) up";
      ExpectFallbackSkippingLossless(Spec(true), shift, shift == 1,
                                     Params(mode, shift == 1 ? 9000 : 2500),
                                     mode != RenderMode::kMinIp, what);
    }
  }
}

// Value-range skipping while full frames fall back: a node whose own data are inert is NOT inert
// for what the frame shows when an ancestor stands in for it, since the ancestor's interpolation
// reaches across the node's faces. Bright slabs end at the faces x = 16 and x = 48 of dim,
// transparent 16^3 bricks; with level-0 bricks missing, the level-1 (or level-2) ancestor's
// interpolation carries light up to 1 (2) level-0 voxels into the dim bricks. Skipping must show
// it: bit-identical to skipping off, and still skipping.
TEST_F(FallbackTest, NodeSkippingKeepsTheLightAnAncestorCarriesAcrossFaces) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = Spec();
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    if (x % 32 >= 10 && x % 32 < 16) return static_cast<uint16_t>(40000 + Hash(x, y, z, c) % 25000);
    return static_cast<uint16_t>(200 + Hash(x, y, z, c) % 800);
  };
  for (const int shift : {1, 2}) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
      const std::string what =
          std::string(RenderModeName(mode)) + ", " + std::to_string(shift) + " level(s) up";
      ExpectFallbackSkippingLossless(spec, shift, false, Params(mode), true, what);
    }
  }
}

TEST(VolumeRendererTest, WorkingSetLargerThanBrickBuffer) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const SceneSpec spec = NoiseSpec({32, 32, 32}, 1, {8, 8, 8});
  auto roomy = MakeRig(spec);
  ASSERT_NE(roomy, nullptr);
  DeviceOctreeOptions tight;
  tight.brick_buffer_bytes = kMinBrickSlots * 10 * 10 * 10 * 2;
  auto small = MakeRig(spec, tight);
  ASSERT_NE(small, nullptr);
  ASSERT_EQ(small->device->slot_count(), kMinBrickSlots);
  // Ten slots split over four allocations of at most three bricks: slots in every allocation.
  DeviceOctreeOptions split;
  split.brick_buffer_bytes = 10 * 10 * 10 * 10 * 2;
  split.max_allocation_bytes = 3 * 10 * 10 * 10 * 2;
  auto split_rig = MakeRig(spec, split);
  ASSERT_NE(split_rig, nullptr);
  ASSERT_EQ(split_rig->device->allocation_count(), 4);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, mode);
    params.channels[0].opacity_scale = 0.05;
    const Camera camera = Standard(*roomy, StandardView::kIso, Projection::kOrthographic, 40, 40);
    FrameStats small_stats;
    const RenderImage a = Gpu(*roomy, camera, params, Refine());
    const RenderImage b = Gpu(*small, camera, params, Refine(), &small_stats);
    EXPECT_TRUE(small_stats.final);
    EXPECT_GT(small_stats.bricks_uploaded, 64u);  // Bricks were evicted and uploaded again.
    EXPECT_LE(CompareImages(a, b).max_abs, 1e-6) << RenderModeName(mode);
    const RenderImage c = Gpu(*split_rig, camera, params, Refine());
    EXPECT_LE(CompareImages(a, c).max_abs, 1e-6) << RenderModeName(mode);
  }
}

// Refinement passes over slices of the tile list (FrameOptions::pass_target_ms, as the render
// service runs them so that huge refinements yield to other views' frames): the same image as
// passes over the whole list, also when the bricks do not all fit (rays of later slices wait
// while earlier slices' bricks are evicted; slices that uploaded re-run and rewrite their list
// entries: a duplicated entry would double-count finished rays) and with a last tile row shorter
// than the others.
TEST(VolumeRendererTest, RefinementInRowBandsGivesTheSameImage) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const SceneSpec spec = NoiseSpec({32, 32, 32}, 2, {8, 8, 8});
  auto roomy = MakeRig(spec);
  ASSERT_NE(roomy, nullptr);
  DeviceOctreeOptions tight;
  tight.brick_buffer_bytes = kMinBrickSlots * 10 * 10 * 10 * 2 * 2;
  auto small = MakeRig(spec, tight);
  ASSERT_NE(small, nullptr);
  FrameOptions banded = Refine();
  banded.pass_target_ms = 1e-9;  // As short as possible: one row of tiles per pass.
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    params.channels[0].opacity_scale = 0.05;
    for (Projection projection : {Projection::kOrthographic, Projection::kPerspective}) {
      const Camera camera = Standard(*roomy, StandardView::kIso, projection, 40, 44);
      FrameStats whole_stats, banded_stats, small_stats;
      const RenderImage whole = Gpu(*roomy, camera, params, Refine(), &whole_stats);
      const RenderImage bands = Gpu(*roomy, camera, params, banded, &banded_stats);
      // (Slice sizes come from the renderer's measured speed: the whole-list refinements before
      // measure it.)
      const RenderImage tight_whole = Gpu(*small, camera, params, Refine());
      const RenderImage tight_bands = Gpu(*small, camera, params, banded, &small_stats);
      EXPECT_TRUE(banded_stats.final && small_stats.final);
      EXPECT_GE(small_stats.passes, 6);
      EXPECT_LE(CompareImages(whole, tight_whole).max_abs, 1e-6) << RenderModeName(mode);
      // Six tile rows of 5 tiles (five of 8 pixel rows and one of 4), at least one pass each.
      EXPECT_GE(banded_stats.passes, 6);
      EXPECT_GT(banded_stats.passes, whole_stats.passes);
      EXPECT_LE(CompareImages(whole, bands).max_abs, 1e-6) << RenderModeName(mode);
      EXPECT_LE(CompareImages(whole, tight_bands).max_abs, 1e-6) << RenderModeName(mode);
      EXPECT_DOUBLE_EQ(banded_stats.finished_fraction, 1.0);
      EXPECT_DOUBLE_EQ(small_stats.finished_fraction, 1.0);
    }
  }
}

TEST(VolumeRendererTest, PerSampleLevelOfDetail) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const SceneSpec spec = NoiseSpec({64, 64, 32}, 1, {8, 8, 8});
  RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.05;
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 64, 64);
  const RenderImage ref = Reference(*rig, camera, params);
  FrameStats fine_stats;
  const RenderImage fine = Gpu(*rig, camera, params, Refine(), &fine_stats);
  EXPECT_LE(CompareImages(fine, ref).max_abs, kTol);

  // lod_bias +1 on a fresh device octree: level 1, a quarter of the bricks requested.
  auto coarse_rig = MakeRig(spec);
  ASSERT_NE(coarse_rig, nullptr);
  FrameOptions coarse = Refine();
  coarse.lod_bias = 1;
  FrameStats coarse_stats;
  const RenderImage blurred = Gpu(*coarse_rig, camera, params, coarse, &coarse_stats);
  EXPECT_LT(coarse_stats.bricks_uploaded * 4, fine_stats.bricks_uploaded * 2);
  const ImageDiff coarse_diff = CompareImages(blurred, ref);
  EXPECT_GT(coarse_diff.max_abs, kTol);  // Different data ...
  EXPECT_LT(coarse_diff.max_abs, 0.25);  // ... of the same volume.
  EXPECT_GT(coarse_diff.psnr, 20);

  // A quarter of the pixels has the same footprint as bias +1.
  auto small_rig = MakeRig(spec);
  ASSERT_NE(small_rig, nullptr);
  const Camera small = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 32, 32);
  FrameStats small_stats;
  Gpu(*small_rig, small, params, Refine(), &small_stats);
  EXPECT_EQ(small_stats.bricks_uploaded, coarse_stats.bricks_uploaded);

  // Bias -1 asks for level -1: clamped to 0, the very same image.
  FrameOptions sharp = Refine();
  sharp.lod_bias = -1;
  const RenderImage same = Gpu(*rig, camera, params, sharp);
  EXPECT_EQ(CompareImages(same, fine).max_abs, 0);
}

TEST(VolumeRendererTest, EmptySpaceSkippingChangesNothingButSamples) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {64, 48, 40};
  spec.brick = {8, 8, 8};
  // Two noisy blobs in empty space.
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    const auto blob = [&](double cx, double cy, double cz, double r) {
      return (x - cx) * (x - cx) + (y - cy) * (y - cy) + (z - cz) * (z - cz) < r * r;
    };
    if (blob(14, 12, 10, 6) || blob(45, 33, 28, 8)) {
      return static_cast<uint16_t>(20000 + Hash(x, y, z, 0) % 40000);
    }
    return 0;
  };
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, mode);
      params.channels[0].opacity_scale = 0.1;
      const Camera camera = Standard(*rig, StandardView::kIso, p, 64, 64);
      FrameOptions with = Refine();
      FrameOptions without = Refine();
      without.skip_empty_space = false;
      FrameStats with_stats, without_stats;
      const RenderImage a = Gpu(*rig, camera, params, with, &with_stats);
      const RenderImage b = Gpu(*rig, camera, params, without, &without_stats);
      EXPECT_EQ(a.rgba, b.rgba) << RenderModeName(mode) << " " << ProjectionName(p);
      // About a quarter of the samples on this volume (measured 19018 vs 76960 ortho).
      EXPECT_LT(with_stats.samples * 2, without_stats.samples)
          << RenderModeName(mode) << " " << ProjectionName(p);
      // Near the faces of a pruned (homogeneous, brickless) node the reference interpolates
      // with the neighbouring voxels while the octree gives the node's average: a bounded
      // difference on a few pixels, the same with and without skipping.
      const ImageDiff d = CompareImages(a, Reference(*rig, camera, params));
      EXPECT_LE(d.max_abs, 0.06) << RenderModeName(mode) << " " << ProjectionName(p) << ": "
                                 << Describe(d);
      EXPECT_GT(d.psnr, 50) << RenderModeName(mode) << " " << ProjectionName(p);
    }
  }
}

// Refinement at level 0 with and without skipping: identical images, every sample either taken
// or skipped, none skipped without; returns the image and the stats with skipping.
RenderImage RenderBothWays(Rig& rig, const Camera& camera, const RenderParams& params,
                           const std::string& what, FrameStats* with_stats) {
  FrameOptions with = Refine();
  with.lod_bias = -4;  // Level 0 everywhere: comparable with the reference.
  FrameOptions without = with;
  without.skip_empty_space = false;
  FrameStats without_stats;
  const RenderImage a = Gpu(rig, camera, params, with, with_stats);
  const RenderImage b = Gpu(rig, camera, params, without, &without_stats);
  EXPECT_EQ(a.rgba, b.rgba) << what;
  EXPECT_EQ(with_stats->samples + with_stats->samples_skipped, without_stats.samples) << what;
  EXPECT_EQ(without_stats.samples_skipped, 0u) << what;
  return a;
}

// Full frames at level 0 once everything they need is resident (converged with skipping off):
// with and without skipping bit-identical to `expected`, and skipping skipped something.
void ExpectConvergedFullFramesEqual(Rig& rig, const Camera& camera, const RenderParams& params,
                                    const RenderImage& expected, const std::string& what) {
  FrameOptions full;
  full.lod_bias = -4;
  full.upload.max_ms = 1e9;
  FrameOptions full_off = full;
  full_off.skip_empty_space = false;
  FrameStats fs;
  for (int i = 0; i < 6 && !fs.final; ++i) Gpu(rig, camera, params, full_off, &fs);
  ASSERT_TRUE(fs.final) << what;
  FrameStats on_stats;
  EXPECT_EQ(Gpu(rig, camera, params, full, &on_stats).rgba, expected.rgba) << what;
  EXPECT_EQ(Gpu(rig, camera, params, full_off).rgba, expected.rgba) << what;
  EXPECT_GT(on_stats.samples_skipped, 0u) << what;
}

// Dim noise around bright blobs, two channels, every brick holding noise (no brickless node, so
// the leaf skipping never applies), inside a black shell three voxels thick (every ray enters
// through black, so MinIP reaches every node's minimum early).
SceneSpec DimNoiseBlobsSpec() {
  SceneSpec spec;
  spec.size = {48, 40, 32};
  spec.brick = {8, 8, 8};
  spec.channels = 2;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    const auto blob = [&](double cx, double cy, double cz, double r) {
      return (x - cx) * (x - cx) + (y - cy) * (y - cy) + (z - cz) * (z - cz) < r * r;
    };
    const bool bright = c == 0 ? blob(12, 12, 10, 6) || blob(34, 28, 22, 7) : blob(30, 14, 16, 8);
    if (bright) return static_cast<uint16_t>(20000 + Hash(x, y, z, c) % 40000);
    const auto in_shell = [](int64_t v, int64_t n) { return v < 3 || v >= n - 3; };
    if (in_shell(x, 48) || in_shell(y, 40) || in_shell(z, 32)) return 0;
    const uint32_t h = Hash(x, y, z, c);
    return static_cast<uint16_t>(c == 0 ? h % 1000 : 100 + h % 500);
  };
  return spec;
}

// Parameters under which DimNoiseBlobsSpec's dim noise cannot change a ray: DVR windows / a LUT
// make it fully transparent, MIP passes through dim nodes after a blob, MinIP through bright ones
// after the background.
RenderParams DimNoiseBlobsParams(RenderMode mode) {
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
  if (mode == RenderMode::kDvr) {
    // Channel 0: a window starting above the noise; channel 1: a LUT transparent below entry
    // 20 (about 5000 stored).
    params.channels[0].window = 30000;
    params.channels[0].level = 1000 + 15000;
    params.channels[0].opacity_scale = 0.2;
    std::array<volume::Rgba, kLutEntries> lut;
    for (int i = 0; i < kLutEntries; ++i) {
      lut[i] = {static_cast<uint8_t>(i), 80, static_cast<uint8_t>(255 - i),
                static_cast<uint8_t>(i < 20 ? 0 : i / 4)};
    }
    params.channels[1].lut = lut;
  }
  return params;
}

// DimNoiseBlobsSpec's rig in DVR, MIP and MinIP, ortho and perspective, with DimNoiseBlobsParams
// changed by `adjust`: refinement bit-identical with skipping off, converged full frames too,
// the CPU reference's image at level 0, and the skipped-sample counter proves the skipping
// happened (DVR and MinIP skip most of the noise; MIP only behind rays that already crossed a
// blob of both channels' brightness).
void ExpectDimNoiseBlobsSkippedLosslessly(Rig& rig,
                                          const std::function<void(RenderParams&)>& adjust) {
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    RenderParams params = DimNoiseBlobsParams(mode);
    adjust(params);
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      const std::string what =
          std::string(RenderModeName(mode)) + " " + std::string(ProjectionName(p));
      const Camera camera = Standard(rig, StandardView::kIso, p, 48, 48);
      FrameStats with_stats;
      const RenderImage a = RenderBothWays(rig, camera, params, what, &with_stats);
      EXPECT_GT(with_stats.samples_skipped,
                mode == RenderMode::kMip ? uint64_t{0} : with_stats.samples / 4)
          << what;
      const ImageDiff d = CompareImages(a, Reference(rig, camera, params));
      EXPECT_LE(d.max_abs, kTol) << what << ": " << Describe(d);
      ExpectConvergedFullFramesEqual(rig, camera, params, a, what);
    }
  }
}

// Value-range skipping (issue 12) on DimNoiseBlobsSpec (LOSSLESS: every brick holds noise): inert
// nodes are skipped without changing the image.
TEST(VolumeRendererTest, ValueRangeSkippingIsLosslessAndTriggers) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(DimNoiseBlobsSpec());
  ASSERT_NE(rig, nullptr);
  // Every node owns a brick: only value ranges can skip here.
  ASSERT_EQ(rig->scene->tree->stats().homogeneous_nodes, 0u);
  ExpectDimNoiseBlobsSkippedLosslessly(*rig, [](RenderParams&) {});
}

// The same with channel transforms (each channel skips in its own space: nodes per channel,
// cells per step of a transformed run). Channel 1's map includes a scale, so its transformed ray
// is not parallel to channel 0's; near the volume's faces a channel leaves the box (no sample
// there, and no skip across it: every skipped sample is one that would have been taken).
TEST(VolumeRendererTest, TransformedChannelsSkipInertSpaceLosslessly) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(DimNoiseBlobsSpec());
  ASSERT_NE(rig, nullptr);
  ExpectDimNoiseBlobsSkippedLosslessly(*rig, [](RenderParams& params) {
    params.channels[0].transform = Mat4::Translation({0.7, -0.4, 0.9});
    params.channels[1].transform =
        Mat4::Translation({-1.3, 0.6, 0.4}) * Mat4::Scale({1.02, 0.98, 1});
  });
}

// 64^3 voxels, two channels, 32^3 bricks that each hold a bright noisy blob of `radius` (<= 7)
// voxels (channel 0's in the brick's high 16^3 octant, channel 1's in its low one, each in one
// DVR cell: cell_ranges.h) in dim noise, inside a black shell: no node is inert for DVR, but most
// of each brick's cells are dim, fine (8^3) and coarse (16^3) alike.
SceneSpec BlobPerBrickSpec(int64_t radius) {
  SceneSpec spec;
  spec.size = {64, 64, 64};
  spec.brick = {32, 32, 32};
  spec.channels = 2;
  spec.value = [radius](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    const int64_t centre = c == 0 ? 23 : 8;
    const int64_t dx = x % 32 - centre;
    const int64_t dy = y % 32 - centre;
    const int64_t dz = z % 32 - centre;
    if (dx * dx + dy * dy + dz * dz < radius * radius) {
      return static_cast<uint16_t>(30000 + Hash(x, y, z, c) % 30000);
    }
    const auto in_shell = [](int64_t v) { return v < 2 || v >= 62; };
    if (in_shell(x) || in_shell(y) || in_shell(z)) return 0;
    return static_cast<uint16_t>(200 + Hash(x, y, z, c) % 800);
  };
  return spec;
}

// Cell ranges (render/cell_ranges.h) on BlobPerBrickSpec: node ranges skip nothing for DVR, so
// the kernel must skip the dim cells and still give exactly the image without skipping, and the
// reference's image.
TEST(VolumeRendererTest, CellRangeSkippingInsideNonEmptyBricksIsLossless) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(BlobPerBrickSpec(3));
  ASSERT_NE(rig, nullptr);
  ASSERT_EQ(rig->scene->tree->stats().homogeneous_nodes, 0u);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    for (ChannelParams& ch : params.channels) {
      ch.window = 20000;
      ch.level = 12000;  // Transparent below 2000: all the dim noise.
      ch.opacity_scale = 0.3;
    }
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      const std::string what =
          std::string(RenderModeName(mode)) + " " + std::string(ProjectionName(p));
      const Camera camera = Standard(*rig, StandardView::kIso, p, 40, 40);
      FrameStats with_stats;
      const RenderImage a = RenderBothWays(*rig, camera, params, what, &with_stats);
      // Most cells: DVR's dim ones are transparent, MIP's lie below the window once a ray has a
      // sample, MinIP's lie above the black shell's zero.
      EXPECT_GT(with_stats.samples_skipped, with_stats.samples) << what;
      const ImageDiff d = CompareImages(a, Reference(*rig, camera, params));
      EXPECT_LE(d.max_abs, kTol) << what << ": " << Describe(d);
    }
  }
}

// The device's opacity correction (OctoCorrectOpacity: squarings for ratios 2^s, else
// 1 - exp2(r log2(1 - a))) against the double CorrectOpacity of render_params.h, alpha by alpha:
// 0 and 1 exact, never outside [0, 1], and off by at most a few ulps of 1 times max(r, 1) (the
// rounding of 1 - a, carried through the power: per reference spacing what compositing's own
// 1 - a loses). A relaxed-precision exp2 / log2 or a wrong formula is far outside.
TEST(VolumeRendererTest, OpacityCorrectionMatchesTheDoubleFormula) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const testing::ClTestEnv& env = testing::SharedClTestEnv();
  const ComputeContext& cc = *env.context;
  const char* source =
      "#include \"ray_common.cl\"\n"
      "__kernel void Correct(__global const float* a, __global const float* r, uint n,\n"
      "                      __global float* out) {\n"
      "  const size_t i = get_global_id(0);\n"
      "  if (i < n) out[i] = OctoCorrectOpacity(a[i], OctoOpacityRatio(r[i]));\n"
      "}\n";
  auto program = BuildProgram(cc, "opacity_test.cl", source, kTestBuildOptions);
  ASSERT_TRUE(program.ok()) << program.status().ToString();
  cl_int err = CL_SUCCESS;
  ClKernel kernel(clCreateKernel(program->get(), "Correct", &err));
  ASSERT_EQ(err, CL_SUCCESS);
  const std::vector<float> alphas = {0.0f, 1e-7f, 1e-5f, 1e-3f,  0.01f,        0.1f,
                                     0.3f, 0.5f,  0.9f,  0.999f, 1.0f - 1e-6f, 1.0f};
  const std::vector<float> ratios = {1.0f / 64, 0.3f, 0.577f, 0.7f,  1.0f,   1.5f,
                                     2.0f,      3.0f, 4.0f,   37.3f, 1000.0f};
  std::vector<float> a;
  std::vector<float> r;
  for (const float ratio : ratios) {
    for (const float alpha : alphas) {
      a.push_back(alpha);
      r.push_back(ratio);
    }
  }
  const size_t n = a.size();
  auto a_buffer = cc.CreateBuffer(CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, n * 4, a.data());
  auto r_buffer = cc.CreateBuffer(CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, n * 4, r.data());
  auto out_buffer = cc.CreateBuffer(CL_MEM_WRITE_ONLY, n * 4);
  ASSERT_TRUE(a_buffer.ok() && r_buffer.ok() && out_buffer.ok());
  ASSERT_TRUE(
      SetKernelArgs(kernel.get(), *a_buffer, *r_buffer, static_cast<cl_uint>(n), *out_buffer).ok());
  ASSERT_TRUE(cc.EnqueueKernel1D(kernel.get(), n).ok());
  std::vector<float> out(n);
  ASSERT_TRUE(cc.ReadBuffer(*out_buffer, 0, n * 4, out.data()).ok());
  for (size_t i = 0; i < n; ++i) {
    const std::string what = "a " + std::to_string(a[i]) + ", ratio " + std::to_string(r[i]);
    const double want = CorrectOpacity(a[i], r[i]);
    EXPECT_GE(out[i], 0.0f) << what;
    EXPECT_LE(out[i], 1.0f) << what;
    if (a[i] == 0.0f || a[i] == 1.0f) {
      EXPECT_EQ(out[i], a[i]) << what;
      continue;
    }
    const double bound = 4.0 * FLT_EPSILON * std::max<double>(r[i], 1.0);
    EXPECT_NEAR(out[i], want, bound) << what;
  }
}

// Gamma and the opacity correction are one implementation whichever step takes a sample: vector
// calls (OctoGamma4, OctoCorrectOpacity4) whose lane 0 the single-sample path takes, so a vector
// builtin that rounds differently from the scalar one cannot make a sample's colour depend on its
// step. Anisotropic voxels seen obliquely give segments that are no power-of-two multiple of the
// reference spacing (the general exp2 / log2 correction, not squarings), and gamma is on in both
// channels. With skipping on, the cell walk cuts each brick's run into stretches elsewhere than
// without, so many samples are taken in an eight- or four-sample step in one frame and alone in
// the other: the images must be bit-identical, and equal the CPU reference.
TEST(VolumeRendererTest, ShadingDoesNotDependOnTheStepThatTakesASample) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // Blobs several cells across: long stretches of visible samples, whose ends the singles take.
  SceneSpec spec = BlobPerBrickSpec(7);
  spec.spacing = {0.4, 0.4, 1.1};
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kDvr);
  params.channels[0].gamma = 0.6;
  params.channels[1].gamma = 1.7;
  for (ChannelParams& ch : params.channels) {
    // Transparent below 2000 (all the dim noise); the blobs' values spread over (0, 1), where the
    // gamma is no identity.
    ch.window = 58000;
    ch.level = 31000;
    ch.opacity_scale = 0.3;
  }
  // Both views are oblique to the voxels' anisotropy: segments of no power-of-two ratio.
  for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
    for (StandardView view : {StandardView::kIso, StandardView::kZ}) {
      const std::string what =
          std::string(ProjectionName(p)) + " " + std::string(StandardViewName(view));
      const Camera camera = Standard(*rig, view, p, 40, 40);
      FrameStats with_stats;
      const RenderImage a = RenderBothWays(*rig, camera, params, what, &with_stats);
      EXPECT_GT(with_stats.samples_skipped, with_stats.samples / 4) << what;
      const ImageDiff d = CompareImages(a, Reference(*rig, camera, params));
      EXPECT_LE(d.max_abs, kTol) << what << ": " << Describe(d);
      ExpectConvergedFullFramesEqual(*rig, camera, params, a, what);
    }
  }
}

// Gammas so far from 1 that they round to 0 or infinity in float (valid: finite and > 0) keep the
// pow limits at the window's ends: t = 0 stays 0, t = 1 stays 1 (exp2(gamma log2 t) alone is NaN
// there), so the images equal the double-precision reference's.
TEST(VolumeRendererTest, ExtremeGammasKeepTheWindowsEnds) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(BlobPerBrickSpec(7));
  ASSERT_NE(rig, nullptr);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
    params.channels[0].gamma = 1e-50;
    params.channels[1].gamma = 1e39;
    for (ChannelParams& ch : params.channels) {
      ch.window = 40000;  // Values from 0 to above the window: t = 0, (0, 1) and 1.
      ch.level = 22000;
      ch.opacity_scale = 0.3;
    }
    const Camera camera = Standard(*rig, StandardView::kIso, Projection::kPerspective, 40, 40);
    FrameOptions options = Refine();
    options.lod_bias = -4;
    const RenderImage image = Gpu(*rig, camera, params, options);
    for (float v : image.rgba) ASSERT_TRUE(std::isfinite(v)) << RenderModeName(mode);
    const ImageDiff d = CompareImages(image, Reference(*rig, camera, params));
    EXPECT_LE(d.max_abs, kTol) << RenderModeName(mode) << ": " << Describe(d);
  }
}

// The brick runs' N-sample steps (OCTO_RUN_LANES 8 where the device prefers wide vectors, 4
// elsewhere) compute every sample with the same expressions lane by lane: renderers of both
// widths on the same octree give bit-identical images — three channels (gamma on two, a LUT
// on one: its lookups go lane by lane), opaque enough to terminate inside a step, DVR,
// MIP and MinIP, orthographic and perspective, refinement and converged full frames.
TEST(VolumeRendererTest, EightAndFourSampleStepsGiveIdenticalImages) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({40, 48, 36}, 3));
  ASSERT_NE(rig, nullptr);
  const testing::ClTestEnv& env = testing::SharedClTestEnv();
  Result<std::unique_ptr<VolumeRenderer>> four =
      VolumeRenderer::Create(env.context, env.programs, rig->device.get(), rig->scene->spec.spacing,
                             kTestBuildOptions, /*run_lanes=*/4);
  ASSERT_TRUE(four.ok()) << four.status().ToString();
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    RenderParams params = ColourParams(mode);  // Gamma on channels 0 and 1, a LUT on 2.
    params.channels[2].opacity_scale = 4;      // Rays terminate early.
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      const std::string what =
          std::string(RenderModeName(mode)) + " " + std::string(ProjectionName(p));
      const Camera camera = Standard(*rig, StandardView::kIso, p, 36, 30);
      FrameOptions refine = Refine();
      refine.lod_bias = -4;
      FrameStats eight_stats, four_stats;
      const RenderImage eight = Gpu(*rig, camera, params, refine, &eight_stats);
      Result<RenderImage> four_image = (*four)->Render(camera, params, refine, &four_stats);
      ASSERT_TRUE(four_image.ok()) << four_image.status().ToString();
      EXPECT_EQ(eight.rgba, four_image->rgba) << what;
      EXPECT_EQ(eight_stats.samples, four_stats.samples) << what;
      EXPECT_GT(eight_stats.samples, 0u) << what;
      FrameOptions full;
      full.lod_bias = -4;
      full.upload.max_ms = 1e9;
      FrameStats fs;
      for (int i = 0; i < 6 && !fs.final; ++i) Gpu(*rig, camera, params, full, &fs);
      ASSERT_TRUE(fs.final) << what;
      Result<RenderImage> four_full = (*four)->Render(camera, params, full);
      ASSERT_TRUE(four_full.ok()) << four_full.status().ToString();
      EXPECT_EQ(Gpu(*rig, camera, params, full).rgba, four_full->rgba) << what;
    }
  }
  EXPECT_FALSE(VolumeRenderer::Create(env.context, env.programs, rig->device.get(),
                                      rig->scene->spec.spacing, kTestBuildOptions, 16)
                   .ok());
}

// Channel transforms (chromatic-aberration correction) take their own brick runs: each channel
// follows its transformed ray through its own bricks, several samples at a time, and falls back
// on single samples where a lane leaves the volume or the channel's brick. Three channels — one
// untransformed, one shifted and scaled so that part of its positions leave the box, one shifted
// by several voxels (into other bricks than the first channel's) — in DVR (opaque enough to
// terminate inside a step), MIP and MinIP, orthographic and perspective: equal to the CPU
// reference at level 0, MIP's samples exactly the reference's (every in/out-of-box decision the
// same), the eight- and four-sample steps bit-identical at every level of detail, and the
// converged full frames equal to refinement.
TEST(VolumeRendererTest, TransformedChannelsRunThroughTheirOwnBricks) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec({48, 40, 36}, 3);
  spec.spacing = {0.5, 0.5, 1.2};
  auto rig = MakeRig(spec);
  ASSERT_NE(rig, nullptr);
  const testing::ClTestEnv& env = testing::SharedClTestEnv();
  Result<std::unique_ptr<VolumeRenderer>> four =
      VolumeRenderer::Create(env.context, env.programs, rig->device.get(), spec.spacing,
                             kTestBuildOptions, /*run_lanes=*/4);
  ASSERT_TRUE(four.ok()) << four.status().ToString();
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    RenderParams params = ColourParams(mode);
    params.channels[1].transform =
        Mat4::Translation({0.8, -0.6, 1.1}) * Mat4::Scale({1.03, 0.97, 1});
    params.channels[2].transform = Mat4::Translation({-2.7, 3.1, -1.9});
    params.channels[2].opacity_scale = 2;  // Rays terminate inside the volume.
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      const std::string what =
          std::string(RenderModeName(mode)) + " " + std::string(ProjectionName(p));
      const Camera camera = Standard(*rig, StandardView::kIso, p, 40, 36);
      FrameOptions refine = Refine();
      refine.lod_bias = -4;  // Level 0: comparable with the reference.
      FrameStats stats;
      const RenderImage image = Gpu(*rig, camera, params, refine, &stats);
      RenderStats ref_stats;
      const RenderImage ref = Reference(*rig, camera, params, &ref_stats);
      const ImageDiff d = CompareImages(image, ref);
      EXPECT_LE(d.max_abs, kTol) << what << ": " << Describe(d);
      if (mode != RenderMode::kDvr) {
        uint64_t ref_samples = 0;
        for (uint64_t n : ref_stats.channel_samples) ref_samples += n;
        EXPECT_EQ(stats.samples, ref_samples) << what;
      }
      Result<RenderImage> four_image = (*four)->Render(camera, params, refine);
      ASSERT_TRUE(four_image.ok()) << four_image.status().ToString();
      EXPECT_EQ(image.rgba, four_image->rgba) << what;
      // The screen's levels of detail: runs through coarser bricks too.
      Result<RenderImage> four_lod = (*four)->Render(camera, params, Refine());
      ASSERT_TRUE(four_lod.ok()) << four_lod.status().ToString();
      EXPECT_EQ(Gpu(*rig, camera, params, Refine()).rgba, four_lod->rgba) << what;
      FrameOptions full;
      full.lod_bias = -4;
      full.upload.max_ms = 1e9;
      FrameStats fs;
      for (int i = 0; i < 6 && !fs.final; ++i) Gpu(*rig, camera, params, full, &fs);
      ASSERT_TRUE(fs.final) << what;
      EXPECT_EQ(Gpu(*rig, camera, params, full).rgba, image.rgba) << what;
    }
  }
  // Bricks read only by runs count as used (the eviction order): transforms that move no sample
  // out of its brick read exactly the bricks of the untransformed frame (a converged full frame,
  // one pass; skipping off: it stamps every brick it samples). Few rays straight through the
  // bricks: runs take every sample, a brick's first one included.
  const Camera camera = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 6, 6);
  RenderParams plain = ColourParams(RenderMode::kMip);
  RenderParams nudged = plain;
  for (ChannelParams& ch : nudged.channels) ch.transform = Mat4::Translation({1e-4, 0, 0});
  FrameOptions full;
  full.lod_bias = -4;
  full.upload.max_ms = 1e9;
  full.skip_empty_space = false;
  FrameStats plain_stats, nudged_stats;
  for (int i = 0; i < 6 && !plain_stats.final; ++i) Gpu(*rig, camera, plain, full, &plain_stats);
  Gpu(*rig, camera, nudged, full, &nudged_stats);
  ASSERT_TRUE(plain_stats.final);
  ASSERT_TRUE(nudged_stats.final);
  EXPECT_GT(plain_stats.slots_used, 1u);
  EXPECT_EQ(nudged_stats.slots_used, plain_stats.slots_used);
}

// A node's faces on the volume's boundary need no half-voxel shell (nothing beyond them is read:
// rays are clipped to the volume, positions clamped into it), so a ray that enters an inert
// volume skips from its first sample: with every value below the DVR window, no ray takes a
// sample — refinement and full frames, orthographic and perspective, a volume whose far bricks
// reach beyond it — and the image is bit-identical to skipping off.
TEST(VolumeRendererTest, RaysEnteringAnInertVolumeTakeNoSample) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({40, 48, 36}, 2));
  ASSERT_NE(rig, nullptr);
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kDvr);
  for (ChannelParams& ch : params.channels) {
    ch.window = 20000;
    ch.level = 70000 + 10000;  // Everything below the window: transparent.
  }
  for (const Projection projection : {Projection::kOrthographic, Projection::kPerspective}) {
    for (const StandardView view : {StandardView::kIso, StandardView::kX, StandardView::kZ}) {
      const Camera camera = Standard(*rig, view, projection, 24, 20);
      const std::string what =
          std::string(projection == Projection::kPerspective ? "persp" : "ortho") + " view " +
          std::to_string(static_cast<int>(view));
      FrameOptions plain = Refine();
      plain.skip_empty_space = false;
      const RenderImage expected = Gpu(*rig, camera, params, plain);
      FrameStats stats;
      EXPECT_EQ(Gpu(*rig, camera, params, Refine(), &stats).rgba, expected.rgba) << what;
      EXPECT_TRUE(stats.final) << what;
      EXPECT_EQ(stats.samples, 0u) << what;
      EXPECT_GT(stats.samples_skipped, 0u) << what;
      FrameStats full;
      EXPECT_EQ(Gpu(*rig, camera, params, FrameOptions{}, &full).rgba, expected.rgba) << what;
      EXPECT_EQ(full.samples, 0u) << what;
    }
  }
}

// The walk over a brick's cells (kernels/raycast.cl, brick-local marching): cells alternate
// like a 3-D checkerboard between bright spots (even cells) and dim noise (odd cells; their
// ranges, apron included, reach only dim voxels), so every face of an inert cell leads into a
// live one. A walk that left a cell through the wrong face, or jumped past its exit, would skip
// bright samples. The checkerboard has the mode's cells: DVR's coarse (16^3, over a 128^3 volume
// so rays cross as many faces as MIP's 8^3 ones in 64^3), MIP's fine. DVR also on bricks of
// 40 x 24 x 20 over an 8^3 checkerboard: their last coarse cells are partial (8, 8 and 4
// voxels), and only there does a coarse cell hold one square alone, inert or live. Oblique,
// nearly axial and perspective rays; bit-identical to skipping off.
TEST(VolumeRendererTest, TheCellWalkSkipsOnlyInertCells) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  struct Case {
    RenderMode mode;
    int64_t square;
    octree::Vec3 size;
    octree::Vec3 brick;
  };
  const std::vector<Case> cases = {
      {RenderMode::kDvr, kCoarseCellSize, {128, 128, 128}, {32, 32, 32}},
      {RenderMode::kDvr, kCellSize, {80, 48, 40}, {40, 24, 20}},
      {RenderMode::kMip, kCellSize, {64, 64, 64}, {32, 32, 32}}};
  const std::vector<std::pair<Projection, Vec3>> views = {
      {Projection::kOrthographic, {1, 0.7, 2}},
      {Projection::kOrthographic, {1, 0.05, 0.03}},
      {Projection::kOrthographic, {-0.4, 1, -0.3}},
      {Projection::kPerspective, {0.9, -0.6, 0.5}},
      {Projection::kPerspective, {-0.2, -0.3, -1}}};
  for (const Case& test : cases) {
    SceneSpec spec;
    spec.size = test.size;
    spec.brick = test.brick;
    spec.channels = 1;
    const int64_t square = test.square;
    spec.value = [square](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
      const bool even = (x / square + y / square + z / square) % 2 == 0;
      const auto inner = [square](int64_t v) {
        return v % square >= 1 && v % square <= square - 2;
      };
      if (even && inner(x) && inner(y) && inner(z)) {
        return static_cast<uint16_t>(30000 + Hash(x, y, z, c) % 30000);
      }
      return static_cast<uint16_t>(200 + Hash(x, y, z, c) % 800);
    };
    auto rig = MakeRig(spec);
    ASSERT_NE(rig, nullptr);
    const Vec3 centre{test.size[0] / 2.0, test.size[1] / 2.0, test.size[2] / 2.0};
    RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, test.mode);
    params.channels[0].window = 20000;
    params.channels[0].level = 12000;         // Transparent below 2000: the dim noise.
    params.channels[0].opacity_scale = 0.05;  // DVR rays cross many bright cells.
    for (size_t v = 0; v < views.size(); ++v) {
      const std::string what = std::string(RenderModeName(test.mode)) + " squares of " +
                               std::to_string(square) + ", view " + std::to_string(v);
      const Vec3 dir = Normalize(views[v].second);
      Result<Camera> camera = Camera::LookAt(views[v].first, centre - dir * 250, centre,
                                             {0.3, -1, 0.2}, 48, 48, 30, 64);
      ASSERT_TRUE(camera.ok()) << camera.status().ToString();
      FrameStats with_stats;
      const RenderImage a = RenderBothWays(*rig, *camera, params, what, &with_stats);
      EXPECT_GT(with_stats.samples_skipped, 0u) << what;
      // Full frames with everything resident take the same walk: identical as well.
      ExpectConvergedFullFramesEqual(*rig, *camera, params, a, what);
    }
  }
}

// DVR skipping's transfer-function bounds (render_frame.h, visible_lo / visible_hi) against the
// reference's own transfer function in double: every stored value outside the bounds has alpha
// exactly 0, for plain ramps, gamma, LUTs with transparent ends, and opacity 0.
TEST(VolumeRendererTest, VisibleRangeBoundsAreConservative) {
  std::vector<ChannelParams> cases;
  ChannelParams ramp;
  ramp.window = 20000;
  ramp.level = 15000;
  cases.push_back(ramp);
  ramp.gamma = 2.5;
  cases.push_back(ramp);
  ChannelParams lut_channel;
  lut_channel.window = 50000;
  lut_channel.level = 30000;
  lut_channel.gamma = 0.7;
  std::array<volume::Rgba, kLutEntries> lut;
  for (int i = 0; i < kLutEntries; ++i) {
    lut[i] = {255, 255, 255, static_cast<uint8_t>(i >= 30 && i <= 200 ? 100 : 0)};
  }
  lut_channel.lut = lut;
  cases.push_back(lut_channel);
  ChannelParams invisible;
  invisible.opacity_scale = 0;
  cases.push_back(invisible);
  for (size_t k = 0; k < cases.size(); ++k) {
    RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kDvr);
    params.channels[0] = cases[k];
    Result<Camera> camera = Camera::Standard(StandardView::kZ, Projection::kOrthographic,
                                             Box3{{0, 0, 0}, {8, 8, 8}}, 4, 4);
    ASSERT_TRUE(camera.ok());
    const PackedFrame packed = PackRenderFrame(*camera, params, 0, true, {8, 8, 8}, {1, 1, 1});
    const OctoChannelParams& ch = packed.channels[0];
    if (cases[k].opacity_scale > 0) {
      EXPECT_LT(ch.visible_lo, ch.visible_hi) << k;
    }
    int invisible_values = 0;
    for (int v = 0; v <= 65535; ++v) {
      if (!(v <= ch.visible_lo || v >= ch.visible_hi)) continue;
      ++invisible_values;
      const double alpha = TransferFunction(cases[k], WindowedValue(cases[k], v))[3];
      ASSERT_EQ(alpha, 0.0) << "case " << k << " value " << v;
    }
    EXPECT_GT(invisible_values, 1000) << k;
  }
}

TEST(VolumeRendererTest, CancelAndInvalidParams) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto rig = MakeRig(NoiseSpec({16, 16, 16}, 1));
  ASSERT_NE(rig, nullptr);
  const Camera camera = Standard(*rig, StandardView::kZ, Projection::kOrthographic, 16, 16);
  RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kDvr);
  std::atomic<bool> cancel{true};
  Result<RenderImage> cancelled = rig->renderer->Render(camera, params, Refine(), nullptr, &cancel);
  EXPECT_EQ(cancelled.status().code(), StatusCode::kCancelled);
  params.step_voxels = 0;
  EXPECT_EQ(rig->renderer->Render(camera, params, Refine()).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(rig->renderer->Render(camera, params, FrameOptions{}).status().code(),
            StatusCode::kInvalidArgument);
  // max_passes stops early: partial image, not final.
  params.step_voxels = 1;
  FrameOptions limited = Refine();
  limited.max_passes = 1;
  FrameStats stats;
  Result<RenderImage> partial = rig->renderer->Render(camera, params, limited, &stats);
  ASSERT_TRUE(partial.ok());
  EXPECT_EQ(stats.passes, 1);
  EXPECT_FALSE(stats.final) << stats.finished_fraction << " " << stats.samples << " "
                            << stats.requests << " " << rig->device->resident_bricks();
  EXPECT_TRUE(AllFinite(*partial));
}

}  // namespace
}  // namespace octoscope::render
