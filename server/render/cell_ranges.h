// Cell ranges: per-channel value ranges of the 8^3-voxel cells of a stored brick, so a ray
// caster can skip the parts of a resident brick that cannot change the ray (DVR: every enabled
// channel maps to zero opacity; MIP/MinIP: no value beyond the running extremum), the way node
// ranges skip whole subtrees (docs/rendering.md "Cell ranges"; layout: docs/octree_format.md).
//
// Cell c (per axis) of a brick covers the interior voxels [8c, min(8c + 8, bs)). A trilinear
// sample whose brick-local position (interior voxel centres at k + 0.5) lies in that interval
// reads interior voxels 8c - 1 .. 8c + 8, i.e. STORED voxels [8c, min(8c + 9, bs + 1)] (the
// stored brick adds a one-voxel apron: stored = interior + 1). A cell's range is the min and max
// of each channel over that stored window, so every such sample lies inside it.
//
// Words: cells in x-fastest order, channels interleaved: word (cell * C + c) holds channel c's
// min in bits 0..15 and max in bits 16..31 (the node buffer's range word).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_RENDER_CELL_RANGES_H_
#define OCTOSCOPE_RENDER_CELL_RANGES_H_

#include <cstdint>
#include <span>
#include <vector>

#include "octree/brick_geometry.h"

namespace octoscope::render {

// Interior voxels per cell per axis (kernels/node_format.h OCTO_CELL_SIZE).
inline constexpr int kCellSize = 8;

// Cells per axis of a brick: ceil(bs / kCellSize).
octree::Vec3 CellsPerAxis(const octree::BrickGeometry& geometry);
// Cells of one brick (the product of CellsPerAxis).
uint64_t CellsPerBrick(const octree::BrickGeometry& geometry);
// uint32 words of one brick's cell ranges: CellsPerBrick * channels.
uint64_t CellRangeWords(const octree::BrickGeometry& geometry);

// Working memory of ComputeCellRanges, reused across calls (fresh memory per brick would cost
// more in page faults than the computation itself).
struct CellRangeScratch {
  std::vector<uint16_t> z_lo, z_hi, y_lo, y_hi;
};

// Computes the cell ranges of one stored brick given as uint16 samples (the device layout,
// geometry.brick_samples() of them) into `out` (CellRangeWords words).
// REQUIRES: brick.size() == geometry.brick_samples(), out.size() == CellRangeWords(geometry).
void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out, CellRangeScratch* scratch);
// The same with its own scratch memory.
void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_CELL_RANGES_H_
