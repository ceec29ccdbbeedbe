#include "render/cell_ranges.h"

#include <algorithm>
#include <vector>

namespace octoscope::render {

namespace {

// The stored-voxel window [first, last] of cell c on an axis of `bs` interior voxels.
int WindowFirst(int c) { return kCellSize * c; }
int WindowLast(int c, int64_t bs) {
  return static_cast<int>(std::min<int64_t>(int64_t{kCellSize} * c + kCellSize + 1, bs + 1));
}

int64_t CellsOn(int64_t bs) { return (bs + kCellSize - 1) / kCellSize; }

}  // namespace

octree::Vec3 CellsPerAxis(const octree::BrickGeometry& geometry) {
  const octree::Vec3& bs = geometry.brick_size();
  return {CellsOn(bs[0]), CellsOn(bs[1]), CellsOn(bs[2])};
}

uint64_t CellsPerBrick(const octree::BrickGeometry& geometry) {
  const octree::Vec3 n = CellsPerAxis(geometry);
  return static_cast<uint64_t>(n[0] * n[1] * n[2]);
}

uint64_t CellRangeWords(const octree::BrickGeometry& geometry) {
  return CellsPerBrick(geometry) * static_cast<uint64_t>(geometry.channels());
}

void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out) {
  const octree::Vec3& bs = geometry.brick_size();
  const octree::Vec3 cells = CellsPerAxis(geometry);
  const int64_t sx = bs[0] + 2;
  const int64_t sy = bs[1] + 2;
  const int64_t sz = bs[2] + 2;
  const int64_t channels = geometry.channels();
  // Separable min/max: reduce x windows per stored row, then y windows, then z windows; each
  // pass shrinks one axis from stored voxels to cells. Values as (min, max) pairs.
  struct Range {
    uint16_t lo;
    uint16_t hi;
  };
  std::vector<Range> by_x(static_cast<size_t>(sz * sy * cells[0] * channels));
  for (int64_t row = 0; row < sz * sy; ++row) {
    const uint16_t* in = brick.data() + row * sx * channels;
    for (int64_t cx = 0; cx < cells[0]; ++cx) {
      Range* r = &by_x[static_cast<size_t>((row * cells[0] + cx) * channels)];
      for (int64_t c = 0; c < channels; ++c) r[c] = {0xffff, 0};
      for (int64_t x = WindowFirst(static_cast<int>(cx));
           x <= WindowLast(static_cast<int>(cx), bs[0]); ++x) {
        for (int64_t c = 0; c < channels; ++c) {
          const uint16_t v = in[x * channels + c];
          r[c].lo = std::min(r[c].lo, v);
          r[c].hi = std::max(r[c].hi, v);
        }
      }
    }
  }
  const int64_t row_ranges = cells[0] * channels;  // Ranges of one (z, y) row after the x pass.
  std::vector<Range> by_y(static_cast<size_t>(sz * cells[1] * row_ranges));
  for (int64_t z = 0; z < sz; ++z) {
    for (int64_t cy = 0; cy < cells[1]; ++cy) {
      Range* r = &by_y[static_cast<size_t>((z * cells[1] + cy) * row_ranges)];
      for (int64_t k = 0; k < row_ranges; ++k) r[k] = {0xffff, 0};
      for (int64_t y = WindowFirst(static_cast<int>(cy));
           y <= WindowLast(static_cast<int>(cy), bs[1]); ++y) {
        const Range* in = &by_x[static_cast<size_t>((z * sy + y) * row_ranges)];
        for (int64_t k = 0; k < row_ranges; ++k) {
          r[k].lo = std::min(r[k].lo, in[k].lo);
          r[k].hi = std::max(r[k].hi, in[k].hi);
        }
      }
    }
  }
  const int64_t slab_ranges = cells[1] * row_ranges;  // Ranges of one z plane after the y pass.
  std::vector<Range> r(static_cast<size_t>(slab_ranges));
  for (int64_t cz = 0; cz < cells[2]; ++cz) {
    uint32_t* words = out.data() + cz * slab_ranges;
    std::fill(r.begin(), r.end(), Range{0xffff, 0});
    for (int64_t z = WindowFirst(static_cast<int>(cz));
         z <= WindowLast(static_cast<int>(cz), bs[2]); ++z) {
      const Range* in = &by_y[static_cast<size_t>(z * slab_ranges)];
      for (int64_t k = 0; k < slab_ranges; ++k) {
        r[k].lo = std::min(r[k].lo, in[k].lo);
        r[k].hi = std::max(r[k].hi, in[k].hi);
      }
    }
    for (int64_t k = 0; k < slab_ranges; ++k) {
      words[k] = uint32_t{r[k].lo} | (uint32_t{r[k].hi} << 16);
    }
  }
}

}  // namespace octoscope::render
