// Cell ranges (server/render/cell_ranges.h) against brute force: each cell's range is the min and
// max over the stored voxels that a trilinear sample anywhere in the cell reads, found here by
// sampling many positions in every cell and recording the 8 voxels each one interpolates, and
// by scanning the stored window straight from its definition.
#include "render/cell_ranges.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace octoscope::render {
namespace {

octree::BrickGeometry Geometry(octree::Vec3 brick, int channels) {
  octree::BrickGeometry::Params params;
  params.volume_size = {256, 256, 256};
  params.brick_size = brick;
  params.channels = channels;
  return octree::BrickGeometry::Create(params).value();
}

struct Fixture {
  octree::BrickGeometry geometry;
  std::vector<uint16_t> brick;
  std::vector<uint32_t> words;
};

Fixture Make(octree::Vec3 bs, int channels, uint32_t seed) {
  Fixture f{Geometry(bs, channels), {}, {}};
  std::mt19937 rng(seed);
  f.brick.resize(f.geometry.brick_samples());
  // Mostly middling values with rare spikes up and down, so both ends of the ranges differ
  // between cells.
  for (uint16_t& v : f.brick) {
    const uint32_t pick = rng() % 100;
    v = static_cast<uint16_t>(pick == 0   ? 1050 + rng() % 64486
                              : pick == 1 ? rng() % 1000
                                          : 1000 + rng() % 50);
  }
  f.words.assign(CellRangeWords(f.geometry), 0xdeadbeef);
  ComputeCellRanges(f.geometry, f.brick, f.words);
  return f;
}

uint16_t Stored(const Fixture& f, int64_t x, int64_t y, int64_t z, int c) {
  const octree::Vec3 s = f.geometry.stored_size();
  return f.brick[static_cast<size_t>(((z * s[1] + y) * s[0] + x) * f.geometry.channels() + c)];
}

TEST(CellRangesTest, CountsFollowTheBrickSize) {
  const octree::BrickGeometry g = Geometry({32, 20, 6}, 3);
  EXPECT_EQ(CellsPerAxis(g), (octree::Vec3{4, 3, 1}));
  EXPECT_EQ(CellsPerBrick(g), 12u);
  EXPECT_EQ(CellsPerAxis(g, kCoarseCellSize), (octree::Vec3{2, 2, 1}));
  EXPECT_EQ(CellsPerBrick(g, kCoarseCellSize), 4u);
  EXPECT_EQ(CoarseCellOffset(g), 36u);
  EXPECT_EQ(CellRangeWords(g), 48u);
}

// Every trilinear footprint of a position inside a cell lies inside the cell's range, and the
// range is tight: its min and max are each read by some position of the cell. Fine and coarse
// cells alike, on brick sizes that are and are not multiples of either.
TEST(CellRangesTest, RangesAreTheTrilinearFootprintsOfTheCell) {
  for (const octree::Vec3 bs :
       {octree::Vec3{16, 16, 16}, octree::Vec3{12, 20, 6}, octree::Vec3{40, 32, 18}}) {
    for (const int channels : {1, 3}) {
      for (const int size : {kCellSize, kCoarseCellSize}) {
        const Fixture f = Make(bs, channels, 7u + static_cast<uint32_t>(channels + bs[0]));
        const octree::Vec3 cells = CellsPerAxis(f.geometry, size);
        const size_t offset = size == kCellSize ? 0 : CoarseCellOffset(f.geometry);
        for (int64_t cz = 0; cz < cells[2]; ++cz) {
          for (int64_t cy = 0; cy < cells[1]; ++cy) {
            for (int64_t cx = 0; cx < cells[0]; ++cx) {
              const int64_t cell = (cz * cells[1] + cy) * cells[0] + cx;
              const int64_t c_idx[3] = {cx, cy, cz};
              for (int c = 0; c < channels; ++c) {
                const uint32_t word = f.words[offset + static_cast<size_t>(cell * channels + c)];
                const uint16_t lo = word & 0xffff;
                const uint16_t hi = word >> 16;
                // The window by definition: stored [Sc, min(Sc + S + 1, bs + 1)] per axis.
                uint16_t want_lo = 0xffff;
                uint16_t want_hi = 0;
                int64_t first[3];
                int64_t last[3];
                for (int a = 0; a < 3; ++a) {
                  first[a] = size * c_idx[a];
                  last[a] = std::min<int64_t>(size * c_idx[a] + size + 1, bs[a] + 1);
                }
                for (int64_t z = first[2]; z <= last[2]; ++z) {
                  for (int64_t y = first[1]; y <= last[1]; ++y) {
                    for (int64_t x = first[0]; x <= last[0]; ++x) {
                      want_lo = std::min(want_lo, Stored(f, x, y, z, c));
                      want_hi = std::max(want_hi, Stored(f, x, y, z, c));
                    }
                  }
                }
                EXPECT_EQ(lo, want_lo) << "size " << size << " cell " << cell << " channel " << c;
                EXPECT_EQ(hi, want_hi) << "size " << size << " cell " << cell << " channel " << c;
                // Positions in the cell (interior coordinates, voxel centres at k + 0.5) read the
                // stored voxels floor(pos - 0.5) + 1 and the next one on each axis.
                uint16_t seen_lo = 0xffff;
                uint16_t seen_hi = 0;
                // Positions on a grid that reaches every voxel a position of the cell reads:
                // both faces (the far one just inside) and a quarter either side of each voxel
                // centre line.
                std::vector<double> pos[3];
                for (int a = 0; a < 3; ++a) {
                  const double cell_lo = size * static_cast<double>(c_idx[a]);
                  const double cell_hi =
                      std::min<double>(cell_lo + size, static_cast<double>(bs[a]));
                  pos[a] = {cell_lo, std::nextafter(cell_hi, 0.0)};
                  for (double p = cell_lo; p < cell_hi; p += 1.0) {
                    pos[a].push_back(p + 0.25);
                    pos[a].push_back(p + 0.75);
                  }
                }
                for (const double pz : pos[2]) {
                  for (const double py : pos[1]) {
                    for (const double px : pos[0]) {
                      const int64_t v0[3] = {static_cast<int64_t>(std::floor(px - 0.5)) + 1,
                                             static_cast<int64_t>(std::floor(py - 0.5)) + 1,
                                             static_cast<int64_t>(std::floor(pz - 0.5)) + 1};
                      for (int corner = 0; corner < 8; ++corner) {
                        const uint16_t v =
                            Stored(f, v0[0] + (corner & 1), v0[1] + ((corner >> 1) & 1),
                                   v0[2] + ((corner >> 2) & 1), c);
                        ASSERT_GE(v, lo);
                        ASSERT_LE(v, hi);
                        seen_lo = std::min(seen_lo, v);
                        seen_hi = std::max(seen_hi, v);
                      }
                    }
                  }
                }
                EXPECT_EQ(seen_lo, lo) << "cell " << cell << ": the range is not tight";
                EXPECT_EQ(seen_hi, hi) << "cell " << cell << ": the range is not tight";
              }
            }
          }
        }
      }
    }
  }
}

}  // namespace
}  // namespace octoscope::render
