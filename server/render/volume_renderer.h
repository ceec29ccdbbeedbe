// VolumeRenderer: OpenCL ray casting of a DeviceOctree (paper, "Basic Ray-Casting", "Full-Frame
// Ray-Casting", "Refinement Ray-Casting"), with the definitions of render/render_params.h and
// render/camera.h — the images agree with the CPU reference renderer (reference_renderer.h) up to
// float precision and the level of detail used.
//
// Per sample (kernels/raycast.cl): the ray is clipped to the volume box and the clipping planes
// exactly as ClipRayToVolume does, sampled at the same segment midpoints at level 0 (entry +
// (i + 0.5) dt, never accumulated; coarser levels: see "Sampling distance"), and each ENABLED
// channel is read at its transformed position. The level of detail is chosen PER SAMPLE: the pixel
// footprint at the sample's distance (constant for orthographic cameras) in level-0 voxels of the
// largest spacing the screen shows along the ray (each axis's spacing times the sine of its angle
// with the ray, at least the finest spacing: the finest spacing itself with isotropic voxels),
// level = clamp(floor(log2(footprint) + lod_bias), 0, root level), so the screen's resolution
// decides, nothing finer is fetched, and no voxel axis is shown coarser than a pixel. Empty space:
// a ray skips the coarsest node around it whose subtree's per-channel value range (in the node
// buffer) maps to zero opacity in every channel (DVR) or cannot raise any channel's running maximum
// (MIP; lower the minimum for MinIP), from its box shrunk by half a voxel of the node's level to
// its exit; inert cells of resident bricks (cell ranges); and a sample in a brickless leaf node
// (homogeneous or never written) whose averages cannot contribute skips to the leaf's exit. With
// channel transforms each channel is tested in its own space (nodes per channel, cells per 8- or
// 4-sample step). Images are identical with skipping off once the bricks are resident
// (docs/rendering.md, "Empty-space skipping"); FrameStats::samples_skipped counts the jumps.
// Programs are specialised per frame's channel variant (enabled channels, transforms) at build time
// and cached.
//
// Modes:
//  * Full frame: a sample whose wanted node (the level the screen needs) is not resident uses the
//    deepest resident ancestor within two levels, else the wanted node's average, and requests
//    the node (the upload manager adds its ancestors). One pass per frame; the requests are
//    uploaded within the frame's budget after the image is read, for the next frame.
//  * Refinement: the ray state (next sample index, accumulated colour / per-channel extremum)
//    is kept on the device between passes; a ray pauses at the first sample whose wanted brick
//    is missing (DVR and MIP alike) and resumes there in the next pass, after the upload. Passes
//    run only the 8x8 tiles that still have unfinished rays: a sweep runs a tile list (the first
//    one all tiles) in slices (FrameOptions::pass_target_ms; one slice without a target), each
//    pass appending on the device the tiles it left unfinished to the next sweep's list.
//    Each pass reports the fraction of finished rays. Because only the bricks of the ray fronts
//    are needed in one pass, working sets larger than the brick buffer finish too (a pass that
//    advances no ray with everything requested resident is an internal error, never a hang).
//
// Sampling distance: a sample at level L stands for step * 2^L level-0 voxels (the level's voxel
// size; a finer step would re-read the same interpolated data), its DVR opacity corrected by its
// actual physical length. Orthographic rays have one level, hence one step. Perspective rays are
// split into bands of constant level (boundaries where the footprint reaches a power of two) and
// each band is sampled at band_entry + (i + 0.5) * step_band, its last segment shortened to the
// band's end. At level 0 this is exactly the fixed-step sampling of the reference.
//
// Brick-buffer pressure (full frames): when a frame's requests could not be uploaded because every
// slot holds a brick the frame itself sampled (UploadStats.deferred with no time or count limit
// reached), the next full frames use an internal extra lod bias of +1 (coarser: the working set
// shrinks ~8x), raised again while the pressure lasts (at most the root level). It is lowered by
// one when a frame requested nothing and used at most 1/9 of the slots (the finer level needs
// at most 8x as many bricks plus these as ancestors): the gap is the hysteresis. Reported as
// FrameStats::lod_bias_used. The pressure bias is kept per FrameOptions::view (several views
// sharing one renderer do not coarsen each other).
//
// Frame-time target (full frames, FrameOptions::target_frame_ms): the cost of a frame falls about
// by half per level of bias (samples per ray follow the level's voxel size; the pixels stay), so
// after each frame the view's time bias moves by 0.75 * log2(kernel ms / target) when that is
// above 0.25 (a dead band against timing noise) or below -1 (finer only with room for a whole
// level, so a cost that jumps when every ray changes level at once cannot make the bias
// oscillate around the target), clamped to [0, root level]. The
// fractional bias changes the level only where the footprint crosses the shifted threshold, so
// quality degrades smoothly across the image. Interaction stays at the target; refinement (which
// ignores both adaptive biases) delivers the full detail when the user stops.
//
// Thread safety: NOT thread-safe; one render thread owns the renderer, its DeviceOctree and the
// device queue (render_service.h). A Refinement belongs to the renderer that started it.
#ifndef OCTOSCOPE_RENDER_VOLUME_RENDERER_H_
#define OCTOSCOPE_RENDER_VOLUME_RENDERER_H_

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <string_view>
#include <vector>

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

enum class FrameMode { kFullFrame, kRefine };

struct FrameOptions {
  FrameMode mode = FrameMode::kFullFrame;
  // Added to the per-sample level: +1 renders at half the screen's resolution, -1 at twice it.
  double lod_bias = 0;
  // Per frame (full frame) or per pass (refinement).
  UploadBudget upload;
  // Refinement: stop after this many passes (stats.final stays false); 0 = until every ray is
  // finished.
  int max_passes = 0;
  // Empty-space skipping (see the file comment). Never changes the image; off only for tests and
  // benchmarks.
  bool skip_empty_space = true;
  // Which view this frame belongs to (e.g. the render service's view id): the adaptive biases
  // of full frames (brick-buffer pressure, frame-time target) are tracked per view.
  uint64_t view = 0;
  // Refinement: a kernel-time target per pass in ms (0 = every pass runs every tile with
  // unfinished rays). Passes then run slices of that tile list (as many tiles as the renderer's
  // measured refinement speed allows, at least one row of tiles), slice after slice (a slice runs
  // again while its passes upload bricks and leave rays unfinished): a refinement of a huge
  // image (a 4K screenshot) advances in short passes, so the render service can run other views'
  // frames between them. The image is the same.
  double pass_target_ms = 0;
  // Full frames: a kernel-time target in ms (0 = none). While frames take longer, the view's
  // frames get coarser (an extra fractional lod bias, see the file comment); when they are
  // much faster, finer again, down to the caller's lod_bias.
  double target_frame_ms = 0;
  // The level of detail measures footprints in the largest spacing the screen shows along each
  // ray, so no voxel axis looks coarser than a pixel (see the file comment). false: in the finest
  // spacing, as if the voxels were isotropic: with anisotropic voxels seen from the side, the
  // coarse axis then shows up to their ratio coarser, at a fraction of the cost (the server's
  // interactive frames, which trade detail for time; their final frames keep the default).
  bool lod_view_spacing = true;
};

struct FrameStats {
  double ms_total = 0;
  double ms_kernel = 0;  // Kernel time (enqueue to finish).
  double ms_upload = 0;  // Brick uploads.
  int passes = 0;        // Kernel passes.
  uint64_t samples = 0;  // Channel samples taken (trilinear reads or averages), all passes.
  // Channel samples empty-space skipping jumped over (brickless leaves, inert value ranges).
  uint64_t samples_skipped = 0;
  uint64_t requests = 0;  // Node requests read back, all passes.
  uint64_t bricks_uploaded = 0;
  // Bricks not uploaded because their page was not in RAM (non-blocking brick reads), all passes.
  uint64_t bricks_unavailable = 0;
  double finished_fraction = 0;       // Rays finished after the last pass (full frame: 1).
  bool final = false;                 // Refinement complete at the level the screen needs.
  std::vector<double> pass_finished;  // finished_fraction after each pass.
  // The lod bias the frame used: FrameOptions::lod_bias plus the internal pressure bias.
  double lod_bias_used = 0;
  uint64_t slots_used = 0;  // Distinct brick slots sampled (the last pass's working set).
};

// A refinement in progress: its camera, parameters, per-pixel ray state on the device and the
// stats of its passes so far. Created by VolumeRenderer::StartRefinement.
class Refinement {
 public:
  ~Refinement();
  Refinement(const Refinement&) = delete;
  Refinement& operator=(const Refinement&) = delete;

  const FrameStats& stats() const { return stats_; }
  bool complete() const { return stats_.final; }

 private:
  friend class VolumeRenderer;
  struct State;  // Defined in volume_renderer.cpp.
  Refinement() = default;

  std::unique_ptr<State> state_;
  FrameStats stats_;
};

// The view's time bias after a full frame whose kernels took `kernel_ms` against a target of
// `target_ms` (the frame-time target above). REQUIRES: kernel_ms > 0, target_ms > 0.
double NextTimeBias(double bias, double kernel_ms, double target_ms, int max_bias);

class VolumeRenderer {
 public:
  // `context`, `programs` and `device_octree` must outlive the renderer; `spacing_um` is the
  // volume's voxel pitch (PhysicalSpacing). The ray-casting programs (one per mode and frame
  // kind) are built lazily on first use, with `build_options` added to the configuring defines
  // (tests pass "-Werror"). `run_lanes`: the widest N-sample step of the brick runs, 4 or 8 (0:
  // RunLanes of the device); every width gives the same image.
  static Result<std::unique_ptr<VolumeRenderer>> Create(
      const ComputeContext* context, ProgramCache* programs, DeviceOctree* device_octree,
      const Vec3& spacing_um, std::string_view build_options = "", int run_lanes = 0);
  ~VolumeRenderer();
  VolumeRenderer(const VolumeRenderer&) = delete;
  VolumeRenderer& operator=(const VolumeRenderer&) = delete;

  // The device buffers a frame (kFullFrame) or a refinement (kRefine) of width x height pixels
  // with `params` uses (frame_buffers.h): exact, computed without allocating anything.
  static FrameBufferSizes BufferSizes(FrameMode mode, const RenderParams& params, int width,
                                      int height);

  // One full-frame pass (Sync, kernel, read image and feedback, upload for the next frame).
  // Errors when params are invalid for the volume. The device buffers come from `buffers` (a
  // view's, reused from frame to frame) or, when null, from the renderer's own set.
  Result<RenderImage> RenderFullFrame(const Camera& camera, const RenderParams& params,
                                      const FrameOptions& options, FrameStats* stats = nullptr,
                                      FrameBuffers* buffers = nullptr);

  // Starts a refinement (reserves the ray state; runs no pass). Its device state lives in
  // `buffers`, which must then outlive the refinement and not be used by another frame before it
  // ends; when null, the refinement owns its buffers.
  Result<std::unique_ptr<Refinement>> StartRefinement(const Camera& camera,
                                                      const RenderParams& params,
                                                      const FrameOptions& options,
                                                      FrameBuffers* buffers = nullptr);
  // One pass over the unfinished rays, then the upload of what they requested. Returns the
  // fraction of finished rays (1 = complete). Adds to refinement's stats.
  Result<double> RefinePass(Refinement& refinement);
  // The image so far: finished rays final, unfinished ones as composited up to their pause.
  Result<RenderImage> ReadImage(const Refinement& refinement);

  // Whole frames: full frame = one pass; refinement = passes until complete, options.max_passes
  // or `cancel` (checked between passes; kCancelled). Stats summed over passes.
  Result<RenderImage> Render(const Camera& camera, const RenderParams& params,
                             const FrameOptions& options, FrameStats* stats = nullptr,
                             const std::atomic<bool>* cancel = nullptr);

  DeviceOctree& device_octree() { return *device_octree_; }
  const Vec3& spacing() const { return spacing_; }

 private:
  struct Impl;
  VolumeRenderer() = default;

  std::unique_ptr<Impl> impl_;
  DeviceOctree* device_octree_ = nullptr;
  // Per view (FrameOptions::view) adaptive state of full frames (see the file comment); views
  // whose state is all zero are erased.
  struct ViewLod {
    int pressure_bias = 0;  // Brick-buffer pressure: 0..root level.
    double time_bias = 0;   // Frame-time target: 0..root level, fractional.
  };
  std::map<uint64_t, ViewLod> view_lod_;
  Vec3 spacing_;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_VOLUME_RENDERER_H_
