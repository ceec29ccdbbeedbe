// CpuRaycaster: the hand-written, multi-threaded C++ ray caster the OpenCL kernels are measured
// against (`octoscope bench render`: "kernel Msamples/s / C++ loop Msamples/s"). A benchmark
// baseline, not production code: it lives in bench/ (library octoscope_bench_baseline, linked only
// by the bench command and its tests). It answers "what can this CPU do with a straightforward loop
// over the full-resolution volume?", so it does the SAME sampling as the kernels and the reference
// renderer (reference_renderer.h), in float:
//  1. Ray setup per pixel in double, with the reference's own ClipRayToVolume (box and clipping
//     planes) and segment count (a ray is set up once; its samples are what cost).
//  2. Sample i at the midpoint of segment i, computed from the entry point (never accumulated),
//     directly in voxel coordinates u = p / spacing - 0.5 (voxel centres at integers).
//  3. Trilinear interpolation of each enabled channel's uint16 samples, clamped to the edge
//     voxels; a channel with a transform reads at transform * p and gives no sample outside the
//     box. Channels without a transform share one footprint computation per sample.
//  4. Transfer function, DVR compositing (opacity corrected by segment length, intermixing,
//     early termination at kEarlyTerminationAlpha) and MIP/MinIP exactly as render_params.h
//     defines them. MIP/MinIP keep the extreme STORED value per channel and window it once at the
//     end: windowing is monotone, so that equals the extreme of the windowed values.
// There is no octree, no level of detail and no empty-space skipping: every sample reads level 0.
// The images equal the reference's within float rounding (tests/bench/cpu_raycaster_test.cpp).
//
// Threads: std::thread per hardware thread (or as asked), rows interleaved (thread k renders rows
// k, k + n, ...), so the dense and the empty parts of an image spread evenly.
//
// Thread safety: immutable after Create; Render is reentrant (it reads the volume only and writes
// its own image) and may be called from several threads at once.
#ifndef OCTOSCOPE_BENCH_BASELINE_CPU_RAYCASTER_H_
#define OCTOSCOPE_BENCH_BASELINE_CPU_RAYCASTER_H_

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "render/camera.h"
#include "render/linear_algebra.h"
#include "render/render_image.h"
#include "render/render_params.h"
#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::bench {

struct CpuRaycastStats {
  uint64_t rays = 0;     // Pixels.
  uint64_t steps = 0;    // Sample positions visited.
  uint64_t samples = 0;  // Channel samples (trilinear reads), the unit of "Msamples/s".
  int threads = 0;       // Threads used.
  double ms = 0;         // Wall time of the render (threads started to threads joined).
};

class CpuRaycaster {
 public:
  // Takes the volume, with ReferenceVolume's invariants (sizes >= 1, spacing finite and > 0,
  // stored type uint8 or uint16, one vector of size[0] * size[1] * size[2] samples per channel,
  // x fastest, each value <= TypeMax(stored_type)); errors when they do not hold.
  static Result<CpuRaycaster> Create(const std::array<int64_t, 3>& size,
                                     const render::Vec3& spacing_um, volume::DataType stored_type,
                                     std::vector<std::vector<uint16_t>> channels);

  // Renders the volume as seen by `camera` on `threads` threads (0 = one per hardware thread).
  // Errors when `params` is invalid for the volume.
  Result<render::RenderImage> Render(const render::Camera& camera,
                                     const render::RenderParams& params, int threads = 0,
                                     CpuRaycastStats* stats = nullptr) const;

  const std::array<int64_t, 3>& size() const { return size_; }
  const render::Vec3& spacing() const { return spacing_; }
  volume::DataType stored_type() const { return stored_type_; }
  int channel_count() const { return static_cast<int>(channels_.size()); }
  render::Box3 bounds() const { return render::PhysicalBounds(size_, spacing_); }
  // Channel c's samples, x fastest. REQUIRES: 0 <= c < channel_count().
  std::span<const uint16_t> channel(int c) const { return channels_[c]; }

 private:
  CpuRaycaster() = default;

  std::array<int64_t, 3> size_{1, 1, 1};
  render::Vec3 spacing_{1, 1, 1};
  volume::DataType stored_type_ = volume::DataType::kUint16;
  std::vector<std::vector<uint16_t>> channels_;
};

}  // namespace octoscope::bench

#endif  // OCTOSCOPE_BENCH_BASELINE_CPU_RAYCASTER_H_
