// SliceRenderer (kernels/slice.cl) against independent CPU computations: every pixel of a slice
// rendered from the octree on the device is compared with the transfer functions of
// render_params.h applied to ReferenceVolume::Sample at the pixel centre, whose position the test
// computes itself from the slice definition (in-plane axes, pixel centres) — never from the
// renderer's own helpers, and never comparing the device with itself.
#include "render/slice_renderer.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <ostream>
#include <vector>

#include "cl_test_env.h"
#include "render/device_octree.h"
#include "render_fixture.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::kTestBuildOptions;
using ::octoscope::render::testing::MakeRenderScene;
using ::octoscope::render::testing::RenderScene;
using ::octoscope::render::testing::SceneSpec;
using ::octoscope::render::testing::SharedClTestEnv;

uint16_t Hash(int c, int64_t x, int64_t y, int64_t z) {
  uint32_t h = static_cast<uint32_t>(c * 7919 + x * 104729 + y * 1299709 + z * 15485863);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return static_cast<uint16_t>(h);
}

// A slice renderer over a scene: the octree mirrored on the device and the same voxels as a
// ReferenceVolume.
struct Slicer {
  std::unique_ptr<RenderScene> scene;
  std::unique_ptr<ReferenceVolume> reference;
  std::unique_ptr<DeviceOctree> device;
  std::unique_ptr<SliceRenderer> renderer;
};

std::unique_ptr<Slicer> MakeSlicer(const SceneSpec& spec, DeviceOctreeOptions options = {},
                                   bool insert = true) {
  auto s = std::make_unique<Slicer>();
  auto scene = MakeRenderScene(spec, insert);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  if (!scene.ok()) return nullptr;
  s->scene = std::move(*scene);
  auto reference = s->scene->Reference();
  EXPECT_TRUE(reference.ok()) << reference.status().ToString();
  if (!reference.ok()) return nullptr;
  s->reference = std::make_unique<ReferenceVolume>(std::move(*reference));
  options.brick_buffer_bytes = std::min<uint64_t>(options.brick_buffer_bytes, uint64_t{64} << 20);
  auto device = DeviceOctree::Create(SharedClTestEnv().context, s->scene->tree.get(), options);
  EXPECT_TRUE(device.ok()) << device.status().ToString();
  if (!device.ok()) return nullptr;
  s->device = std::move(*device);
  auto renderer = SliceRenderer::Create(SharedClTestEnv().context, SharedClTestEnv().programs,
                                        s->device.get(), spec.spacing, kTestBuildOptions);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  if (!renderer.ok()) return nullptr;
  s->renderer = std::move(*renderer);
  return s;
}

// The CPU oracle: the slice's definition evaluated with ReferenceVolume::Sample (level 0).
RenderImage ExpectedSlice(const ReferenceVolume& ref, const RenderParams& params, int axis,
                          double position, int width, int height, double um_per_pixel,
                          std::array<double, 2> centre) {
  // In-plane axes (image x, image rows) written out from the specification.
  static constexpr int kU[3] = {1, 0, 0};
  static constexpr int kV[3] = {2, 2, 1};
  const Box3 box = ref.bounds();
  RenderImage img;
  img.width = width;
  img.height = height;
  img.rgba.resize(static_cast<size_t>(width) * height * 4);
  for (int py = 0; py < height; ++py) {
    for (int px = 0; px < width; ++px) {
      Vec3 p;
      p[axis] = position;
      p[kU[axis]] = centre[0] + (px + 0.5 - width / 2.0) * um_per_pixel;
      p[kV[axis]] = centre[1] + (py + 0.5 - height / 2.0) * um_per_pixel;
      auto inside = [&](const Vec3& q) {
        for (int a = 0; a < 3; ++a) {
          if (q[a] < box.lo[a] || q[a] > box.hi[a]) return false;
        }
        return true;
      };
      float* out = img.rgba.data() + (static_cast<size_t>(py) * width + px) * 4;
      if (!inside(p)) {
        // The background is straight RGBA; images are premultiplied.
        const double a = params.background[3];
        for (int k = 0; k < 3; ++k) out[k] = static_cast<float>(params.background[k] * a);
        out[3] = static_cast<float>(a);
        continue;
      }
      std::array<double, 3> rgb{0, 0, 0};
      for (int c = 0; c < ref.channel_count(); ++c) {
        const ChannelParams& ch = params.channels[c];
        if (!ch.enabled) continue;
        const Vec3 q = ch.transform.TransformPoint(p);
        if (!inside(q)) continue;
        const auto tf = TransferFunction(ch, WindowedValue(ch, ref.Sample(c, q)));
        for (int k = 0; k < 3; ++k) rgb[k] += tf[k];
      }
      for (int k = 0; k < 3; ++k) out[k] = static_cast<float>(std::min(rgb[k], 1.0));
      out[3] = 1;
    }
  }
  return img;
}

// Three channels: a partial window, a gamma, a LUT; colours that sum past 1.
RenderParams ThreeChannelParams() {
  RenderParams p = DefaultRenderParams(3, volume::DataType::kUint16, RenderMode::kMip);
  p.channels[0].color = {1, 0.25, 0};
  p.channels[0].window = 40000;
  p.channels[0].level = 30000;
  p.channels[1].color = {0.5, 1, 0.3};
  p.channels[1].gamma = 0.7;
  std::array<volume::Rgba, kLutEntries> lut;
  for (int i = 0; i < kLutEntries; ++i) {
    lut[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(255 - i),
              static_cast<uint8_t>((i * 7) % 256), 255};
  }
  p.channels[2].lut = lut;
  p.background = {0.1, 0.2, 0.3, 0.4};
  return p;
}

bool AllFinite(const RenderImage& img) {
  return std::all_of(img.rgba.begin(), img.rgba.end(),
                     [](float v) { return std::isfinite(v) && v >= 0 && v <= 1; });
}

SliceOptions Converge() {
  SliceOptions o;
  o.converge = true;
  o.max_frames = 8;
  return o;
}

struct Level0Case {
  const char* name;
  std::array<int64_t, 3> size;
  Vec3 spacing;
  int axis;
  double position;  // Physical.
};

std::ostream& operator<<(std::ostream& os, const Level0Case& k) { return os << k.name; }

class SliceLevel0Test : public ::testing::TestWithParam<Level0Case> {};

// At level 0 with one pixel per finest voxel spacing, every pixel equals the reference's
// transfer functions of ReferenceVolume::Sample at the pixel centre.
TEST_P(SliceLevel0Test, MatchesReferenceSample) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const Level0Case& k = GetParam();
  SceneSpec spec;
  spec.size = k.size;
  spec.spacing = k.spacing;
  spec.brick = {8, 8, 8};
  spec.channels = 3;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  auto s = MakeSlicer(spec);
  ASSERT_NE(s, nullptr);
  const Box3 box = s->reference->bounds();
  const int u = k.axis == 0 ? 1 : 0;
  const int v = k.axis == 2 ? 1 : 2;
  const double upp = std::min({k.spacing.x, k.spacing.y, k.spacing.z});
  SliceView view;
  view.axis = k.axis;
  view.position_um = k.position;
  // The cross-section plus a two-pixel margin of background on every side.
  view.width = static_cast<int>(std::lround(box.hi[u] / upp)) + 4;
  view.height = static_cast<int>(std::lround(box.hi[v] / upp)) + 4;
  view.um_per_pixel = upp;
  const RenderParams params = ThreeChannelParams();
  SliceStats stats;
  auto img = s->renderer->Render(view, params, Converge(), &stats);
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  EXPECT_EQ(stats.level, 0);
  EXPECT_TRUE(stats.converged);
  EXPECT_EQ(stats.last_requests, 0u);
  const RenderImage expected = ExpectedSlice(*s->reference, params, k.axis, k.position, view.width,
                                             view.height, upp, {box.Center()[u], box.Center()[v]});
  const auto diff = testing::CompareImages(*img, expected);
  EXPECT_LE(diff.max_abs, 1e-3) << "at " << diff.worst_x << "," << diff.worst_y;
  // The margin is background, the cross-section opaque.
  EXPECT_FLOAT_EQ(img->Pixel(0, 0)[3], 0.4f);
  EXPECT_FLOAT_EQ(img->Pixel(view.width / 2, view.height / 2)[3], 1.0f);
  // Inside pixels read 3 channels each.
  const uint64_t inside = static_cast<uint64_t>(view.width - 4) * (view.height - 4);
  EXPECT_EQ(stats.last_samples, 3 * inside);
}

INSTANTIATE_TEST_SUITE_P(
    Slices, SliceLevel0Test,
    ::testing::Values(Level0Case{"ZBetweenVoxelCentres", {24, 20, 12}, {1, 1, 1}, 2, 5.3},
                      Level0Case{"ZOnBrickFace", {24, 20, 12}, {1, 1, 1}, 2, 8.0},
                      Level0Case{"ZOnVolumeFace", {24, 20, 12}, {1, 1, 1}, 2, 12.0},
                      Level0Case{"YBetweenVoxelCentres", {24, 20, 12}, {1, 1, 1}, 1, 9.75},
                      Level0Case{"XOnVoxelCentre", {24, 20, 12}, {1, 1, 1}, 0, 13.5},
                      Level0Case{"ZAnisotropic", {20, 16, 10}, {0.5, 0.75, 2}, 2, 7.1},
                      Level0Case{"YAnisotropic", {20, 16, 10}, {0.5, 0.75, 2}, 1, 5.9},
                      Level0Case{"XAnisotropicBrickFace", {20, 16, 10}, {0.5, 0.75, 2}, 0, 4.0}),
    [](const ::testing::TestParamInfo<Level0Case>& info) { return info.param.name; });

// A zoomed-out view samples a coarser level: fewer bricks and requests, bounded error on smooth
// data.
TEST(SliceRendererTest, ZoomedOutUsesCoarserLevel) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {64, 64, 32};
  spec.brick = {8, 8, 8};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) {
    return static_cast<uint16_t>(32768 + 20000 * std::sin(x * 0.09) * std::cos(y * 0.07) +
                                 5000 * std::sin(z * 0.1));
  };
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  SliceView fine;
  fine.axis = 2;
  fine.position_um = 15.3;
  fine.width = fine.height = 64;
  fine.um_per_pixel = 1;
  SliceView coarse = fine;
  coarse.width = coarse.height = 16;
  coarse.um_per_pixel = 4;

  auto a = MakeSlicer(spec);
  ASSERT_NE(a, nullptr);
  SliceStats fine_stats;
  auto fine_img = a->renderer->Render(fine, params, Converge(), &fine_stats);
  ASSERT_TRUE(fine_img.ok()) << fine_img.status().ToString();
  auto b = MakeSlicer(spec);
  ASSERT_NE(b, nullptr);
  SliceStats coarse_stats;
  auto coarse_img = b->renderer->Render(coarse, params, Converge(), &coarse_stats);
  ASSERT_TRUE(coarse_img.ok()) << coarse_img.status().ToString();

  EXPECT_EQ(fine_stats.level, 0);
  EXPECT_EQ(coarse_stats.level, 2);
  EXPECT_TRUE(fine_stats.converged);
  EXPECT_TRUE(coarse_stats.converged);
  EXPECT_LT(coarse_stats.bricks_uploaded, fine_stats.bricks_uploaded);
  EXPECT_LT(coarse_stats.requests, fine_stats.requests);
  // Level 0: exact; level 2: the smooth field's averages, close to the full-resolution values.
  const RenderImage fine_ref = ExpectedSlice(*a->reference, params, 2, 15.3, 64, 64, 1, {32, 32});
  EXPECT_LE(testing::CompareImages(*fine_img, fine_ref).max_abs, 1e-3);
  const RenderImage coarse_ref = ExpectedSlice(*b->reference, params, 2, 15.3, 16, 16, 4, {32, 32});
  const auto diff = testing::CompareImages(*coarse_img, coarse_ref);
  EXPECT_LE(diff.max_abs, 0.05) << "at " << diff.worst_x << "," << diff.worst_y;
  EXPECT_GT(diff.max_abs, 1e-4);  // Really a different level.
  // lod_bias -2 brings the zoomed-out view back to level 0.
  SliceOptions biased = Converge();
  biased.lod_bias = -2;
  SliceStats biased_stats;
  auto biased_img = b->renderer->Render(coarse, params, biased, &biased_stats);
  ASSERT_TRUE(biased_img.ok());
  EXPECT_EQ(biased_stats.level, 0);
  EXPECT_LE(testing::CompareImages(*biased_img, coarse_ref).max_abs, 1e-3);
}

// Anisotropic voxels (1 x 1 x 4 µm) at 2 µm per pixel: a z slice shows x and y, so it reads
// level 1; an x slice shows y and z, and level 1's 8 µm z would be coarser than its pixels, so it
// reads level 0 and equals the full-resolution reference (the finest spacing alone would have
// taken level 1 for both).
TEST(SliceRendererTest, AnisotropicSlicesTakeTheLevelTheirPlaneShows) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {32, 32, 16};
  spec.spacing = {1, 1, 4};
  spec.brick = {8, 8, 8};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) {
    return static_cast<uint16_t>((x * 7919 + y * 104729 + z * 1299709) % 60000);
  };
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  SliceView side;
  side.axis = 0;
  side.position_um = 13.3;
  side.width = 16;   // y: 32 µm.
  side.height = 32;  // z: 64 µm.
  side.um_per_pixel = 2;
  SliceView top = side;
  top.axis = 2;
  top.position_um = 29.0;
  top.width = top.height = 16;
  auto rig = MakeSlicer(spec);
  ASSERT_NE(rig, nullptr);
  SliceStats side_stats;
  auto side_img = rig->renderer->Render(side, params, Converge(), &side_stats);
  ASSERT_TRUE(side_img.ok()) << side_img.status().ToString();
  SliceStats top_stats;
  auto top_img = rig->renderer->Render(top, params, Converge(), &top_stats);
  ASSERT_TRUE(top_img.ok()) << top_img.status().ToString();
  EXPECT_EQ(side_stats.level, 0);
  EXPECT_EQ(top_stats.level, 1);
  const RenderImage side_ref = ExpectedSlice(*rig->reference, params, 0, 13.3, 16, 32, 2, {16, 32});
  EXPECT_LE(testing::CompareImages(*side_img, side_ref).max_abs, 1e-3);
}

// SliceLevel's formula, independently of the renderer: the footprint in the larger in-plane
// spacing (the plane of axis a shows the other two axes).
TEST(SliceRendererTest, LevelFormula) {
  EXPECT_EQ(SliceLevel(1, {1, 1, 1}, 2, 0, 5), 0);
  EXPECT_EQ(SliceLevel(1.99, {1, 1, 1}, 2, 0, 5), 0);
  EXPECT_EQ(SliceLevel(2, {1, 1, 1}, 2, 0, 5), 1);
  EXPECT_EQ(SliceLevel(8, {1, 1, 1}, 0, 0.5, 5), 3);  // floor(3.5).
  EXPECT_EQ(SliceLevel(1000, {1, 1, 1}, 1, 0, 4), 4);
  EXPECT_EQ(SliceLevel(0.01, {1, 1, 1}, 2, 0, 4), 0);
  EXPECT_EQ(SliceLevel(4, {1, 1, 1}, 2, -1, 4), 1);
  // Anisotropic voxels {2, 1, 4}: z slices show x (2) and y (1), x slices y (1) and z (4), y slices
  // x (2) and z (4). The finest spacing (1) alone would give level 3 in every plane.
  EXPECT_EQ(SliceLevel(8, {2, 1, 4}, 2, 0, 5), 2);
  EXPECT_EQ(SliceLevel(8, {2, 1, 4}, 0, 0, 5), 1);
  EXPECT_EQ(SliceLevel(8, {2, 1, 4}, 1, 0, 5), 1);
  EXPECT_EQ(SliceLevel(7.99, {2, 1, 4}, 2, 0, 5), 1);
  // The normal's spacing does not count: z slices of {1, 1, 0.25} at 1 µm per pixel stay at
  // level 0 (the finest spacing would give level 2).
  EXPECT_EQ(SliceLevel(1, {1, 1, 0.25}, 2, 0, 5), 0);
}

// A disabled channel is never sampled and leaves the other channels' colours unchanged; a
// channel transform shifts that channel's image.
TEST(SliceRendererTest, DisabledChannelAndTransform) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {24, 24, 8};
  spec.brick = {8, 8, 8};
  spec.channels = 3;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  auto s = MakeSlicer(spec);
  ASSERT_NE(s, nullptr);
  SliceView view;
  view.axis = 2;
  view.position_um = 3.5;
  view.width = view.height = 24;
  view.um_per_pixel = 1;
  RenderParams all = ThreeChannelParams();
  RenderParams disabled = all;
  disabled.channels[1].enabled = false;
  RenderParams black = all;  // Channel 1 sampled but adds nothing.
  black.channels[1].color = {0, 0, 0};
  SliceStats all_stats, disabled_stats, black_stats;
  auto all_img = s->renderer->Render(view, all, Converge(), &all_stats);
  auto disabled_img = s->renderer->Render(view, disabled, Converge(), &disabled_stats);
  auto black_img = s->renderer->Render(view, black, Converge(), &black_stats);
  ASSERT_TRUE(all_img.ok() && disabled_img.ok() && black_img.ok());
  EXPECT_EQ(all_stats.last_samples, 3u * 24 * 24);
  EXPECT_EQ(disabled_stats.last_samples, 2u * 24 * 24);
  EXPECT_EQ(black_img->rgba, disabled_img->rgba);
  EXPECT_GT(testing::CompareImages(*all_img, *disabled_img).max_abs, 0.01);
  EXPECT_LE(testing::CompareImages(
                *disabled_img, ExpectedSlice(*s->reference, disabled, 2, 3.5, 24, 24, 1, {12, 12}))
                .max_abs,
            1e-3);

  // Channel 0 alone, read 3 µm further along +x: its right-hand 3 columns get nothing.
  RenderParams one = ThreeChannelParams();
  one.channels[1].enabled = false;
  one.channels[2].enabled = false;
  RenderParams shifted = one;
  shifted.channels[0].transform = Mat4::Translation({3, 0, 0});
  SliceStats shifted_stats;
  auto one_img = s->renderer->Render(view, one, Converge());
  auto shifted_img = s->renderer->Render(view, shifted, Converge(), &shifted_stats);
  ASSERT_TRUE(one_img.ok() && shifted_img.ok());
  EXPECT_EQ(shifted_stats.last_samples, 21u * 24);
  EXPECT_LE(testing::CompareImages(
                *shifted_img, ExpectedSlice(*s->reference, shifted, 2, 3.5, 24, 24, 1, {12, 12}))
                .max_abs,
            1e-3);
  for (int y = 0; y < 24; ++y) {
    for (int x = 0; x < 21; ++x) {
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(shifted_img->Pixel(x, y)[k], one_img->Pixel(x + 3, y)[k], 1e-4);
      }
    }
    EXPECT_EQ(shifted_img->Pixel(22, y)[0], 0.0f);
    EXPECT_EQ(shifted_img->Pixel(22, y)[3], 1.0f);
  }
}

// Nothing resident: the first frame shows averages (complete, finite) and asks for bricks;
// repeated frames converge to the level-0 result.
TEST(SliceRendererTest, ConvergesFromNothingResident) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {32, 32, 32};
  spec.brick = {8, 8, 8};
  spec.channels = 2;
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  auto s = MakeSlicer(spec);
  ASSERT_NE(s, nullptr);
  SliceView view;
  view.axis = 1;
  view.position_um = 20.2;
  view.width = view.height = 32;
  view.um_per_pixel = 1;
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kMip);
  params.channels[0].color = {1, 0, 1};
  params.channels[1].color = {0, 1, 0};
  const RenderImage expected = ExpectedSlice(*s->reference, params, 1, 20.2, 32, 32, 1, {16, 16});

  SliceOptions once;  // One frame, then uploads for the next.
  SliceStats first;
  auto first_img = s->renderer->Render(view, params, once, &first);
  ASSERT_TRUE(first_img.ok()) << first_img.status().ToString();
  EXPECT_EQ(first.frames, 1);
  EXPECT_FALSE(first.converged);
  EXPECT_GT(first.requests, 0u);
  EXPECT_GT(first.bricks_uploaded, 0u);
  EXPECT_TRUE(AllFinite(*first_img));
  EXPECT_GT(testing::CompareImages(*first_img, expected).max_abs, 0.05);  // Averages, not data.
  for (int i = 0; i < 32 * 32; ++i) EXPECT_EQ(first_img->rgba[4 * i + 3], 1.0f);

  SliceStats rest;
  auto img = s->renderer->Render(view, params, Converge(), &rest);
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  EXPECT_TRUE(rest.converged);
  EXPECT_LE(rest.frames, 8);
  EXPECT_LE(testing::CompareImages(*img, expected).max_abs, 1e-3);
}

// The slice needs more bricks than the buffer holds: every frame renders what it can, the image
// stays complete and finite, and max_frames bounds the work.
TEST(SliceRendererTest, WorkingSetLargerThanBrickBuffer) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {64, 64, 16};
  spec.brick = {8, 8, 8};
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  DeviceOctreeOptions options;
  options.brick_buffer_bytes = 10 * 10 * 10 * 2 * uint64_t{kMinBrickSlots};  // 8 slots.
  auto s = MakeSlicer(spec, options);
  ASSERT_NE(s, nullptr);
  ASSERT_EQ(s->device->slot_count(), kMinBrickSlots);
  SliceView view;  // 64 level-0 bricks in the plane.
  view.axis = 2;
  view.position_um = 4.5;
  view.width = view.height = 64;
  view.um_per_pixel = 1;
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  SliceOptions o = Converge();
  o.max_frames = 4;
  SliceStats stats;
  auto img = s->renderer->Render(view, params, o, &stats);
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  EXPECT_FALSE(stats.converged);
  EXPECT_EQ(stats.frames, 4);
  EXPECT_GT(stats.last_requests, 0u);
  EXPECT_TRUE(AllFinite(*img));
  for (int i = 0; i < 64 * 64; ++i) EXPECT_EQ(img->rgba[4 * i + 3], 1.0f);
  EXPECT_LE(s->device->resident_bricks(), uint64_t{kMinBrickSlots});
}

// The octree is filled after the DeviceOctree was created (construction in progress): each
// render syncs first and shows the data inserted so far.
TEST(SliceRendererTest, SeesDataInsertedAfterCreation) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {16, 16, 16};
  spec.brick = {8, 8, 8};
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  auto s = MakeSlicer(spec, {}, /*insert=*/false);
  ASSERT_NE(s, nullptr);
  SliceView view;
  view.axis = 0;
  view.position_um = 6.5;
  view.width = view.height = 16;
  view.um_per_pixel = 1;
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  auto empty = s->renderer->Render(view, params, Converge());
  ASSERT_TRUE(empty.ok()) << empty.status().ToString();
  EXPECT_TRUE(AllFinite(*empty));
  ASSERT_TRUE(s->scene->InsertPlanes(0, 16).ok());
  auto full = s->renderer->Render(view, params, Converge());
  ASSERT_TRUE(full.ok()) << full.status().ToString();
  EXPECT_LE(
      testing::CompareImages(*full, ExpectedSlice(*s->reference, params, 0, 6.5, 16, 16, 1, {8, 8}))
          .max_abs,
      1e-3);
}

// Default view: centred, the cross-section fitted; a plane outside the box is all background.
TEST(SliceRendererTest, DefaultsAndPlaneOutsideVolume) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {16, 8, 8};
  spec.brick = {8, 8, 8};
  spec.value = [](int c, int64_t x, int64_t y, int64_t z) { return Hash(c, x, y, z); };
  auto s = MakeSlicer(spec);
  ASSERT_NE(s, nullptr);
  RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  params.background = {0.5, 0.25, 0, 0};
  SliceView view;
  view.axis = 2;
  view.position_um = 2.5;
  view.width = 32;
  view.height = 32;  // 16 x 8 µm fitted: 0.5 µm per pixel, rows 8..23 inside.
  const SliceFrame frame = ResolveSliceFrame(view, s->reference->bounds());
  EXPECT_DOUBLE_EQ(frame.um_per_pixel, 0.5);
  auto img = s->renderer->Render(view, params, Converge());
  ASSERT_TRUE(img.ok());
  // 0.5 µm per pixel with 1 µm voxels is still level 0 (footprint 0.5).
  EXPECT_LE(testing::CompareImages(
                *img, ExpectedSlice(*s->reference, params, 2, 2.5, 32, 32, 0.5, {8, 4}))
                .max_abs,
            1e-3);
  EXPECT_EQ(img->Pixel(5, 7)[3], 0.0f);
  EXPECT_EQ(img->Pixel(5, 8)[3], 1.0f);
  view.position_um = 8.01;  // Beyond the box (z extent 8).
  SliceStats stats;
  auto outside = s->renderer->Render(view, params, {}, &stats);
  ASSERT_TRUE(outside.ok());
  EXPECT_EQ(stats.last_samples, 0u);
  // The background (straight RGBA, alpha 0 here) appears premultiplied: transparent black.
  for (int i = 0; i < 32 * 32; ++i) {
    EXPECT_EQ(outside->rgba[4 * i], 0.0f);
    EXPECT_EQ(outside->rgba[4 * i + 3], 0.0f);
  }
  params.background = {0.5, 0.25, 0, 0.5};
  outside = s->renderer->Render(view, params, {}, &stats);
  ASSERT_TRUE(outside.ok());
  for (int i = 0; i < 32 * 32; ++i) {
    EXPECT_EQ(outside->rgba[4 * i], 0.25f);
    EXPECT_EQ(outside->rgba[4 * i + 1], 0.125f);
    EXPECT_EQ(outside->rgba[4 * i + 3], 0.5f);
  }
}

TEST(SliceRendererTest, RejectsInvalidInput) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec;
  spec.size = {8, 8, 8};
  spec.brick = {8, 8, 8};
  auto s = MakeSlicer(spec);
  ASSERT_NE(s, nullptr);
  const RenderParams params = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip);
  SliceView view;
  view.axis = 3;
  EXPECT_EQ(s->renderer->Render(view, params).status().code(), StatusCode::kInvalidArgument);
  view.axis = 2;
  view.width = 0;
  EXPECT_EQ(s->renderer->Render(view, params).status().code(), StatusCode::kInvalidArgument);
  view.width = 8;
  view.um_per_pixel = -1;
  EXPECT_EQ(s->renderer->Render(view, params).status().code(), StatusCode::kInvalidArgument);
  view.um_per_pixel = std::nullopt;
  const RenderParams two = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kMip);
  EXPECT_EQ(s->renderer->Render(view, two).status().code(), StatusCode::kInvalidArgument);
  SliceOptions o;
  o.max_frames = 0;
  EXPECT_EQ(s->renderer->Render(view, params, o).status().code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(s->renderer->Render(view, params).ok());
}

}  // namespace
}  // namespace octoscope::render
