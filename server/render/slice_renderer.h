// SliceRenderer: axis-aligned slice views of a DeviceOctree (the paper's Fig. 1: three orthogonal
// slices beside the 3-D view), rendered by OpenCL from the same octree and with the same
// transfer functions as the 3-D renderer (render/render_params.h), at the level of detail the
// screen needs.
//
// Geometry (physical µm, render_params.h): a SliceView cuts the volume with the plane
// {p : p[axis] = position_um}. In-plane axes (those of camera.h's standard views):
//   axis z (2): image x = +x, image rows = +y;
//   axis y (1): image x = +x, image rows = +z;
//   axis x (0): image x = +y, image rows = +z.
// Pixel (px, py) has its centre at in-plane coordinates
//   u = center_u + (px + 0.5 - width / 2) * um_per_pixel,
//   v = center_v + (py + 0.5 - height / 2) * um_per_pixel;
// by default centre = the volume box's centre and um_per_pixel = the smallest value that fits the
// box's cross-section into the image (max(extent_u / width, extent_v / height)).
//
// Level of detail: footprint = um_per_pixel / (the larger spacing of the two in-plane axes), level
// = clamp(floor(log2(footprint) + lod_bias), 0, root level) (SliceLevel), one level for the whole
// slice: the finest level none of whose voxels looks larger than a pixel in the plane (the ray
// caster's rule, volume_renderer.h, for rays along the normal).
//
// Pixel value: a pixel centre outside the volume box (faces inclusive; also every pixel when the
// plane misses the box) is params.background. Inside, each ENABLED channel c (disabled ones are
// never sampled) reads the volume at transform_c * p — no contribution when that lands outside
// the box — by trilinear interpolation of the level's voxels at that position, clamped to the
// level's voxel centres ([0.5, LevelSize - 0.5] level voxels per axis; at level 0 this is
// exactly ReferenceVolume::Sample). rgb = sum over the channels of TransferFunction(
// WindowedValue(value)).rgb (LUT or colour * t; alpha and opacity_scale are not used), clamped to
// 1; alpha = 1 (the slice is opaque; the background does not show through). The compositing mode,
// clipping planes and step of RenderParams do not apply to slices.
//
// Missing bricks: as the 3-D renderer's full-frame mode (volume_renderer.h): the deepest resident
// node of the path within two levels of the wanted one, else the wanted node's average; the
// wanted node is requested and uploaded after the frame within the budget. With
// SliceOptions::converge, frames repeat until one asks for nothing (the image is then exactly the
// wanted level) or max_frames is reached (the image is still complete, partly coarser).
//
// Thread safety: NOT thread-safe; one render thread owns the renderer, its DeviceOctree and the
// device queue (like VolumeRenderer; both may share one DeviceOctree on that thread).
#ifndef OCTOSCOPE_RENDER_SLICE_RENDERER_H_
#define OCTOSCOPE_RENDER_SLICE_RENDERER_H_

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>

#include "render/camera.h"
#include "render/device.h"
#include "render/device_octree.h"
#include "render/frame_buffers.h"
#include "render/linear_algebra.h"
#include "render/program_cache.h"
#include "render/render_image.h"
#include "render/render_params.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::render {

// One slice. Invariants (checked by Render): axis in {0, 1, 2}; width, height in
// [1, kMaxImageSize]; position and centre finite; um_per_pixel finite and > 0 when set.
struct SliceView {
  int axis = 2;            // 0 = x, 1 = y, 2 = z: the plane's normal.
  double position_um = 0;  // The plane's position along the axis (physical).
  int width = 256;         // Pixels.
  int height = 256;
  // In-plane physical coordinates (u, v) of the image centre; default: the box's centre.
  std::optional<std::array<double, 2>> center_um;
  // Physical size of one (square) pixel; default: the box's cross-section fitted to the image.
  std::optional<double> um_per_pixel;
};

// The in-plane axes (image x, image rows) of a slice normal to `axis` (see the file comment).
// REQUIRES: 0 <= axis <= 2.
std::array<int, 2> SliceInPlaneAxes(int axis);

// A slice's pixel grid in physical space: pixel (px, py) has its centre at
// origin + (px + 0.5) * du + (py + 0.5) * dv.
struct SliceFrame {
  Vec3 origin;
  Vec3 du;
  Vec3 dv;
  double um_per_pixel = 1;
};
// Resolves the defaults of `view` against the volume box. REQUIRES: view valid (see SliceView).
SliceFrame ResolveSliceFrame(const SliceView& view, const Box3& bounds);

// The level of detail of a slice normal to `axis` (see the file comment). REQUIRES: um_per_pixel
// > 0, spacing > 0, axis in 0..2.
int SliceLevel(double um_per_pixel, const Vec3& spacing_um, int axis, double lod_bias,
               int root_level);

struct SliceOptions {
  // Added to the level: +1 renders at half the screen's resolution, -1 at twice it.
  double lod_bias = 0;
  // Upload budget per frame; protect_frame is set to the frame just rendered.
  UploadBudget upload;
  // Repeat frames (upload, render again) until a frame requests nothing or max_frames ran.
  bool converge = false;
  int max_frames = 16;  // >= 1; used with converge.
};

struct SliceStats {
  double ms = 0;                 // Wall time of Render (all frames, uploads included).
  int frames = 0;                // Kernel passes.
  int level = 0;                 // The level of detail sampled.
  bool converged = false;        // The last frame requested nothing (all wanted bricks used).
  uint64_t bricks_uploaded = 0;  // Over all frames.
  // Bricks not uploaded because their page was not in RAM (non-blocking reads), all frames.
  uint64_t bricks_unavailable = 0;
  uint64_t samples = 0;        // Channel reads (trilinear or averages), all frames.
  uint64_t requests = 0;       // Node requests read back, all frames.
  uint64_t last_samples = 0;   // Channel reads of the last frame.
  uint64_t last_requests = 0;  // Node requests of the last frame.
};

class SliceRenderer {
 public:
  // `context`, `programs` and `device_octree` must outlive the renderer; `spacing_um` is the
  // volume's voxel pitch (PhysicalSpacing). Builds kernels/slice.cl with `build_options`.
  static Result<std::unique_ptr<SliceRenderer>> Create(const ComputeContext* context,
                                                       ProgramCache* programs,
                                                       DeviceOctree* device_octree,
                                                       const Vec3& spacing_um,
                                                       std::string_view build_options = "");
  ~SliceRenderer();
  SliceRenderer(const SliceRenderer&) = delete;
  SliceRenderer& operator=(const SliceRenderer&) = delete;

  // The device buffers a frame of `view` with `params` uses (frame_buffers.h): exact, computed
  // without allocating anything.
  static FrameBufferSizes BufferSizes(const SliceView& view, const RenderParams& params);

  // Renders `view` (Sync, kernel, feedback, upload per frame; see the file comment). The image
  // is straight = premultiplied RGBA (alpha is 1 or the background's), row 0 = the smallest v.
  // kInvalidArgument for an invalid view, params or options. The device buffers come from
  // `buffers` (a view's, reused from frame to frame) or, when null, from the renderer's own set.
  Result<RenderImage> Render(const SliceView& view, const RenderParams& params,
                             const SliceOptions& options = {}, SliceStats* stats = nullptr,
                             FrameBuffers* buffers = nullptr);

  const Vec3& spacing() const { return spacing_; }
  // The volume box [0, size * spacing].
  Box3 bounds() const;

 private:
  struct Impl;
  SliceRenderer() = default;

  std::unique_ptr<Impl> impl_;
  DeviceOctree* device_octree_ = nullptr;
  Vec3 spacing_;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_SLICE_RENDERER_H_
