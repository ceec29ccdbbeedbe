// The C++ baseline ray caster against the independent double-precision reference renderer: same
// images within float rounding, for every mode, standard and perspective views, anisotropic
// spacing, fractional steps, LUTs, gamma, clipping planes and per-channel transforms; the same
// sample counts; thread-count independence.
#include "baseline/cpu_raycaster.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "render/camera.h"
#include "render/reference_renderer.h"
#include "render/render_fixture.h"
#include "render/render_params.h"

namespace octoscope::render {
namespace {

using ::octoscope::bench::CpuRaycaster;
using ::octoscope::bench::CpuRaycastStats;

using testing::CompareImages;

// Float rounding of positions (~1e-5 voxels), values and compositing over ~100 samples stays far
// below this; a wrong sample position or formula gives errors of 1e-2 and more.
constexpr double kTolerance = 2e-4;

struct Volume {
  std::array<int64_t, 3> size;
  Vec3 spacing;
  std::vector<std::vector<uint16_t>> channels;
};

// Two channels with structure at every scale: a bright ball, a gradient and hashed noise.
Volume MakeVolume(std::array<int64_t, 3> size, Vec3 spacing) {
  Volume v{size, spacing, {}};
  v.channels.assign(2, std::vector<uint16_t>(static_cast<size_t>(size[0] * size[1] * size[2])));
  size_t i = 0;
  for (int64_t z = 0; z < size[2]; ++z) {
    for (int64_t y = 0; y < size[1]; ++y) {
      for (int64_t x = 0; x < size[0]; ++x, ++i) {
        const double dx = x - size[0] * 0.4, dy = y - size[1] * 0.55, dz = z - size[2] * 0.5;
        const double r2 = (dx * dx + dy * dy + dz * dz) / (size[0] * size[0] * 0.06);
        const uint32_t hash =
            static_cast<uint32_t>((x * 73856093) ^ (y * 19349663) ^ (z * 83492791));
        v.channels[0][i] = static_cast<uint16_t>(40000 * std::exp(-r2) + hash % 3000);
        v.channels[1][i] = static_cast<uint16_t>(200 * x + 150 * z + (hash >> 8) % 2000);
      }
    }
  }
  return v;
}

struct Pair {
  RenderImage cpu;
  RenderImage reference;
  CpuRaycastStats cpu_stats;
  RenderStats reference_stats;
};

Pair RenderBoth(const Volume& v, const Camera& camera, const RenderParams& params,
                int threads = 2) {
  Pair p;
  auto cpu = CpuRaycaster::Create(v.size, v.spacing, volume::DataType::kUint16, v.channels);
  EXPECT_TRUE(cpu.ok()) << cpu.status().ToString();
  auto reference =
      ReferenceVolume::FromStored(v.size, v.spacing, volume::DataType::kUint16, v.channels);
  EXPECT_TRUE(reference.ok()) << reference.status().ToString();
  auto image = cpu->Render(camera, params, threads, &p.cpu_stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  auto ref_image = RenderReference(*reference, camera, params, &p.reference_stats);
  EXPECT_TRUE(ref_image.ok()) << ref_image.status().ToString();
  p.cpu = std::move(*image);
  p.reference = std::move(*ref_image);
  return p;
}

RenderParams ColouredParams(RenderMode mode, double step) {
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, mode);
  params.step_voxels = step;
  params.channels[0].color = {1, 0.2, 0.1};
  params.channels[0].window = 40000;
  params.channels[0].level = 22000;
  params.channels[0].opacity_scale = 0.3;
  params.channels[1].color = {0.1, 0.8, 1};
  params.channels[1].window = 9000;
  params.channels[1].level = 6000;
  params.channels[1].opacity_scale = 0.1;
  params.background = {0.1, 0.2, 0.3, 0.5};
  return params;
}

std::vector<Camera> Views(const Volume& v, int w, int h) {
  const Box3 box = PhysicalBounds(v.size, v.spacing);
  std::vector<Camera> cameras;
  for (StandardView view : {StandardView::kZ, StandardView::kX, StandardView::kIso}) {
    cameras.push_back(*Camera::Standard(view, Projection::kOrthographic, box, w, h));
  }
  cameras.push_back(*Camera::Standard(StandardView::kIso, Projection::kPerspective, box, w, h));
  cameras.push_back(*Camera::Standard(StandardView::kY, Projection::kPerspective, box, w, h));
  return cameras;
}

TEST(CpuRaycasterTest, EveryModeAndViewMatchesTheReference) {
  const Volume v = MakeVolume({40, 32, 24}, {0.5, 0.5, 1.25});
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (double step : {1.0, 0.7, 2.5}) {
      const RenderParams params = ColouredParams(mode, step);
      int view = 0;
      for (const Camera& camera : Views(v, 40, 36)) {
        const Pair p = RenderBoth(v, camera, params);
        const auto diff = CompareImages(p.cpu, p.reference);
        EXPECT_LT(diff.max_abs, kTolerance)
            << RenderModeName(mode) << " step " << step << " view " << view << " at ("
            << diff.worst_x << ", " << diff.worst_y << ")";
        ++view;
      }
    }
  }
}

TEST(CpuRaycasterTest, ImagesAreNotTrivial) {
  // Guards the comparison above: the images hold structure, not just background.
  const Volume v = MakeVolume({40, 32, 24}, {0.5, 0.5, 1.25});
  const Box3 box = PhysicalBounds(v.size, v.spacing);
  const Camera camera = *Camera::Standard(StandardView::kZ, Projection::kOrthographic, box, 40, 32);
  const Pair p = RenderBoth(v, camera, ColouredParams(RenderMode::kDvr, 1));
  float lo = 1, hi = 0;
  for (size_t i = 0; i < p.cpu.rgba.size(); i += 4) {
    lo = std::min(lo, p.cpu.rgba[i]);
    hi = std::max(hi, p.cpu.rgba[i]);
  }
  EXPECT_GT(hi - lo, 0.3);
}

TEST(CpuRaycasterTest, LutGammaClipPlanesAndTransformsMatchTheReference) {
  const Volume v = MakeVolume({32, 28, 20}, {1, 1, 2});
  const Box3 box = PhysicalBounds(v.size, v.spacing);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    RenderParams params = ColouredParams(mode, 0.8);
    std::array<volume::Rgba, kLutEntries> lut;
    for (int i = 0; i < kLutEntries; ++i) {
      lut[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(255 - i),
                static_cast<uint8_t>((i * 7) % 256), static_cast<uint8_t>(i / 2)};
    }
    params.channels[0].lut = lut;
    params.channels[0].gamma = 0.6;
    // Chromatic-aberration-like shift and slight scale of channel 1.
    params.channels[1].transform =
        Mat4::Translation({1.3, -0.7, 0.9}) * Mat4::Scale({1.02, 1, 0.98});
    params.clip_planes = {{{1, 0.3, 0}, 24}, {{0, 0, -1}, -6}};
    for (StandardView view : {StandardView::kZ, StandardView::kIso}) {
      const Camera camera = *Camera::Standard(view, Projection::kOrthographic, box, 36, 36);
      const Pair p = RenderBoth(v, camera, params);
      const auto diff = CompareImages(p.cpu, p.reference);
      EXPECT_LT(diff.max_abs, kTolerance)
          << RenderModeName(mode) << " view " << StandardViewName(view) << " at (" << diff.worst_x
          << ", " << diff.worst_y << ")";
    }
  }
}

TEST(CpuRaycasterTest, CountsTheSameSamplesAsTheReference) {
  const Volume v = MakeVolume({24, 24, 24}, {1, 1, 1});
  const Box3 box = PhysicalBounds(v.size, v.spacing);
  const Camera camera =
      *Camera::Standard(StandardView::kIso, Projection::kOrthographic, box, 32, 32);
  RenderParams params = ColouredParams(RenderMode::kMip, 1);
  params.channels[1].enabled = false;
  const Pair p = RenderBoth(v, camera, params);
  EXPECT_EQ(p.cpu_stats.rays, 32u * 32u);
  EXPECT_EQ(p.cpu_stats.steps, p.reference_stats.steps);
  EXPECT_EQ(p.cpu_stats.samples, p.reference_stats.channel_samples[0]);
  EXPECT_EQ(p.reference_stats.channel_samples[1], 0u);
  EXPECT_GT(p.cpu_stats.samples, 32u * 32u * 5);  // Most rays cross ~20 voxels.
  EXPECT_GE(p.cpu_stats.ms, 0);
  EXPECT_EQ(p.cpu_stats.threads, 2);
}

TEST(CpuRaycasterTest, ThreadCountDoesNotChangeTheImage) {
  const Volume v = MakeVolume({24, 20, 16}, {1, 1, 1.5});
  const Box3 box = PhysicalBounds(v.size, v.spacing);
  auto cpu = CpuRaycaster::Create(v.size, v.spacing, volume::DataType::kUint16, v.channels);
  ASSERT_TRUE(cpu.ok());
  const Camera camera =
      *Camera::Standard(StandardView::kIso, Projection::kPerspective, box, 30, 25);
  const RenderParams params = ColouredParams(RenderMode::kDvr, 1);
  auto one = cpu->Render(camera, params, 1);
  auto three = cpu->Render(camera, params, 3);
  auto many = cpu->Render(camera, params, 64);  // More threads than rows: clamped.
  ASSERT_TRUE(one.ok() && three.ok() && many.ok());
  EXPECT_EQ(one->rgba, three->rgba);
  EXPECT_EQ(one->rgba, many->rgba);
}

TEST(CpuRaycasterTest, RejectsInvalidVolumesAndParams) {
  EXPECT_FALSE(CpuRaycaster::Create({0, 1, 1}, {1, 1, 1}, volume::DataType::kUint16, {{}}).ok());
  EXPECT_FALSE(CpuRaycaster::Create({2, 1, 1}, {1, 1, 1}, volume::DataType::kUint16, {{1}}).ok());
  EXPECT_FALSE(CpuRaycaster::Create({1, 1, 1}, {0, 1, 1}, volume::DataType::kUint16, {{1}}).ok());
  EXPECT_FALSE(CpuRaycaster::Create({1, 1, 1}, {1, 1, 1}, volume::DataType::kUint8, {{300}}).ok());
  EXPECT_FALSE(CpuRaycaster::Create({1, 1, 1}, {1, 1, 1}, volume::DataType::kFloat32, {{1}}).ok());
  EXPECT_FALSE(CpuRaycaster::Create({1, 1, 1}, {1, 1, 1}, volume::DataType::kUint16, {}).ok());
  auto cpu = CpuRaycaster::Create({2, 2, 2}, {1, 1, 1}, volume::DataType::kUint16,
                                  {std::vector<uint16_t>(8, 5)});
  ASSERT_TRUE(cpu.ok());
  const Camera camera =
      *Camera::Standard(StandardView::kZ, Projection::kOrthographic, cpu->bounds(), 4, 4);
  RenderParams params = DefaultRenderParams(2, volume::DataType::kUint16, RenderMode::kMip);
  EXPECT_FALSE(cpu->Render(camera, params).ok());  // Two channel params for one channel.
  params.channels.pop_back();
  params.step_voxels = 0;
  EXPECT_FALSE(cpu->Render(camera, params).ok());
}

}  // namespace
}  // namespace octoscope::render
