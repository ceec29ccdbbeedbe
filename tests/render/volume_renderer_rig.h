// Test rig for the VolumeRenderer tests (volume_renderer_test.cpp, render_stability_test.cpp): a
// RenderScene mirrored into a DeviceOctree with a VolumeRenderer on the shared test device, plus
// the ReferenceVolume of the same voxels, and small helpers that render with either.
//
// Thread safety: a Rig is used by one test thread.
#ifndef OCTOSCOPE_TESTS_RENDER_VOLUME_RENDERER_RIG_H_
#define OCTOSCOPE_TESTS_RENDER_VOLUME_RENDERER_RIG_H_

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "cl_test_env.h"
#include "render/device_octree.h"
#include "render/reference_renderer.h"
#include "render/volume_renderer.h"
#include "render_fixture.h"

namespace octoscope::render::testing {

// GPU (float) vs reference (double) per component; see volume_renderer_test.cpp for why.
inline constexpr double kTol = 2.0 / 255;

inline uint32_t Hash(int64_t x, int64_t y, int64_t z, int c) {
  uint32_t h = static_cast<uint32_t>(x * 73856093 ^ y * 19349663 ^ z * 83492791 ^ c * 2654435761u);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

// A scene on the device: octree + DeviceOctree + renderer, and the reference of the same voxels.
struct Rig {
  std::unique_ptr<RenderScene> scene;
  std::unique_ptr<DeviceOctree> device;
  std::unique_ptr<VolumeRenderer> renderer;
  std::optional<ReferenceVolume> reference;

  Box3 bounds() const { return reference->bounds(); }
};

// Builds the scene and the renderer (the brick buffer defaults to 16 MiB instead of 512);
// nullptr (with a test failure recorded) when anything fails.
inline std::unique_ptr<Rig> MakeRig(const SceneSpec& spec, DeviceOctreeOptions options = {}) {
  auto rig = std::make_unique<Rig>();
  Result<std::unique_ptr<RenderScene>> scene = MakeRenderScene(spec);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  if (!scene.ok()) return nullptr;
  rig->scene = std::move(*scene);
  Result<ReferenceVolume> ref = rig->scene->Reference();
  EXPECT_TRUE(ref.ok()) << ref.status().ToString();
  if (!ref.ok()) return nullptr;
  rig->reference = std::move(*ref);
  const ClTestEnv& env = SharedClTestEnv();
  if (options.brick_buffer_bytes == (uint64_t{512} << 20)) options.brick_buffer_bytes = 16 << 20;
  Result<std::unique_ptr<DeviceOctree>> device =
      DeviceOctree::Create(env.context, rig->scene->tree.get(), options);
  EXPECT_TRUE(device.ok()) << device.status().ToString();
  if (!device.ok()) return nullptr;
  rig->device = std::move(*device);
  Result<std::unique_ptr<VolumeRenderer>> renderer = VolumeRenderer::Create(
      env.context, env.programs, rig->device.get(), spec.spacing, kTestBuildOptions);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  if (!renderer.ok()) return nullptr;
  rig->renderer = std::move(*renderer);
  return rig;
}

inline FrameOptions Refine() {
  FrameOptions o;
  o.mode = FrameMode::kRefine;
  o.upload.max_ms = 1e9;
  return o;
}

inline Camera Standard(const Rig& rig, StandardView view, Projection projection, int w, int h) {
  Result<Camera> c = Camera::Standard(view, projection, rig.bounds(), w, h);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return *c;
}

inline RenderImage Gpu(Rig& rig, const Camera& camera, const RenderParams& params,
                       const FrameOptions& options, FrameStats* stats = nullptr) {
  Result<RenderImage> image = rig.renderer->Render(camera, params, options, stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  return image.ok() ? *image : RenderImage{};
}

inline RenderImage Reference(const Rig& rig, const Camera& camera, const RenderParams& params,
                             RenderStats* stats = nullptr) {
  Result<RenderImage> image = RenderReference(*rig.reference, camera, params, stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  return image.ok() ? *image : RenderImage{};
}

inline bool AllFinite(const RenderImage& image) {
  return std::all_of(image.rgba.begin(), image.rgba.end(),
                     [](float v) { return std::isfinite(v) && v >= 0 && v <= 1; });
}

inline std::string Describe(const ImageDiff& d) {
  return "max_abs " + std::to_string(d.max_abs) + " at (" + std::to_string(d.worst_x) + ", " +
         std::to_string(d.worst_y) + "), psnr " + std::to_string(d.psnr);
}

}  // namespace octoscope::render::testing

#endif  // OCTOSCOPE_TESTS_RENDER_VOLUME_RENDERER_RIG_H_
