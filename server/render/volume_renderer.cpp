#include "render/volume_renderer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <utility>

#include "../../kernels/node_format.h"
#include "../../kernels/render_format.h"
#include "render/cl_call.h"
#include "render/cl_handles.h"
#include "render/render_frame.h"

namespace octoscope::render {

// The frame and channel structs are passed to the kernel byte for byte: only 32-bit fields, no
// padding, the offsets OpenCL C computes for the same declarations.
static_assert(sizeof(float) == 4 && sizeof(int) == 4);
static_assert(sizeof(OctoRenderFrame) == 48 * 4);
static_assert(offsetof(OctoRenderFrame, origin) == 0);
static_assert(offsetof(OctoRenderFrame, projection) == 12);
static_assert(offsetof(OctoRenderFrame, forward) == 16);
static_assert(offsetof(OctoRenderFrame, pixel_scale) == 28);
static_assert(offsetof(OctoRenderFrame, right) == 32);
static_assert(offsetof(OctoRenderFrame, t_min) == 44);
static_assert(offsetof(OctoRenderFrame, up) == 48);
static_assert(offsetof(OctoRenderFrame, lod_scale) == 60);
static_assert(offsetof(OctoRenderFrame, clip) == 64);
static_assert(offsetof(OctoRenderFrame, background) == 112);
static_assert(offsetof(OctoRenderFrame, volume) == 128);
static_assert(offsetof(OctoRenderFrame, step) == 140);
static_assert(offsetof(OctoRenderFrame, clip_count) == 144);
static_assert(offsetof(OctoRenderFrame, active_channels) == 156);
static_assert(offsetof(OctoRenderFrame, inv_reference) == 168);
static_assert(offsetof(OctoRenderFrame, lod_spacing) == 172);
static_assert(sizeof(OctoChannelParams) == 26 * 4);
static_assert(offsetof(OctoChannelParams, color) == 48);
static_assert(offsetof(OctoChannelParams, window_lo) == 64);
static_assert(offsetof(OctoChannelParams, channel) == 80);
static_assert(offsetof(OctoChannelParams, lut) == 84);
static_assert(offsetof(OctoChannelParams, identity) == 88);
static_assert(offsetof(OctoChannelParams, visible_lo) == 92);
static_assert(OCTO_MAX_CLIP_PLANES == kMaxClipPlanes && OCTO_LUT_ENTRIES == kLutEntries);
static_assert(OCTO_MAX_ACTIVE_CHANNELS == octree::kMaxChannels);
static_assert(kMaxBrickAllocations == 4);  // OCTO_BRICK_BUFFER_PARAMS takes four buffers.

namespace {

using Clock = std::chrono::steady_clock;

// Work-group tile of the ray-casting kernels (pixels per side).
constexpr int kTile = OCTO_TILE;

// Tiles of kTile x kTile pixels covering a width x height image.
uint64_t TileCount(int width, int height) {
  const auto tiles = [](int n) {
    return static_cast<uint64_t>((std::max(n, 0) + kTile - 1) / kTile);
  };
  return tiles(width) * tiles(height);
}

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// Everything the kernel needs besides the octree: the frame struct and the per-channel buffers.
struct FrameInputs {
  OctoRenderFrame frame{};
  cl_mem channels = nullptr;  // OctoChannelParams per enabled channel (at least one entry).
  cl_mem lut = nullptr;       // float4 entries (at least one).
  int active = 0;
  // The program variant's specialising defines (kernels/raycast.cl): the tree's brick size and
  // channel count, the enabled channels and whether all of them are untransformed (the last two
  // absent when no channel is enabled).
  std::string variant;
};

// -DOCTO_FIXED_BRICK / OCTO_FIXED_CHANNELS for the tree (kernels/node_format.h: its strides and
// node indices become constants), then -DOCTO_ACTIVE / OCTO_CHANNELS / OCTO_IDENTITY for the
// enabled channels of `packed`.
std::string VariantDefines(const octree::BrickGeometry& geometry, const PackedFrame& packed) {
  const auto& bs = geometry.brick_size();
  std::string defines = " -DOCTO_FIXED_BRICK=" + std::to_string(bs[0]) + "," +
                        std::to_string(bs[1]) + "," + std::to_string(bs[2]) +
                        " -DOCTO_FIXED_CHANNELS=" + std::to_string(geometry.channels());
  if (packed.frame.active_channels <= 0) return defines;
  defines.append(" -DOCTO_ACTIVE=");
  defines.append(std::to_string(packed.frame.active_channels));
  defines.append(" -DOCTO_CHANNELS=");
  for (int k = 0; k < packed.frame.active_channels; ++k) {
    if (k > 0) defines.push_back(',');
    defines.append(std::to_string(packed.channels[k].channel));
  }
  defines.append(packed.all_identity ? " -DOCTO_IDENTITY=1" : " -DOCTO_IDENTITY=0");
  return defines;
}

// Enabled channels, and float entries of their LUTs.
int ActiveChannels(const RenderParams& params) {
  int active = 0;
  for (const ChannelParams& cp : params.channels) active += cp.enabled ? 1 : 0;
  return active;
}
size_t LutFloats(const RenderParams& params) {
  size_t floats = 0;
  for (const ChannelParams& cp : params.channels) {
    if (cp.enabled && cp.lut) floats += 4 * kLutEntries;
  }
  return floats;
}

// Converts camera and parameters to the kernel's voxel-space frame (render_frame.h), writing the
// per-channel buffers into `buffers` (reserved by the caller with VolumeRenderer::BufferSizes).
// REQUIRES: params validated for the volume.
Result<FrameInputs> MakeFrameInputs(const ComputeContext& context, const Camera& camera,
                                    const RenderParams& params, const FrameOptions& options,
                                    const octree::BrickGeometry& geometry, const Vec3& spacing,
                                    const FrameBuffers& buffers) {
  const auto& n = geometry.volume_size();
  const PackedFrame packed = PackRenderFrame(camera, params, options.lod_bias,
                                             options.skip_empty_space, {n[0], n[1], n[2]}, spacing);
  FrameInputs in;
  in.frame = packed.frame;
  // Footprints in the finest spacing: the kernel's LOD spacing is then 1 on every ray.
  if (!options.lod_view_spacing) std::fill_n(in.frame.lod_spacing, 3, 1.0f);
  in.active = packed.frame.active_channels;
  in.variant = VariantDefines(geometry, packed);
  const std::vector<OctoChannelParams>& channels = packed.channels;
  const std::vector<float>& lut = packed.lut;
  const ClMem& channel_buffer = buffers.handle(FrameBuffer::kChannels);
  const ClMem& lut_buffer = buffers.handle(FrameBuffer::kLut);
  OCTO_RETURN_IF_ERROR(context.WriteBuffer(channel_buffer, 0, channels.size() * sizeof(channels[0]),
                                           channels.data()));
  OCTO_RETURN_IF_ERROR(context.WriteBuffer(lut_buffer, 0, lut.size() * sizeof(float), lut.data()));
  in.channels = channel_buffer.get();
  in.lut = lut_buffer.get();
  return in;
}

OctoTreeGeometry TreeGeometry(const octree::BrickGeometry& g) {
  OctoTreeGeometry t{};
  for (int a = 0; a < 3; ++a) {
    t.volume_size[a] = static_cast<int>(g.volume_size()[a]);
    t.brick_size[a] = static_cast<int>(g.brick_size()[a]);
  }
  t.root_level = g.root_level();
  t.channels = g.channels();
  return t;
}

}  // namespace

struct VolumeRenderer::Impl {
  const ComputeContext* context = nullptr;
  ProgramCache* programs = nullptr;
  std::string build_options;
  // One kernel per (mode define, refine), created on first use.
  std::map<std::string, ClKernel> kernels;  // By build options (mode, frame kind, variant).
  ClMem counters;                           // OCTO_COUNTER_WORDS uints, set before every pass.
  ClMem dummy;                              // Stands in for the ray-state buffers of full frames.
  // Kernel ms per listed tile of the last refinement passes (0 = none yet): sizes the slices of
  // the tile list that refinements with a pass target run per pass.
  double refine_ms_per_tile = 0;
  std::unique_ptr<FrameBuffers> own_buffers;  // Full frames of callers that pass none.

  // The program of (mode, frame kind) specialised for `variant` (VariantDefines), built on
  // first use and kept: switching channels back and forth does not rebuild.
  Result<cl_kernel> Kernel(RenderMode mode, bool refine, const std::string& variant) {
    const std::string options = build_options +
                                " -DOCTO_MODE=" + std::to_string(KernelModeDefine(mode)) +
                                " -DOCTO_REFINE=" + (refine ? "1" : "0") + variant;
    auto it = kernels.find(options);
    if (it == kernels.end()) {
      OCTO_ASSIGN_OR_RETURN(ClKernel kernel,
                            programs->CreateKernel("raycast.cl", "RayCast", options));
      it = kernels.emplace(options, std::move(kernel)).first;
    }
    return it->second.get();
  }

  // Which rays a pass runs: full frames every pixel (2-D tiles); refinement passes the entries
  // [offset, offset + count) of the tile list `tiles_in` (of the list of all tiles when `all`),
  // appending to `tiles_out` from index `out_start` on those still unfinished.
  struct PassTiles {
    bool refine = false;
    cl_mem tiles_in = nullptr;
    cl_mem tiles_out = nullptr;
    cl_mem stamps = nullptr;
    uint32_t offset = 0;
    uint32_t count = 0;
    bool all = false;
    uint32_t out_start = 0;
  };

  // Sets every argument and runs one pass over the width x height pixels (full frames) or the
  // listed tiles (refinement); reads the counters back (finished rays, samples, the end of the
  // tiles_out list). Adds the kernel time to stats.

  Status RunPass(DeviceOctree& octree, cl_kernel kernel, const FrameInputs& in, uint32_t frame,
                 cl_mem image, cl_mem ray_next, cl_mem ray_acc, cl_mem ray_extreme, int width,
                 int height, const PassTiles& tiles, uint32_t* finished, uint64_t* samples,
                 uint32_t* next_tiles, FrameStats* stats) {
    // Zero, but the tile list appends where the sweep's earlier passes left off.
    uint32_t initial[OCTO_COUNTER_WORDS] = {};
    initial[OCTO_COUNTER_NEXT_TILES] = tiles.out_start;
    OCTO_RETURN_IF_ERROR(context->WriteBuffer(counters, 0, sizeof(initial), initial));
    const auto bricks = octree.brick_buffers();
    OCTO_RETURN_IF_ERROR(SetKernelArgs(
        kernel, octree.node_buffer(), bricks[0], bricks[1], bricks[2], bricks[3],
        octree.slots_per_allocation(), TreeGeometry(octree.geometry()), in.frame, in.channels,
        in.lut, octree.request_flags(), octree.request_list(), octree.request_capacity(),
        octree.slot_used(), octree.cell_ranges(), frame, image, counters, ray_next, ray_acc,
        ray_extreme, tiles.refine ? tiles.tiles_in : dummy.get(),
        tiles.refine ? tiles.tiles_out : dummy.get(), tiles.refine ? tiles.stamps : dummy.get(),
        tiles.offset, tiles.count, tiles.all ? 1 : 0));
    const Clock::time_point start = Clock::now();
    if (tiles.refine) {
      OCTO_RETURN_IF_ERROR(EnqueueTiles(kernel, tiles.count));
    } else {
      OCTO_RETURN_IF_ERROR(Enqueue(kernel, width, height));
    }
    OCTO_RETURN_IF_ERROR(context->Finish());
    stats->ms_kernel += MsSince(start);
    uint32_t words[OCTO_COUNTER_WORDS];
    OCTO_RETURN_IF_ERROR(context->ReadBuffer(counters, 0, sizeof(words), words));
    *finished = words[OCTO_COUNTER_FINISHED];
    *next_tiles = words[OCTO_COUNTER_NEXT_TILES];
    *samples = (uint64_t{words[OCTO_COUNTER_SAMPLES_HI]} << 32) | words[OCTO_COUNTER_SAMPLES_LO];
    stats->slots_used = words[OCTO_COUNTER_SLOTS_USED];
    stats->samples_skipped +=
        (uint64_t{words[OCTO_COUNTER_SKIPPED_HI]} << 32) | words[OCTO_COUNTER_SKIPPED_LO];
    return Status::Ok();
  }

  // One work item per pixel, 2-D over the image in tiles of kTile x kTile (rounded up; the kernel
  // ignores work items outside the image): the rays of a work group are neighbours and read the
  // same bricks.
  Status Enqueue(cl_kernel kernel, int width, int height) const {
    if (width <= 0 || height <= 0) return Status::Ok();
    const auto round_up = [](int n) {
      return static_cast<size_t>((n + kTile - 1) / kTile * kTile);
    };
    const size_t global[2] = {round_up(width), round_up(height)};
    const size_t local[2] = {kTile, kTile};
    // A device whose limit for this kernel is below one tile picks its own work-group shape.
    size_t max_group = 0;
    OCTO_RETURN_IF_ERROR(
        OCTO_CL(clGetKernelWorkGroupInfo(kernel, context->device_id(), CL_KERNEL_WORK_GROUP_SIZE,
                                         sizeof(max_group), &max_group, nullptr)));
    const bool tiles = max_group >= size_t{kTile} * kTile;
    return OCTO_CL(clEnqueueNDRangeKernel(context->queue(), kernel, 2, nullptr, global,
                                          tiles ? local : nullptr, 0, nullptr, nullptr));
  }

  // A 1-D range of kTile^2 work items per tile; groups of one tile where the device allows.
  Status EnqueueTiles(cl_kernel kernel, uint32_t tiles) const {
    if (tiles == 0) return Status::Ok();
    const size_t group = size_t{kTile} * kTile;
    const size_t global = size_t{tiles} * group;
    size_t max_group = 0;
    OCTO_RETURN_IF_ERROR(
        OCTO_CL(clGetKernelWorkGroupInfo(kernel, context->device_id(), CL_KERNEL_WORK_GROUP_SIZE,
                                         sizeof(max_group), &max_group, nullptr)));
    return OCTO_CL(clEnqueueNDRangeKernel(context->queue(), kernel, 1, nullptr, &global,
                                          max_group >= group ? &group : nullptr, 0, nullptr,
                                          nullptr));
  }

  // Reads the pass's requests and uploads them within `budget`; adds to stats.
  Status Feedback(DeviceOctree& octree, UploadBudget budget, FrameStats* stats,
                  UploadStats* upload_out) {
    OCTO_ASSIGN_OR_RETURN(std::vector<uint32_t> requests, octree.ReadFeedback());
    stats->requests += requests.size();
    UploadStats upload;
    const Clock::time_point start = Clock::now();
    OCTO_RETURN_IF_ERROR(octree.Upload(requests, budget, &upload));
    stats->ms_upload += MsSince(start);
    stats->bricks_uploaded += upload.uploaded;
    stats->bricks_unavailable += upload.unavailable;
    *upload_out = upload;
    return Status::Ok();
  }
};

struct Refinement::State {
  RenderMode mode = RenderMode::kDvr;
  FrameOptions options;
  FrameInputs inputs;
  std::unique_ptr<FrameBuffers> own_buffers;  // When the caller passed none.
  // The buffers below (and inputs') live in *buffers (the caller's or own_buffers).
  FrameBuffers* buffers = nullptr;
  cl_mem image = nullptr;        // float4 per pixel.
  cl_mem ray_next = nullptr;     // uint per pixel: next sample index or OCTO_RAY_DONE.
  cl_mem ray_acc = nullptr;      // float4 per pixel (DVR).
  cl_mem ray_extreme = nullptr;  // float per pixel and enabled channel (MIP/MinIP).
  // A sweep runs the tile list tiles_in (every tile in the first sweep) in slices, one per pass
  // (FrameOptions::pass_target_ms; the whole list without a target), each appending its
  // unfinished tiles to tiles_out after the earlier slices' ones; then the lists swap. A slice
  // whose pass uploaded bricks and left rays unfinished runs again (its rays use the bricks
  // before another slice's uploads could evict them), appending from the same index: its
  // entries are overwritten, never duplicated. Progress is judged per sweep (a slice whose rays
  // all wait for bricks may stand still while others advance).
  cl_mem tiles_in = nullptr;     // The tiles this sweep runs (unless all_tiles).
  cl_mem tiles_out = nullptr;    // Where its passes list those still unfinished.
  cl_mem tile_stamps = nullptr;  // uint per tile: the pass (octree frame) that listed it last.
  uint32_t tile_count = 0;       // Entries of tiles_in, or all tiles.
  bool all_tiles = true;         // The first sweep runs every tile.
  uint32_t slice_start = 0;      // The next slice: entries [slice_start, + slice_tiles).
  uint32_t slice_tiles = 0;      // 0 = not cut yet.
  int slice_runs = 0;            // Passes the slice has run.
  uint32_t out_count = 0;        // Entries of tiles_out so far this sweep.
  int width = 0;
  int height = 0;
  uint64_t finished = 0;
  int stalled_passes = 0;          // Consecutive sweeps without progress.
  int stalled_without_upload = 0;  // Of which consecutive ones that uploaded nothing either.
  uint64_t sweep_finished = 0, sweep_samples = 0, sweep_uploaded = 0;
  bool sweep_waiting = false, sweep_unavailable = false;
};

Refinement::~Refinement() = default;

VolumeRenderer::~VolumeRenderer() = default;

double NextTimeBias(double bias, double kernel_ms, double target_ms, int max_bias) {
  // About half the cost per level of bias, so log2 of the ratio is the bias step that would hit
  // the target; damped. Coarser as soon as a frame is over the target (beyond a dead band against
  // timing noise), finer only with room for a whole level (under half the target): where every
  // ray changes level at once (orthographic views) the cost jumps, and a symmetric band would
  // flip between a frame over the target and one far under it.
  const double error = std::log2(kernel_ms / target_ms);
  if (error > 0.25 || error < -1.0) {
    bias = std::clamp(bias + 0.75 * error, 0.0, static_cast<double>(max_bias));
  }
  return bias;
}

Result<std::unique_ptr<VolumeRenderer>> VolumeRenderer::Create(
    const ComputeContext* context, ProgramCache* programs, DeviceOctree* device_octree,
    const Vec3& spacing_um, std::string_view build_options, int run_lanes) {
  if (context == nullptr || programs == nullptr || device_octree == nullptr) {
    return InvalidArgumentError("volume renderer: context, programs and octree are required");
  }
  if (run_lanes != 0 && run_lanes != 4 && run_lanes != 8) {
    return InvalidArgumentError("volume renderer: run_lanes must be 0, 4 or 8, not " +
                                std::to_string(run_lanes));
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(spacing_um[a]) || spacing_um[a] <= 0) {
      return InvalidArgumentError("volume renderer: spacing must be finite and > 0");
    }
  }
  std::unique_ptr<VolumeRenderer> r(new VolumeRenderer());
  r->impl_ = std::make_unique<Impl>();
  r->impl_->context = context;
  r->impl_->programs = programs;
  r->impl_->build_options =
      std::string(build_options) + " -DOCTO_RUN_LANES=" +
      std::to_string(run_lanes != 0 ? run_lanes : RunLanes(context->device()));
  OCTO_ASSIGN_OR_RETURN(r->impl_->counters,
                        context->CreateBuffer(CL_MEM_READ_WRITE, OCTO_COUNTER_WORDS * 4));
  OCTO_ASSIGN_OR_RETURN(r->impl_->dummy, context->CreateBuffer(CL_MEM_READ_WRITE, 16));
  r->impl_->own_buffers = std::make_unique<FrameBuffers>(context);
  r->device_octree_ = device_octree;
  r->spacing_ = spacing_um;
  // No program is built here: a frame builds the variant it uses (a first image after opening
  // a file would otherwise also wait for one it does not use).
  return r;
}

namespace {

// Host memory for `pixels` RGBA float pixels; kResourceExhausted instead of an exception when the
// host cannot hold them (an image may be up to 16384^2 pixels, 4 GiB).
Status AllocateImage(RenderImage* image, size_t pixels) {
  try {
    image->rgba.resize(pixels * 4);
  } catch (const std::bad_alloc&) {
    return ResourceExhaustedError("no host memory for a " + std::to_string(image->width) + "x" +
                                  std::to_string(image->height) + " image");
  }
  return Status::Ok();
}

}  // namespace

FrameBufferSizes VolumeRenderer::BufferSizes(FrameMode mode, const RenderParams& params, int width,
                                             int height) {
  const uint64_t pixels = uint64_t(std::max(width, 0)) * uint64_t(std::max(height, 0));
  const uint64_t active = std::max(1, ActiveChannels(params));
  FrameBufferSizes sizes{};
  const auto at = [&sizes](FrameBuffer b) -> uint64_t& { return sizes[static_cast<size_t>(b)]; };
  at(FrameBuffer::kImage) = std::max<uint64_t>(pixels, 1) * 4 * sizeof(float);
  at(FrameBuffer::kChannels) = active * sizeof(OctoChannelParams);
  at(FrameBuffer::kLut) = std::max<size_t>(LutFloats(params), 4) * sizeof(float);
  if (mode == FrameMode::kRefine) {
    at(FrameBuffer::kRayNext) = std::max<uint64_t>(pixels, 1) * sizeof(uint32_t);
    const uint64_t tiles = std::max<uint64_t>(TileCount(width, height), 1) * sizeof(uint32_t);
    at(FrameBuffer::kRayTilesA) = tiles;
    at(FrameBuffer::kRayTilesB) = tiles;
    at(FrameBuffer::kRayTileStamp) = tiles;
    if (params.mode == RenderMode::kDvr) {
      at(FrameBuffer::kRayAccumulator) = std::max<uint64_t>(pixels, 1) * 4 * sizeof(float);
    } else {
      at(FrameBuffer::kRayExtreme) = std::max<uint64_t>(pixels, 1) * active * sizeof(float);
    }
  }
  return sizes;
}

Result<RenderImage> VolumeRenderer::RenderFullFrame(const Camera& camera,
                                                    const RenderParams& params,
                                                    const FrameOptions& options, FrameStats* stats,
                                                    FrameBuffers* buffers) {
  const Clock::time_point start = Clock::now();
  DeviceOctree& octree = *device_octree_;
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, octree.geometry().channels()));
  if (!std::isfinite(options.lod_bias)) return InvalidArgumentError("lod bias must be finite");
  FrameStats local;
  // The pressure bias makes the frame coarser while the brick buffer cannot hold its working set.
  FrameOptions frame_options = options;
  ViewLod lod;
  if (const auto it = view_lod_.find(options.view); it != view_lod_.end()) lod = it->second;
  if (options.target_frame_ms <= 0) lod.time_bias = 0;
  frame_options.lod_bias += lod.pressure_bias + lod.time_bias;
  // The frame's device buffers: the caller's (reused from frame to frame) or the renderer's own.
  FrameBuffers& frame_buffers = buffers != nullptr ? *buffers : *impl_->own_buffers;
  OCTO_RETURN_IF_ERROR(frame_buffers.Reserve(
      BufferSizes(FrameMode::kFullFrame, params, camera.width(), camera.height())));
  OCTO_ASSIGN_OR_RETURN(FrameInputs in,
                        MakeFrameInputs(*impl_->context, camera, params, frame_options,
                                        octree.geometry(), spacing_, frame_buffers));
  OCTO_ASSIGN_OR_RETURN(cl_kernel kernel, impl_->Kernel(params.mode, false, in.variant));
  // Nodes first (construction may have moved on), then the frame's feedback.
  OCTO_RETURN_IF_ERROR(octree.Sync());
  OCTO_ASSIGN_OR_RETURN(const uint32_t frame, octree.BeginFrame());
  const size_t pixels = static_cast<size_t>(camera.width()) * camera.height();
  const ClMem& image = frame_buffers.handle(FrameBuffer::kImage);
  uint32_t finished = 0;
  uint64_t samples = 0;
  uint32_t next_tiles = 0;
  OCTO_RETURN_IF_ERROR(impl_->RunPass(octree, kernel, in, frame, image.get(), impl_->dummy.get(),
                                      impl_->dummy.get(), impl_->dummy.get(), camera.width(),
                                      camera.height(), {}, &finished, &samples, &next_tiles,
                                      &local));
  RenderImage out;
  out.width = camera.width();
  out.height = camera.height();
  OCTO_RETURN_IF_ERROR(AllocateImage(&out, pixels));
  OCTO_RETURN_IF_ERROR(
      impl_->context->ReadBuffer(image, 0, out.rgba.size() * sizeof(float), out.rgba.data()));
  // Upload for the next frame; this frame's bricks stay.
  UploadBudget budget = options.upload;
  budget.protect_frame = frame;
  UploadStats upload;
  const uint64_t requests_before = local.requests;
  OCTO_RETURN_IF_ERROR(impl_->Feedback(octree, budget, &local, &upload));
  local.passes = 1;
  local.samples = samples;
  local.finished_fraction = 1;
  local.pass_finished = {1.0};
  // Nothing requested: every sample used the level the screen needs.
  local.final = local.requests == requests_before;
  local.lod_bias_used = frame_options.lod_bias;
  // Pressure: requests were left although neither the time nor the count limit stopped the
  // upload, so every evictable slot was taken (the frame's own bricks are protected).
  const bool time_or_count_limited =
      upload.ms >= budget.max_ms ||
      (budget.max_bricks != 0 && upload.uploaded >= budget.max_bricks);
  const int max_bias = octree.geometry().root_level();
  if (upload.deferred > 0 && !time_or_count_limited) {
    lod.pressure_bias = std::min(lod.pressure_bias + 1, max_bias);
  } else if (lod.pressure_bias > 0 && local.final &&
             local.slots_used * 9 <= uint64_t{octree.slot_count()}) {
    // Room for the next finer level: up to 8x the bricks plus these as their ancestors.
    --lod.pressure_bias;
  }
  if (options.target_frame_ms > 0 && local.ms_kernel > 0) {
    lod.time_bias = NextTimeBias(lod.time_bias, local.ms_kernel, options.target_frame_ms, max_bias);
  }
  if (lod.pressure_bias > 0 || lod.time_bias > 0) {
    view_lod_[options.view] = lod;
  } else {
    view_lod_.erase(options.view);
  }
  local.ms_total = MsSince(start);
  if (stats) *stats = std::move(local);
  return out;
}

Result<std::unique_ptr<Refinement>> VolumeRenderer::StartRefinement(const Camera& camera,
                                                                    const RenderParams& params,
                                                                    const FrameOptions& options,
                                                                    FrameBuffers* buffers) {
  DeviceOctree& octree = *device_octree_;
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, octree.geometry().channels()));
  if (!std::isfinite(options.lod_bias)) return InvalidArgumentError("lod bias must be finite");
  if (options.max_passes < 0) return InvalidArgumentError("max_passes must be >= 0");
  std::unique_ptr<Refinement> r(new Refinement());
  r->state_ = std::make_unique<Refinement::State>();
  Refinement::State& s = *r->state_;
  s.mode = params.mode;
  s.options = options;
  r->stats_.lod_bias_used = options.lod_bias;
  s.width = camera.width();
  s.height = camera.height();
  if (buffers == nullptr) {
    s.own_buffers = std::make_unique<FrameBuffers>(impl_->context);
    buffers = s.own_buffers.get();
  }
  s.buffers = buffers;
  OCTO_RETURN_IF_ERROR(
      buffers->Reserve(BufferSizes(FrameMode::kRefine, params, s.width, s.height)));
  OCTO_ASSIGN_OR_RETURN(s.inputs, MakeFrameInputs(*impl_->context, camera, params, options,
                                                  octree.geometry(), spacing_, *buffers));
  // Build the program now: a pass should not pay for compilation.
  OCTO_RETURN_IF_ERROR(impl_->Kernel(params.mode, true, s.inputs.variant).status());
  const size_t pixels = static_cast<size_t>(s.width) * s.height;
  const ComputeContext& ctx = *impl_->context;
  // Ray state is initialised on the device (no host copies: a 16384^2 refinement must not
  // need gigabytes of host memory). Unprocessed pixels show the background until their ray ran.
  const auto fill = [&ctx, buffers](FrameBuffer which, size_t count, const void* pattern,
                                    size_t pattern_bytes, cl_mem* out) -> Status {
    *out = buffers->get(which);
    OCTO_CL_RETURN_IF_ERROR(clEnqueueFillBuffer(ctx.queue(), *out, pattern, pattern_bytes, 0,
                                                count * pattern_bytes, 0, nullptr, nullptr));
    return Status::Ok();
  };
  const float* bg = s.inputs.frame.background;
  OCTO_RETURN_IF_ERROR(fill(FrameBuffer::kImage, pixels, bg, 4 * sizeof(float), &s.image));
  const uint32_t zero = 0;
  OCTO_RETURN_IF_ERROR(fill(FrameBuffer::kRayNext, pixels, &zero, sizeof(zero), &s.ray_next));
  const uint64_t tiles = TileCount(s.width, s.height);
  if (tiles > std::numeric_limits<uint32_t>::max()) {
    return InvalidArgumentError("refinement: image too large (" + std::to_string(tiles) +
                                " tiles)");
  }
  OCTO_RETURN_IF_ERROR(fill(FrameBuffer::kRayTileStamp, std::max<uint64_t>(tiles, 1), &zero,
                            sizeof(zero), &s.tile_stamps));
  s.tiles_in = buffers->get(FrameBuffer::kRayTilesA);
  s.tiles_out = buffers->get(FrameBuffer::kRayTilesB);
  s.tile_count = static_cast<uint32_t>(tiles);
  s.all_tiles = true;
  if (params.mode == RenderMode::kDvr) {
    const float none = 0.0f;
    OCTO_RETURN_IF_ERROR(
        fill(FrameBuffer::kRayAccumulator, pixels * 4, &none, sizeof(none), &s.ray_acc));
    s.ray_extreme = impl_->dummy.get();
  } else {
    // Stored-value extrema; "not sampled" lies outside [0, 65535]: below for maxima, above for
    // minima.
    const float init =
        params.mode == RenderMode::kMip ? -1.0f : std::numeric_limits<float>::infinity();
    OCTO_RETURN_IF_ERROR(fill(FrameBuffer::kRayExtreme,
                              pixels * static_cast<size_t>(std::max(1, s.inputs.active)), &init,
                              sizeof(init), &s.ray_extreme));
    s.ray_acc = impl_->dummy.get();
  }
  OCTO_RETURN_IF_ERROR(ctx.Finish());
  return r;
}

Result<double> VolumeRenderer::RefinePass(Refinement& refinement) {
  const Clock::time_point start = Clock::now();
  if (refinement.state_ == nullptr) return InvalidArgumentError("refinement has no state");
  Refinement::State& s = *refinement.state_;
  FrameStats& stats = refinement.stats_;
  const size_t pixels = static_cast<size_t>(s.width) * s.height;
  if (s.finished >= pixels) return 1.0;
  DeviceOctree& octree = *device_octree_;
  OCTO_ASSIGN_OR_RETURN(cl_kernel kernel, impl_->Kernel(s.mode, true, s.inputs.variant));
  // This pass's slice of the tile list: as many tiles as the measured speed allows within the
  // pass target (at least one row of tiles; one row while no speed is known), else the rest.
  if (s.slice_tiles == 0) {
    const uint32_t rest = s.tile_count - s.slice_start;
    double tiles = static_cast<double>(rest);
    if (s.options.pass_target_ms > 0) {
      const uint32_t row = static_cast<uint32_t>(TileCount(s.width, kTile));
      const double fit = impl_->refine_ms_per_tile > 0
                             ? std::floor(s.options.pass_target_ms / impl_->refine_ms_per_tile)
                             : 0.0;
      tiles = std::clamp(fit, static_cast<double>(std::min(row, rest)), tiles);
    }
    s.slice_tiles = static_cast<uint32_t>(tiles);
    s.slice_runs = 0;
  }
  OCTO_RETURN_IF_ERROR(octree.Sync());
  OCTO_ASSIGN_OR_RETURN(const uint32_t frame, octree.BeginFrame());
  uint32_t finished = 0;
  uint64_t samples = 0;
  uint32_t next_tiles = 0;
  const Impl::PassTiles tiles{.refine = true,
                              .tiles_in = s.tiles_in,
                              .tiles_out = s.tiles_out,
                              .stamps = s.tile_stamps,
                              .offset = s.slice_start,
                              .count = s.slice_tiles,
                              .all = s.all_tiles,
                              .out_start = s.out_count};
  const double kernel_ms_before = stats.ms_kernel;
  OCTO_RETURN_IF_ERROR(impl_->RunPass(octree, kernel, s.inputs, frame, s.image, s.ray_next,
                                      s.ray_acc, s.ray_extreme, s.width, s.height, tiles, &finished,
                                      &samples, &next_tiles, &stats));
  ++s.slice_runs;
  // The speed of listed tiles, for the slices cut later (a moving average).
  if (s.slice_tiles > 0 && samples > 0) {
    const double ms_per_tile =
        (stats.ms_kernel - kernel_ms_before) / static_cast<double>(s.slice_tiles);
    impl_->refine_ms_per_tile = impl_->refine_ms_per_tile > 0
                                    ? 0.5 * impl_->refine_ms_per_tile + 0.5 * ms_per_tile
                                    : ms_per_tile;
  }
  // Paused rays hold no brick between passes: protect nothing but what this upload brings in
  // (the upload manager never evicts a brick it uploaded in the same call).
  UploadBudget budget = s.options.upload;
  budget.protect_frame = frame + 1;
  UploadStats upload;
  OCTO_RETURN_IF_ERROR(impl_->Feedback(octree, budget, &stats, &upload));
  s.finished += finished;
  stats.passes += 1;
  stats.samples += samples;
  const double fraction = static_cast<double>(s.finished) / static_cast<double>(pixels);
  stats.finished_fraction = fraction;
  stats.pass_finished.push_back(fraction);
  stats.final = s.finished >= pixels;
  stats.ms_total += MsSince(start);
  // The sweep so far; it ends after its last slice.
  s.sweep_finished += finished;
  s.sweep_samples += samples;
  s.sweep_uploaded += upload.uploaded;
  // Bricks that wait for their page (non-blocking reads) or for a free slot will come.
  s.sweep_waiting = s.sweep_waiting || upload.unavailable > 0 || upload.deferred > 0;
  s.sweep_unavailable = s.sweep_unavailable || upload.unavailable > 0;
  if (stats.final) return fraction;
  // A slice whose pass brought bricks in and left tiles unfinished runs again next, appending
  // where it did (its rays use the bricks before another slice's uploads could evict them: with a
  // small brick buffer, slices taking turns would thrash); only while it advances, after its
  // first pass. A slice that is the whole list starts the next sweep instead: the same tiles,
  // less those that finished.
  const bool whole_list = s.slice_start == 0 && s.slice_tiles == s.tile_count;
  if (upload.uploaded > 0 && next_tiles > s.out_count && !whole_list &&
      (s.slice_runs == 1 || finished > 0 || samples > 0)) {
    return fraction;
  }
  s.out_count = next_tiles;
  s.slice_start += s.slice_tiles;
  s.slice_tiles = 0;
  if (s.slice_start < s.tile_count) return fraction;
  // The end of the sweep: the next one runs the tiles left unfinished.
  std::swap(s.tiles_in, s.tiles_out);
  s.tile_count = s.out_count;
  s.all_tiles = false;
  s.slice_start = 0;
  s.out_count = 0;
  // Every unfinished ray waits for a brick: a sweep that neither advanced a ray nor uploaded
  // anything, with nothing left waiting, will never progress (nor will endlessly many that keep
  // uploading in vain). Sweeps that wait for the disk do not count: the disk sets their pace.
  if (s.sweep_finished == 0 && s.sweep_samples == 0 && !s.sweep_unavailable) {
    ++s.stalled_passes;
    s.stalled_without_upload =
        s.sweep_uploaded == 0 && !s.sweep_waiting ? s.stalled_without_upload + 1 : 0;
    // One sweep without an upload can happen while construction changes the tree between Sync
    // and Upload (a wanted node lost its brick); the next Sync sees it. Three in a row cannot.
    if (s.stalled_without_upload >= 3 || s.stalled_passes > 1000) {
      return InternalError("refinement makes no progress: " + std::to_string(pixels - s.finished) +
                           " rays wait for bricks that cannot be made resident (" +
                           std::to_string(octree.slot_count()) + " brick slots)");
    }
  } else if (s.sweep_finished != 0 || s.sweep_samples != 0) {
    s.stalled_passes = 0;
    s.stalled_without_upload = 0;
  }
  s.sweep_finished = s.sweep_samples = s.sweep_uploaded = 0;
  s.sweep_waiting = s.sweep_unavailable = false;
  return fraction;
}

Result<RenderImage> VolumeRenderer::ReadImage(const Refinement& refinement) {
  if (refinement.state_ == nullptr) return InvalidArgumentError("refinement has no state");
  const Refinement::State& s = *refinement.state_;
  RenderImage out;
  out.width = s.width;
  out.height = s.height;
  OCTO_RETURN_IF_ERROR(AllocateImage(&out, static_cast<size_t>(s.width) * s.height));
  OCTO_RETURN_IF_ERROR(impl_->context->ReadBuffer(
      s.buffers->handle(FrameBuffer::kImage), 0, out.rgba.size() * sizeof(float), out.rgba.data()));
  return out;
}

Result<RenderImage> VolumeRenderer::Render(const Camera& camera, const RenderParams& params,
                                           const FrameOptions& options, FrameStats* stats,
                                           const std::atomic<bool>* cancel) {
  if (options.mode == FrameMode::kFullFrame) {
    return RenderFullFrame(camera, params, options, stats);
  }
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<Refinement> refinement,
                        StartRefinement(camera, params, options));
  while (!refinement->complete()) {
    if (options.max_passes > 0 && refinement->stats().passes >= options.max_passes) break;
    if (cancel != nullptr && cancel->load()) return CancelledError("render cancelled");
    OCTO_RETURN_IF_ERROR(RefinePass(*refinement).status());
  }
  OCTO_ASSIGN_OR_RETURN(RenderImage image, ReadImage(*refinement));
  if (stats) *stats = refinement->stats();
  return image;
}

}  // namespace octoscope::render
