// DenseKernel: the plainest OpenCL ray caster doing the renderer's level-0 work — the benchmark
// baseline of `octoscope bench render` ("octree renderer Msamples/s ÷ plain kernel Msamples/s").
// Not production code: it lives in bench/ (library octoscope_bench_baseline).
//
// The whole volume is ONE device buffer of uint16 (x fastest, channels interleaved per voxel, as
// in the renderer's bricks). kernels/dense_baseline.cl casts the renderer's rays (the same
// PackRenderFrame arguments and OctoPixelRay), samples every step voxels from the entry with
// segment midpoints, reads 8 voxels per channel and sample (trilinear, clamp to edge), and
// composites with the renderer's transfer function — in 8x8 work groups, without octree, paging,
// level of detail or empty-space skipping. On devices with 8-lane float vectors (CPUs) and without
// channel transforms a work item may cast eight rays (a 4 x 2 pixel block) in lockstep as vector
// lanes (DensePacketRayCast; set_packets): DVR's compositing is a chain along a ray but vector
// work across rays. Which form is faster depends on the view (on PoCL: packets 1.06-1.12x at
// 1024^2 of 512^3, 0.86-0.96x at 256^2), so `bench render` times both and takes the faster.
// Its images equal the renderer's at level 0 and
// the CPU reference within float rounding (tests/bench/dense_kernel_test.cpp).
//
// Thread safety: not thread-safe (one kernel object whose arguments Render sets); use from one
// thread at a time. The ComputeContext and ProgramCache must outlive it.
#ifndef OCTOSCOPE_BENCH_BASELINE_DENSE_KERNEL_H_
#define OCTOSCOPE_BENCH_BASELINE_DENSE_KERNEL_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <span>
#include <tuple>
#include <utility>
#include <vector>

#include "render/camera.h"
#include "render/cl_handles.h"
#include "render/device.h"
#include "render/linear_algebra.h"
#include "render/program_cache.h"
#include "render/render_image.h"
#include "render/render_params.h"
#include "util/result.h"

namespace octoscope::bench {

struct DenseKernelStats {
  uint64_t samples = 0;  // Channel samples (trilinear reads), the unit of "Msamples/s".
  uint32_t rays = 0;     // Pixels finished.
  double ms_kernel = 0;  // Enqueue to Finish of the one kernel launch.
  double ms_total = 0;   // Render call: arguments, kernel, image read back.
  bool packets = false;  // Eight rays per work item (DensePacketRayCast) were cast.
};

class DenseKernel {
 public:
  // Uploads `channels` (each size[0] * size[1] * size[2] stored values, x fastest) as one
  // interleaved buffer. Errors: kInvalidArgument for sizes < 1, no channel, more than
  // OCTO_MAX_ACTIVE_CHANNELS, a channel of the wrong length or a plane too large for 32-bit
  // offsets (size[0] * size[1] * channels >= 2^32); kResourceExhausted when the device cannot
  // hold the buffer.
  static Result<DenseKernel> Create(const render::ComputeContext* context,
                                    render::ProgramCache* programs,
                                    const std::array<int64_t, 3>& size,
                                    const render::Vec3& spacing_um,
                                    const std::vector<std::span<const uint16_t>>& channels);

  // Renders the volume as seen by `camera` (one launch). Errors when `params` is invalid for the
  // volume or the device fails.
  Result<render::RenderImage> Render(const render::Camera& camera,
                                     const render::RenderParams& params,
                                     DenseKernelStats* stats = nullptr);

  uint64_t volume_bytes() const { return volume_bytes_; }

  // Eight rays per work item where the device and parameters allow it (the default); false casts
  // one ray per work item everywhere (tests compare the two).
  void set_packets(bool allowed) { packets_allowed_ = allowed; }

 private:
  DenseKernel() = default;

  const render::ComputeContext* context_ = nullptr;
  render::ProgramCache* programs_ = nullptr;
  std::array<int64_t, 3> size_{1, 1, 1};
  render::Vec3 spacing_{1, 1, 1};
  int channel_count_ = 0;
  uint64_t volume_bytes_ = 0;
  render::ClMem volume_;
  render::ClMem counters_;
  render::ClMem image_;  // float4 per pixel, grown on demand.
  size_t image_pixels_ = 0;
  bool packets_allowed_ = true;
  // Per (OCTO_MODE, enabled channel count), created on first use.
  std::map<std::tuple<int, int, bool>, render::ClKernel> kernels_;  // (mode, channels, packets)
};

}  // namespace octoscope::bench

#endif  // OCTOSCOPE_BENCH_BASELINE_DENSE_KERNEL_H_
