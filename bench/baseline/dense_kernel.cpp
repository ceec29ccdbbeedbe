#include "baseline/dense_kernel.h"

#include <algorithm>
#include <chrono>
#include <string>
#include <utility>

#include "../../kernels/render_format.h"
#include "render/cl_call.h"
#include "render/render_frame.h"
#include "util/checked_math.h"

namespace octoscope::bench {

using render::Camera;
using render::ClKernel;
using render::ClMem;
using render::RenderImage;
using render::RenderMode;
using render::RenderParams;

namespace {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// Work groups of kTile x kTile pixels, as the renderer's.
constexpr size_t kTile = 8;

}  // namespace

Result<DenseKernel> DenseKernel::Create(const render::ComputeContext* context,
                                        render::ProgramCache* programs,
                                        const std::array<int64_t, 3>& size,
                                        const render::Vec3& spacing_um,
                                        const std::vector<std::span<const uint16_t>>& channels) {
  if (size[0] < 1 || size[1] < 1 || size[2] < 1) {
    return InvalidArgumentError("dense kernel: every size must be >= 1");
  }
  if (channels.empty() || channels.size() > OCTO_MAX_ACTIVE_CHANNELS) {
    return InvalidArgumentError("dense kernel: 1.." + std::to_string(OCTO_MAX_ACTIVE_CHANNELS) +
                                " channels, not " + std::to_string(channels.size()));
  }
  const uint64_t nc = channels.size();
  const auto plane =
      CheckedProduct({static_cast<uint64_t>(size[0]), static_cast<uint64_t>(size[1]), nc});
  const auto voxels =
      CheckedProduct({static_cast<uint64_t>(size[0]), static_cast<uint64_t>(size[1]),
                      static_cast<uint64_t>(size[2])});
  if (!plane || *plane >= (uint64_t{1} << 32) || !voxels || size[2] >= (int64_t{1} << 24)) {
    return InvalidArgumentError("dense kernel: volume too large for its 32-bit plane offsets");
  }
  const auto bytes = CheckedProduct({*voxels, nc, uint64_t{2}});
  if (!bytes) return ResourceExhaustedError("dense kernel: volume too large");
  for (size_t c = 0; c < channels.size(); ++c) {
    if (channels[c].size() != *voxels) {
      return InvalidArgumentError("dense kernel: channel " + std::to_string(c) + " has " +
                                  std::to_string(channels[c].size()) + " samples, expected " +
                                  std::to_string(*voxels));
    }
  }
  DenseKernel k;
  k.context_ = context;
  k.programs_ = programs;
  k.size_ = size;
  k.spacing_ = spacing_um;
  k.channel_count_ = static_cast<int>(nc);
  k.volume_bytes_ = *bytes;
  OCTO_ASSIGN_OR_RETURN(k.volume_, context->CreateBuffer(CL_MEM_READ_ONLY, *bytes));
  // Interleave the channels slab by slab (~16 MB of host memory at a time).
  const uint64_t plane_voxels = static_cast<uint64_t>(size[0]) * static_cast<uint64_t>(size[1]);
  const uint64_t slab_planes = std::max<uint64_t>(1, (uint64_t{8} << 20) / (plane_voxels * nc));
  std::vector<uint16_t> slab;
  for (uint64_t z0 = 0; z0 < static_cast<uint64_t>(size[2]); z0 += slab_planes) {
    const uint64_t z1 = std::min<uint64_t>(size[2], z0 + slab_planes);
    const uint64_t first = z0 * plane_voxels, count = (z1 - z0) * plane_voxels;
    slab.resize(count * nc);
    for (uint64_t c = 0; c < nc; ++c) {
      const uint16_t* src = channels[c].data() + first;
      for (uint64_t i = 0; i < count; ++i) slab[i * nc + c] = src[i];
    }
    OCTO_RETURN_IF_ERROR(
        context->WriteBuffer(k.volume_, first * nc * 2, slab.size() * 2, slab.data()));
  }
  OCTO_ASSIGN_OR_RETURN(k.counters_,
                        context->CreateBuffer(CL_MEM_READ_WRITE, OCTO_COUNTER_WORDS * 4));
  return k;
}

Result<RenderImage> DenseKernel::Render(const Camera& camera, const RenderParams& params,
                                        DenseKernelStats* stats) {
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, channel_count_));
  const Clock::time_point start = Clock::now();
  // Level 0 everywhere (the kernel has no levels) and no skipping: the frame as the renderer's.
  const render::PackedFrame packed =
      render::PackRenderFrame(camera, params, 0, false, size_, spacing_);
  // Eight rays per work item (DensePacketRayCast) on devices with 8-lane float vectors (CPUs)
  // when no channel has a transform; else one ray per work item.
  const int lanes = render::RunLanes(context_->device());
  const bool packets = packets_allowed_ && lanes >= 8 && packed.all_identity;
  // One program per (mode, enabled channel count); its kernel per packets.
  const std::tuple<int, int, bool> key{render::KernelModeDefine(params.mode),
                                       std::max(1, packed.frame.active_channels), packets};
  auto it = kernels_.find(key);
  if (it == kernels_.end()) {
    OCTO_ASSIGN_OR_RETURN(ClKernel kernel,
                          programs_->CreateKernel(
                              "dense_baseline.cl", packets ? "DensePacketRayCast" : "DenseRayCast",
                              "-DOCTO_MODE=" + std::to_string(std::get<0>(key)) +
                                  " -DOCTO_DENSE_ACTIVE=" + std::to_string(std::get<1>(key)) +
                                  " -DOCTO_RUN_LANES=" + std::to_string(lanes)));
    it = kernels_.emplace(key, std::move(kernel)).first;
  }
  const cl_kernel kernel = it->second.get();

  const render::ComputeContext& ctx = *context_;
  OCTO_ASSIGN_OR_RETURN(
      ClMem channel_buffer,
      ctx.CreateBuffer(CL_MEM_READ_ONLY, packed.channels.size() * sizeof(OctoChannelParams),
                       packed.channels.data()));
  OCTO_ASSIGN_OR_RETURN(
      ClMem lut_buffer,
      ctx.CreateBuffer(CL_MEM_READ_ONLY, packed.lut.size() * sizeof(float), packed.lut.data()));
  const size_t pixels = static_cast<size_t>(camera.width()) * camera.height();
  if (pixels > image_pixels_) {
    OCTO_ASSIGN_OR_RETURN(image_, ctx.CreateBuffer(CL_MEM_WRITE_ONLY, pixels * 4 * sizeof(float)));
    image_pixels_ = pixels;
  }
  const uint32_t zeros[OCTO_COUNTER_WORDS] = {0, 0, 0, 0};
  OCTO_RETURN_IF_ERROR(ctx.WriteBuffer(counters_, 0, sizeof(zeros), zeros));
  OCTO_RETURN_IF_ERROR(render::SetKernelArgs(kernel, volume_, static_cast<cl_uint>(channel_count_),
                                             packed.frame, channel_buffer, lut_buffer, image_,
                                             counters_));

  // 2-D range of work items (pixels, or 4 x 2 pixel blocks) rounded up to whole 8x8 tiles (a
  // device whose limit is below a tile chooses).
  const auto round_up = [](int n) { return (static_cast<size_t>(n) + kTile - 1) / kTile * kTile; };
  const size_t global[2] = {round_up(packets ? (camera.width() + 3) / 4 : camera.width()),
                            round_up(packets ? (camera.height() + 1) / 2 : camera.height())};
  const size_t local[2] = {kTile, kTile};
  size_t max_group = 0;
  OCTO_RETURN_IF_ERROR(OCTO_CL(clGetKernelWorkGroupInfo(
      kernel, ctx.device_id(), CL_KERNEL_WORK_GROUP_SIZE, sizeof(max_group), &max_group, nullptr)));
  const Clock::time_point kernel_start = Clock::now();
  OCTO_RETURN_IF_ERROR(OCTO_CL(clEnqueueNDRangeKernel(ctx.queue(), kernel, 2, nullptr, global,
                                                      max_group >= kTile * kTile ? local : nullptr,
                                                      0, nullptr, nullptr)));
  OCTO_RETURN_IF_ERROR(ctx.Finish());
  const double ms_kernel = MsSince(kernel_start);

  RenderImage image;
  image.width = camera.width();
  image.height = camera.height();
  image.rgba.resize(pixels * 4);
  OCTO_RETURN_IF_ERROR(ctx.ReadBuffer(image_, 0, pixels * 4 * sizeof(float), image.rgba.data()));
  uint32_t words[OCTO_COUNTER_WORDS];
  OCTO_RETURN_IF_ERROR(ctx.ReadBuffer(counters_, 0, sizeof(words), words));
  if (stats) {
    stats->samples =
        (uint64_t{words[OCTO_COUNTER_SAMPLES_HI]} << 32) | words[OCTO_COUNTER_SAMPLES_LO];
    stats->rays = words[OCTO_COUNTER_FINISHED];
    stats->ms_kernel = ms_kernel;
    stats->ms_total = MsSince(start);
    stats->packets = packets;
  }
  return image;
}

}  // namespace octoscope::bench
