#include "octree/write_coverage.h"

#include <algorithm>
#include <bit>
#include <string>
#include <utility>

#include "octree/binary_stream.h"

namespace octoscope::octree {
namespace {

uint64_t Words(uint64_t bits) { return (bits + 63) / 64; }

bool TestBit(const std::vector<uint64_t>& words, uint64_t i) {
  return ((words[i / 64] >> (i % 64)) & 1) != 0;
}

void SetBit(std::vector<uint64_t>& words, uint64_t i) { words[i / 64] |= uint64_t{1} << (i % 64); }

uint64_t PopCount(const std::vector<uint64_t>& words) {
  uint64_t n = 0;
  for (uint64_t w : words) n += static_cast<uint64_t>(std::popcount(w));
  return n;
}

}  // namespace

WriteCoverage::WriteCoverage(const Vec3& extent)
    : extent_(extent),
      rows_(static_cast<uint64_t>(extent[1]) * static_cast<uint64_t>(extent[2])),
      full_(Words(rows_), 0) {}

void WriteCoverage::Mark(const Box& local) {
  Box b = local.Intersect(Box{{0, 0, 0}, extent_});
  if (b.empty()) return;
  const int64_t nx = extent_[0];
  const bool whole_rows = b.lo[0] == 0 && b.hi[0] == nx;
  for (int64_t z = b.lo[2]; z < b.hi[2]; ++z) {
    for (int64_t y = b.lo[1]; y < b.hi[1]; ++y) {
      const uint64_t row = static_cast<uint64_t>(z * extent_[1] + y);
      if (TestBit(full_, row)) continue;
      bool now_full = whole_rows;
      if (!whole_rows) {
        // A partially written row keeps an exact x-bitmap until it fills up.
        std::vector<uint64_t>& bits = partial_[static_cast<uint32_t>(row)];
        if (bits.empty()) bits.assign(Words(static_cast<uint64_t>(nx)), 0);
        for (int64_t x = b.lo[0]; x < b.hi[0]; ++x) SetBit(bits, static_cast<uint64_t>(x));
        now_full = PopCount(bits) == static_cast<uint64_t>(nx);
      }
      if (now_full) {
        partial_.erase(static_cast<uint32_t>(row));
        SetBit(full_, row);
        ++full_count_;
      }
    }
  }
}

uint64_t WriteCoverage::WrittenVoxels() const {
  uint64_t n = full_count_ * static_cast<uint64_t>(extent_[0]);
  for (const auto& [row, bits] : partial_) n += PopCount(bits);
  return n;
}

void WriteCoverage::Save(std::ostream& out) const {
  for (uint64_t w : full_) PutLe<uint64_t>(out, w);
  PutLe<uint32_t>(out, static_cast<uint32_t>(partial_.size()));
  for (const auto& [row, bits] : partial_) {
    PutLe<uint32_t>(out, row);
    for (uint64_t w : bits) PutLe<uint64_t>(out, w);
  }
}

Result<WriteCoverage> WriteCoverage::Load(std::istream& in, const Vec3& extent) {
  WriteCoverage c(extent);
  BinaryReader r(in);
  for (uint64_t& w : c.full_) w = r.Get<uint64_t>();
  // Bits past the last row must be clear.
  if (c.rows_ % 64 != 0 && !c.full_.empty() && (c.full_.back() >> (c.rows_ % 64)) != 0) {
    return CorruptError("write coverage: full-row bits beyond the box");
  }
  c.full_count_ = PopCount(c.full_);
  const uint32_t partial_count = r.Get<uint32_t>();
  if (!r.ok()) return CorruptError("write coverage: truncated");
  if (partial_count > c.rows_ - c.full_count_) {
    return CorruptError("write coverage: " + std::to_string(partial_count) +
                        " partial rows, more than the box has unfinished rows");
  }
  const uint64_t nx = static_cast<uint64_t>(extent[0]);
  for (uint32_t i = 0; i < partial_count; ++i) {
    const uint32_t row = r.Get<uint32_t>();
    std::vector<uint64_t> bits(Words(nx));
    for (uint64_t& w : bits) w = r.Get<uint64_t>();
    if (!r.ok()) return CorruptError("write coverage: truncated");
    const uint64_t ones = PopCount(bits);
    if (row >= c.rows_ || TestBit(c.full_, row) || c.partial_.count(row) != 0 || ones == 0 ||
        ones >= nx || (nx % 64 != 0 && (bits.back() >> (nx % 64)) != 0)) {
      return CorruptError("write coverage: inconsistent partial row " + std::to_string(row));
    }
    c.partial_.emplace(row, std::move(bits));
  }
  return c;
}

}  // namespace octoscope::octree
