// The CPU reference renderer: an independent, deliberately simple implementation of every
// rendering feature, in double precision, straight from the full-resolution volume (no octree, no
// bricks, no levels of detail, no OpenCL). Tests and benchmarks compare the GPU renderer with it:
// the GPU is never its own oracle. All definitions (coordinates, transfer functions, compositing)
// are those of render/render_params.h and render/camera.h.
//
// Per ray (one per pixel centre):
//  1. Intersect the half-line with the volume box [0, n s] (faces inclusive), then clip that
//     interval analytically by each clipping plane; an empty interval gives the background.
//  2. Walk the interval in segments of step_voxels measured in voxel index space (physical length
//     dt = step_voxels / |direction / spacing|); the last segment is shortened to end exactly at
//     the exit. Sample i sits at the midpoint of its segment, computed as entry + (i + 0.5) * dt
//     (never accumulated), so an axis-aligned ray through voxel centres with step 1 samples
//     exactly the voxel centres.
//  3. Each enabled channel reads its volume at transform * p with trilinear interpolation of the
//     stored values (clamp to edge: positions between the box face and the outermost voxel centre
//     take the edge value). Disabled channels are never read.
//  4. Composite per RenderParams::mode (see render_params.h); DVR opacity is corrected with the
//     segment's physical length relative to the smallest spacing.
// Output pixels are RGBA floats in [0, 1], premultiplied (DVR over the background) and never
// NaN or Inf. MIP/MinIP pixels have alpha 1 where some channel was sampled, else the background's.
// Rendering is deterministic: identical inputs give bit-identical images.
//
// Thread safety: ReferenceVolume is immutable after construction and may be shared; RenderReference
// is reentrant (it reads its inputs only).
#ifndef OCTOSCOPE_RENDER_REFERENCE_RENDERER_H_
#define OCTOSCOPE_RENDER_REFERENCE_RENDERER_H_

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "io/volume_source.h"
#include "render/camera.h"
#include "render/linear_algebra.h"
#include "render/render_image.h"
#include "render/render_params.h"
#include "util/result.h"
#include "volume/data_type.h"
#include "volume/value_map.h"

namespace octoscope::render {

// A whole multi-channel volume in RAM as stored values (uint8 or uint16 samples, held as
// uint16). Invariants: every size >= 1; spacing finite and > 0; one vector of
// size[0] * size[1] * size[2] samples per channel (x fastest, then y, then z), each value <=
// TypeMax(stored_type); at least one channel.
class ReferenceVolume {
 public:
  // Errors when the invariants above do not hold.
  static Result<ReferenceVolume> FromStored(const std::array<int64_t, 3>& size,
                                            const Vec3& spacing_um, volume::DataType stored_type,
                                            std::vector<std::vector<uint16_t>> channels);

  // Reads all of `source` (one plane at a time) and converts it to stored values with
  // maps[channel]; spacing from source.info() (unknown axes count as 1 µm). Errors when the maps
  // do not match the source (count, file type, stored type uint8/uint16), when the stored volume
  // would exceed `max_bytes`, or when a read fails.
  static Result<ReferenceVolume> Load(io::VolumeSource& source,
                                      const std::vector<volume::ValueMap>& maps,
                                      uint64_t max_bytes = uint64_t{1} << 30);

  const std::array<int64_t, 3>& size() const { return size_; }
  const Vec3& spacing() const { return spacing_; }
  volume::DataType stored_type() const { return stored_type_; }
  int channel_count() const { return static_cast<int>(channels_.size()); }
  Box3 bounds() const { return PhysicalBounds(size_, spacing_); }

  // REQUIRES: indices in range.
  uint16_t Value(int channel, int64_t x, int64_t y, int64_t z) const {
    return channels_[channel][static_cast<size_t>((z * size_[1] + y) * size_[0] + x)];
  }

  // Channel `channel`'s stored values, x fastest. REQUIRES: 0 <= channel < channel_count().
  std::span<const uint16_t> channel_data(int channel) const { return channels_[channel]; }

  // Trilinear interpolation of `channel` at physical position p, clamped to the edge voxels.
  // REQUIRES: p finite.
  double Sample(int channel, const Vec3& p) const;

 private:
  ReferenceVolume() = default;

  std::array<int64_t, 3> size_{1, 1, 1};
  Vec3 spacing_{1, 1, 1};
  volume::DataType stored_type_ = volume::DataType::kUint16;
  std::vector<std::vector<uint16_t>> channels_;
};

// The parameter interval [t_enter, t_exit] (t >= 0) in which `ray` lies inside `box` (faces
// inclusive) and on the kept side of every clipping plane; nullopt when it is empty or a single
// point. Exact for rays parallel to box faces or planes (no division by zero).
std::optional<std::pair<double, double>> ClipRayToVolume(const Ray& ray, const Box3& box,
                                                         const std::vector<ClipPlane>& planes);

// Renders `volume` as seen by `camera`. Errors when `params` is invalid for the volume.
Result<RenderImage> RenderReference(const ReferenceVolume& volume, const Camera& camera,
                                    const RenderParams& params, RenderStats* stats = nullptr);

// Loads `source` with ReferenceVolume::Load, then renders it.
Result<RenderImage> RenderReference(io::VolumeSource& source,
                                    const std::vector<volume::ValueMap>& maps, const Camera& camera,
                                    const RenderParams& params, RenderStats* stats = nullptr);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_REFERENCE_RENDERER_H_
