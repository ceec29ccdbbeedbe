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

int64_t CellsOn(int64_t bs, int cell_size) { return (bs + cell_size - 1) / cell_size; }

// The coarse cells' words from the fine ones: each coarse cell's range is the union of its (up
// to) 2 x 2 x 2 fine cells' ranges, whose windows make up its own.
void MergeCoarse(const octree::BrickGeometry& geometry, std::span<uint32_t> out) {
  const octree::Vec3 fine = CellsPerAxis(geometry, kCellSize);
  const octree::Vec3 coarse = CellsPerAxis(geometry, kCoarseCellSize);
  const int64_t channels = geometry.channels();
  const uint32_t* fine_words = out.data();
  uint32_t* word = out.data() + CoarseCellOffset(geometry);
  for (int64_t cz = 0; cz < coarse[2]; ++cz) {
    for (int64_t cy = 0; cy < coarse[1]; ++cy) {
      for (int64_t cx = 0; cx < coarse[0]; ++cx) {
        for (int64_t c = 0; c < channels; ++c) {
          uint32_t lo = 0xffff;
          uint32_t hi = 0;
          for (int64_t z = 2 * cz; z < std::min(2 * cz + 2, fine[2]); ++z) {
            for (int64_t y = 2 * cy; y < std::min(2 * cy + 2, fine[1]); ++y) {
              for (int64_t x = 2 * cx; x < std::min(2 * cx + 2, fine[0]); ++x) {
                const uint32_t w = fine_words[((z * fine[1] + y) * fine[0] + x) * channels + c];
                lo = std::min(lo, w & 0xffffu);
                hi = std::max(hi, w >> 16);
              }
            }
          }
          *word++ = lo | (hi << 16);
        }
      }
    }
  }
}

}  // namespace

octree::Vec3 CellsPerAxis(const octree::BrickGeometry& geometry, int cell_size) {
  const octree::Vec3& bs = geometry.brick_size();
  return {CellsOn(bs[0], cell_size), CellsOn(bs[1], cell_size), CellsOn(bs[2], cell_size)};
}

uint64_t CellsPerBrick(const octree::BrickGeometry& geometry, int cell_size) {
  const octree::Vec3 n = CellsPerAxis(geometry, cell_size);
  return static_cast<uint64_t>(n[0] * n[1] * n[2]);
}

uint64_t CoarseCellOffset(const octree::BrickGeometry& geometry) {
  return CellsPerBrick(geometry, kCellSize) * static_cast<uint64_t>(geometry.channels());
}

uint64_t CellRangeWords(const octree::BrickGeometry& geometry) {
  return (CellsPerBrick(geometry, kCellSize) + CellsPerBrick(geometry, kCoarseCellSize)) *
         static_cast<uint64_t>(geometry.channels());
}

// Built for AVX2 too (picked at load time where the CPU has it): the passes are min/max over
// uint16 vectors, twice as wide there.
__attribute__((target_clones("avx2", "default"))) void ComputeCellRanges(
    const octree::BrickGeometry& geometry, std::span<const uint16_t> brick, std::span<uint32_t> out,
    CellRangeScratch* scratch) {
  const octree::Vec3& bs = geometry.brick_size();
  const octree::Vec3 cells = CellsPerAxis(geometry);
  const size_t sy = static_cast<size_t>(bs[1] + 2);
  const size_t channels = static_cast<size_t>(geometry.channels());
  const size_t row = static_cast<size_t>(bs[0] + 2) * channels;  // Samples of one stored row.
  const size_t plane = sy * row;
  // Separable min/max, z then y then x: the first two passes are element-wise over whole
  // contiguous rows (they vectorise and read each sample about once), leaving a small array of
  // cells_z * cells_y rows for the x windows.
  std::vector<uint16_t>& z_lo = scratch->z_lo;
  std::vector<uint16_t>& z_hi = scratch->z_hi;
  z_lo.assign(static_cast<size_t>(cells[2]) * plane, 0xffff);
  z_hi.assign(z_lo.size(), 0);
  for (int64_t cz = 0; cz < cells[2]; ++cz) {
    uint16_t* lo = z_lo.data() + static_cast<size_t>(cz) * plane;
    uint16_t* hi = z_hi.data() + static_cast<size_t>(cz) * plane;
    for (int z = WindowFirst(static_cast<int>(cz)); z <= WindowLast(static_cast<int>(cz), bs[2]);
         ++z) {
      const uint16_t* in = brick.data() + static_cast<size_t>(z) * plane;
      for (size_t i = 0; i < plane; ++i) {
        lo[i] = std::min(lo[i], in[i]);
        hi[i] = std::max(hi[i], in[i]);
      }
    }
  }
  std::vector<uint16_t>& y_lo = scratch->y_lo;
  std::vector<uint16_t>& y_hi = scratch->y_hi;
  y_lo.assign(static_cast<size_t>(cells[2] * cells[1]) * row, 0xffff);
  y_hi.assign(y_lo.size(), 0);
  for (int64_t cz = 0; cz < cells[2]; ++cz) {
    for (int64_t cy = 0; cy < cells[1]; ++cy) {
      const size_t at = static_cast<size_t>(cz * cells[1] + cy) * row;
      uint16_t* lo = y_lo.data() + at;
      uint16_t* hi = y_hi.data() + at;
      for (int y = WindowFirst(static_cast<int>(cy)); y <= WindowLast(static_cast<int>(cy), bs[1]);
           ++y) {
        const size_t from = static_cast<size_t>(cz) * plane + static_cast<size_t>(y) * row;
        for (size_t i = 0; i < row; ++i) {
          lo[i] = std::min(lo[i], z_lo[from + i]);
          hi[i] = std::max(hi[i], z_hi[from + i]);
        }
      }
    }
  }
  uint32_t* word = out.data();  // Cells x fastest, channels interleaved.
  for (int64_t czy = 0; czy < cells[2] * cells[1]; ++czy) {
    const uint16_t* lo = y_lo.data() + static_cast<size_t>(czy) * row;
    const uint16_t* hi = y_hi.data() + static_cast<size_t>(czy) * row;
    for (int64_t cx = 0; cx < cells[0]; ++cx) {
      for (size_t c = 0; c < channels; ++c) {
        uint16_t l = 0xffff;
        uint16_t h = 0;
        for (int x = WindowFirst(static_cast<int>(cx));
             x <= WindowLast(static_cast<int>(cx), bs[0]); ++x) {
          l = std::min(l, lo[static_cast<size_t>(x) * channels + c]);
          h = std::max(h, hi[static_cast<size_t>(x) * channels + c]);
        }
        *word++ = uint32_t{l} | (uint32_t{h} << 16);
      }
    }
  }
  MergeCoarse(geometry, out);
}

void ComputeCellRanges(const octree::BrickGeometry& geometry, std::span<const uint16_t> brick,
                       std::span<uint32_t> out) {
  CellRangeScratch scratch;
  ComputeCellRanges(geometry, brick, out, &scratch);
}

}  // namespace octoscope::render
