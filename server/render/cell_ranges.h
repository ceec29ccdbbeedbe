// Cell ranges: per-channel value ranges of the cells of a stored brick, so a ray caster can skip
// the parts of a resident brick that cannot change the ray (DVR: every enabled channel maps to
// zero opacity; MIP/MinIP: no value beyond the running extremum), the way node ranges skip whole
// subtrees (docs/rendering.md "Cell ranges"; layout: docs/octree_format.md). Two cell sizes:
// fine 8^3-voxel cells (MIP, MinIP) and coarse 16^3 ones (DVR).
//
// Cell c (per axis) of size S covers the interior voxels [Sc, min(Sc + S, bs)). A trilinear
// sample whose brick-local position (interior voxel centres at k + 0.5) lies in that interval
// reads interior voxels Sc - 1 .. Sc + S, i.e. STORED voxels [Sc, min(Sc + S + 1, bs + 1)] (the
// stored brick adds a one-voxel apron: stored = interior + 1). A cell's range is the min and max
// of each channel over that stored window, so every such sample lies inside it. A coarse cell's
// window is the union of its fine cells' windows, so its range is their ranges' union.
//
// Words: the fine cells, then the coarse ones; in each, cells in x-fastest order, channels
// interleaved: word (cell * C + c) holds channel c's min in bits 0..15 and max in bits 16..31 (the
// node buffer's range word).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_RENDER_CELL_RANGES_H_
#define OCTOSCOPE_RENDER_CELL_RANGES_H_

#include <cstdint>
#include <span>
#include <vector>

#include "octree/brick_geometry.h"

namespace octoscope::render {

// Interior voxels per cell per axis, fine and coarse (kernels/node_format.h OCTO_FINE_CELL_SIZE,
// OCTO_COARSE_CELL_SIZE).
inline constexpr int kCellSize = 8;
inline constexpr int kCoarseCellSize = 2 * kCellSize;

// Cells of `cell_size` per axis of a brick: ceil(bs / cell_size).
octree::Vec3 CellsPerAxis(const octree::BrickGeometry& geometry, int cell_size = kCellSize);
// Cells of one brick (the product of CellsPerAxis).
uint64_t CellsPerBrick(const octree::BrickGeometry& geometry, int cell_size = kCellSize);
// Where the coarse cells' words start: CellsPerBrick (fine) * channels.
uint64_t CoarseCellOffset(const octree::BrickGeometry& geometry);
// uint32 words of one brick's cell ranges, fine and coarse: (CellsPerBrick (fine) + CellsPerBrick
// (coarse)) * channels.
uint64_t CellRangeWords(const octree::BrickGeometry& geometry);

// Working memory of ComputeCellRanges, reused across calls (fresh memory per brick would cost
// more in page faults than the computation itself).
struct CellRangeScratch {
  std::vector<uint16_t> z_lo, z_hi, y_lo, y_hi;
};

// Computes the cell ranges of one stored brick given as uint16 samples (the device layout,
// geometry.brick_samples() of them) into `out` (CellRangeWords words: fine, then coarse).
// REQUIRES: brick.size() == geometry.brick_samples(), out.size() == CellRangeWords(geometry).
void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out, CellRangeScratch* scratch);
// The same with its own scratch memory.
void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_CELL_RANGES_H_
