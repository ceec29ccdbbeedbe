// SyntheticEmbryo: Octoscope's built-in demo specimen. A VolumeSource that computes, on demand, a
// multi-channel uint16 volume resembling a fluorescently labelled embryo imaged by light-sheet
// microscopy: an ellipsoidal embryo filling most of the box, in a dark background at camera offset
// (~100-130 counts, low noise).
//   channel 0 "nuclei":    hundreds of bright, blurred ellipsoidal nuclei packed inside the embryo,
//                          brightness varying per nucleus, a few small bright mitotic ones;
//   channel 1 "membranes": thin bright cell outlines (the Voronoi boundaries between nucleus
//                          centres) plus the embryo's outer surface;
//   channel 2 "spots":     sparse, very bright, small spots (like smFISH mRNA dots);
//   channel 3 "reporter":  a transgene-like marker expressed in the nuclei of one region.
// All channels carry camera-like noise (read noise plus signal-dependent shot noise) and a mild
// light-sheet attenuation along x and z.
//
// Structures scale with the volume: nucleus size in voxels is proportional to the largest extent
// (cell spacing ~7% of it, never under 6 voxels, so below ~90 voxels there are fewer, not smaller,
// cells): a 256^3 demo and a 2048^3 one show the same embryo at different resolutions. Everything
// is computed with integer arithmetic from an integer hash of (position, channel, seed), so the
// same options give bit-identical voxels on every machine and every call; ReadSlab computes only
// the slab asked for (tens of nanoseconds per voxel: nuclei and spots sit in small spatial grids,
// so a voxel only looks at its neighbourhood).
//
// Thread safety: thread-safe. After Create() the object is immutable; ReadSlab uses only local
// scratch memory and may run on any number of threads at once.
#ifndef OCTOSCOPE_IO_SYNTHETIC_EMBRYO_H_
#define OCTOSCOPE_IO_SYNTHETIC_EMBRYO_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

struct SyntheticEmbryoOptions {
  std::array<int64_t, 3> size{256, 256, 128};  // Voxels along x, y, z; each 1..kMaxSize.
  int channels = 3;                            // 1..kMaxChannels.
  uint64_t seed = 42;
  // Voxel pitch in micrometres; light-sheet stacks are typically coarser along z.
  std::array<double, 3> spacing_um{0.4, 0.4, 2.0};
  // How much of the box the embryo spans along each axis, in percent (1..100). Small values give
  // a sparse scan: mostly empty background, like a few labelled cells in a large field.
  int embryo_percent = 92;
};

class SyntheticEmbryo final : public VolumeSource {
 public:
  static constexpr int kMaxChannels = 4;
  static constexpr int64_t kMaxSize = 65536;

  // Errors (kInvalidArgument) when a size, the channel count or a spacing is out of range.
  static Result<std::unique_ptr<SyntheticEmbryo>> Create(const SyntheticEmbryoOptions& options);

  const volume::VolumeInfo& info() const override { return info_; }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override;

  // Number of nuclei and spots generated (for tests and the demo's summary).
  int nucleus_count() const;
  int spot_count() const;

  ~SyntheticEmbryo() override;

 private:
  struct Grid;
  struct Nucleus;
  struct Spot;
  struct RowScratch;

  SyntheticEmbryo();
  void Build(const SyntheticEmbryoOptions& options);
  void RenderRow(int channel, int64_t y, int64_t z, RowScratch& scratch, uint16_t* out) const;
  void SplatNuclei(int64_t y, int64_t z, bool reporter_only, RowScratch& scratch) const;
  void SplatSpots(int64_t y, int64_t z, RowScratch& scratch) const;
  void RenderMembranes(int64_t y, int64_t z, RowScratch& scratch) const;
  // Signed distance (in 1/16 voxel) of a voxel from the embryo surface, negative inside; only
  // meaningful near the surface.
  int64_t SurfaceDistance(int64_t x, int64_t y, int64_t z, int64_t r2) const;

  volume::VolumeInfo info_;
  uint64_t seed_ = 0;
  std::array<int64_t, 3> size_{1, 1, 1};
  std::array<int64_t, 3> centre_{};     // Embryo centre, 1/16 voxel.
  std::array<int64_t, 3> semi_axis_{};  // Embryo semi-axes, 1/16 voxel (>= 8).
  // Per axis and voxel index: (position - centre) * kUnit / semi_axis, so that
  // sum of squares < kUnit^2 means "inside the embryo".
  std::array<std::vector<int64_t>, 3> unit_coord_;
  int64_t membrane_half_width_ = 0;  // 1/16 voxel.
  int64_t surface_half_width_ = 0;   // 1/16 voxel.
  // Normalised squared radii (kUnit^2 = surface) between which SurfaceDistance is needed.
  int64_t inner_r2_ = 0;
  int64_t outer_r2_ = 0;

  std::vector<Nucleus> nuclei_;  // One per cell of nucleus_grid_; brightness 0 when not shown.
  int present_nuclei_ = 0;
  std::vector<Spot> spots_;
  std::unique_ptr<Grid> nucleus_grid_;  // Cell -> index into nuclei_.
  std::unique_ptr<Grid> spot_grid_;     // Cell -> index into spots_ (or -1).
  std::vector<int32_t> cell_of_x_;      // Voxel x -> x index of its nucleus_grid_ cell.
  std::vector<int32_t> atten_x_;        // Voxel x -> light-sheet attenuation along x (of 1024).
  // Lookup tables (computed in integers, so identical everywhere).
  std::vector<int32_t> nucleus_profile_;  // By q>>10, q = (distance / radius)^2 * 2^20; 0..1024.
  std::vector<int32_t> noise_sigma_;      // By signal>>4: noise standard deviation * 16.
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_SYNTHETIC_EMBRYO_H_
