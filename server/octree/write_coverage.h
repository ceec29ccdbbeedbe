// WriteCoverage: which voxels of one box have been written at least once — the completeness
// tracker of one leaf brick and one channel (docs/octree_format.md, "Node table"). The octree
// prunes a node only when it is COMPLETE (every valid voxel written in every channel), which is
// what makes the final structure independent of insertion order and block shapes.
//
// Representation (cheap for the common slab/block inserts): one bit per (y, z) ROW of the box
// that is fully written, plus an exact x-bitmap only for rows written partially so far; a
// row's x-bitmap is dropped the moment the row becomes full. A box of nx*ny*nz voxels costs
// ny*nz bits plus nx bits per partially written row.
//
// Invariants: full_count_ == popcount(full_); a row is never both full and in partial_; every
// x-bitmap in partial_ has at least one bit clear among its nx bits.
//
// Thread safety: a plain value; the owner serialises access.
#ifndef OCTOSCOPE_OCTREE_WRITE_COVERAGE_H_
#define OCTOSCOPE_OCTREE_WRITE_COVERAGE_H_

#include <cstdint>
#include <istream>
#include <map>
#include <ostream>
#include <vector>

#include "octree/brick_geometry.h"
#include "util/result.h"

namespace octoscope::octree {

class WriteCoverage {
 public:
  // Tracks the box [0, extent). REQUIRES: 1 <= extent[a] <= kMaxBrickAxis.
  explicit WriteCoverage(const Vec3& extent);

  // Marks the voxels of `local` (clipped to [0, extent)) as written.
  void Mark(const Box& local);
  bool complete() const { return full_count_ == rows_; }
  const Vec3& extent() const { return extent_; }
  // Voxels written so far (for tests and diagnostics).
  uint64_t WrittenVoxels() const;

  // Binary form (little-endian): u64 full-row words, u32 partial rows, then per partial row
  // u32 row index and its x words. The extent is not stored: the reader passes it.
  void Save(std::ostream& out) const;
  // kCorrupt on a truncated or inconsistent record.
  static Result<WriteCoverage> Load(std::istream& in, const Vec3& extent);

  bool operator==(const WriteCoverage&) const = default;

 private:
  Vec3 extent_;
  uint64_t rows_ = 0;  // ny * nz.
  std::vector<uint64_t> full_;
  uint64_t full_count_ = 0;
  std::map<uint32_t, std::vector<uint64_t>> partial_;  // Ordered: deterministic Save.
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_WRITE_COVERAGE_H_
