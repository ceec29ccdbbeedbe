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
  // Mostly low values with rare spikes, so the ranges differ between cells.
  for (uint16_t& v : f.brick) {
    v = static_cast<uint16_t>(rng() % 100 == 0 ? rng() % 65536 : 1000 + rng() % 50);
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
  EXPECT_EQ(CellRangeWords(g), 36u);
}

// Every trilinear footprint of a position inside a cell lies inside the cell's range, and the
// range is tight: its min and max are each read by some position of the cell.
TEST(CellRangesTest, RangesAreTheTrilinearFootprintsOfTheCell) {
  for (const octree::Vec3 bs : {octree::Vec3{16, 16, 16}, octree::Vec3{12, 20, 6}}) {
    for (const int channels : {1, 3}) {
      const Fixture f = Make(bs, channels, 7u + static_cast<uint32_t>(channels + bs[0]));
      const octree::Vec3 cells = CellsPerAxis(f.geometry);
      std::mt19937 rng(1);
      for (int64_t cz = 0; cz < cells[2]; ++cz) {
        for (int64_t cy = 0; cy < cells[1]; ++cy) {
          for (int64_t cx = 0; cx < cells[0]; ++cx) {
            const int64_t cell = (cz * cells[1] + cy) * cells[0] + cx;
            const int64_t c_idx[3] = {cx, cy, cz};
            for (int c = 0; c < channels; ++c) {
              const uint32_t word = f.words[static_cast<size_t>(cell * channels + c)];
              const uint16_t lo = word & 0xffff;
              const uint16_t hi = word >> 16;
              // The window by definition: stored [8c, min(8c + 9, bs + 1)] per axis.
              uint16_t want_lo = 0xffff;
              uint16_t want_hi = 0;
              int64_t first[3];
              int64_t last[3];
              for (int a = 0; a < 3; ++a) {
                first[a] = 8 * c_idx[a];
                last[a] = std::min<int64_t>(8 * c_idx[a] + 9, bs[a] + 1);
              }
              for (int64_t z = first[2]; z <= last[2]; ++z) {
                for (int64_t y = first[1]; y <= last[1]; ++y) {
                  for (int64_t x = first[0]; x <= last[0]; ++x) {
                    want_lo = std::min(want_lo, Stored(f, x, y, z, c));
                    want_hi = std::max(want_hi, Stored(f, x, y, z, c));
                  }
                }
              }
              EXPECT_EQ(lo, want_lo) << "cell " << cell << " channel " << c;
              EXPECT_EQ(hi, want_hi) << "cell " << cell << " channel " << c;
              // Positions in the cell (interior coordinates, voxel centres at k + 0.5) read the
              // stored voxels floor(pos - 0.5) + 1 and the next one on each axis.
              uint16_t seen_lo = 0xffff;
              uint16_t seen_hi = 0;
              for (int trial = 0; trial < 2000; ++trial) {
                int64_t v0[3];
                for (int a = 0; a < 3; ++a) {
                  const double cell_lo = 8.0 * static_cast<double>(c_idx[a]);
                  const double cell_hi = std::min<double>(cell_lo + 8, static_cast<double>(bs[a]));
                  // The corners matter most: a quarter of the trials sit on a cell face.
                  const int pick = static_cast<int>(rng() % 4);
                  const double pos = pick == 0 ? cell_lo
                                     : pick == 1
                                         ? std::nextafter(cell_hi, 0.0)
                                         : cell_lo + (cell_hi - cell_lo) * (rng() / 4294967296.0);
                  v0[a] = static_cast<int64_t>(std::floor(pos - 0.5)) + 1;
                }
                for (int corner = 0; corner < 8; ++corner) {
                  const uint16_t v = Stored(f, v0[0] + (corner & 1), v0[1] + ((corner >> 1) & 1),
                                            v0[2] + ((corner >> 2) & 1), c);
                  EXPECT_GE(v, lo);
                  EXPECT_LE(v, hi);
                  seen_lo = std::min(seen_lo, v);
                  seen_hi = std::max(seen_hi, v);
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

}  // namespace
}  // namespace octoscope::render
