#include "octree/brick_geometry.h"

#include <algorithm>
#include <array>
#include <initializer_list>
#include <optional>
#include <string_view>
#include <vector>

#include "octree/node_encoding.h"
#include "util/checked_math.h"

namespace octoscope::octree {
namespace {

// Concatenation by appending (GCC 12 reports false -Wrestrict positives for "lit" + string).
std::string Cat(std::initializer_list<std::string_view> parts) {
  std::string s;
  for (std::string_view p : parts) s.append(p);
  return s;
}

std::string Str(int64_t v) { return std::to_string(v); }

}  // namespace

// ---- Box ------------------------------------------------------------------------------------

uint64_t Box::VoxelCount() const {
  if (empty()) return 0;
  const std::optional<uint64_t> n =
      CheckedProduct({static_cast<uint64_t>(hi[0] - lo[0]), static_cast<uint64_t>(hi[1] - lo[1]),
                      static_cast<uint64_t>(hi[2] - lo[2])});
  return n ? *n : UINT64_MAX;
}

bool Box::Contains(const Vec3& p) const {
  for (int a = 0; a < 3; ++a) {
    if (p[a] < lo[a] || p[a] >= hi[a]) return false;
  }
  return true;
}

bool Box::ContainsBox(const Box& other) const {
  if (other.empty()) return true;
  for (int a = 0; a < 3; ++a) {
    if (other.lo[a] < lo[a] || other.hi[a] > hi[a]) return false;
  }
  return true;
}

Box Box::Intersect(const Box& other) const {
  Box r;
  for (int a = 0; a < 3; ++a) {
    r.lo[a] = std::max(lo[a], other.lo[a]);
    r.hi[a] = std::min(hi[a], other.hi[a]);
  }
  return r;
}

Box Box::Dilate(int64_t d) const {
  if (empty()) return Box{};
  Box r;
  for (int a = 0; a < 3; ++a) {
    r.lo[a] = lo[a] - d;
    r.hi[a] = hi[a] + d;
  }
  return r;
}

std::string Box::ToString() const {
  return Cat({"[", Str(lo[0]), ",", Str(hi[0]), ")x[", Str(lo[1]), ",", Str(hi[1]), ")x[",
              Str(lo[2]), ",", Str(hi[2]), ")"});
}

int64_t FloorDiv(int64_t n, int64_t d) {
  int64_t q = n / d;
  // C++ division truncates toward zero; step down for negative non-exact quotients.
  if (n % d != 0 && n < 0) --q;
  return q;
}

int64_t CeilDiv(int64_t n, int64_t d) {
  int64_t q = n / d;
  if (n % d != 0 && n > 0) ++q;
  return q;
}

Box CoarsenBox(const Box& box, int s) {
  if (box.empty()) return Box{};
  const int64_t d = int64_t{1} << s;
  Box r;
  for (int a = 0; a < 3; ++a) {
    r.lo[a] = FloorDiv(box.lo[a], d);
    r.hi[a] = CeilDiv(box.hi[a], d);
  }
  return r;
}

Box RefineBox(const Box& box, int s) {
  if (box.empty()) return Box{};
  const int64_t m = int64_t{1} << s;
  Box r;
  for (int a = 0; a < 3; ++a) {
    // Multiplication, not <<, so negative (apron) coordinates are well defined in every dialect.
    r.lo[a] = box.lo[a] * m;
    r.hi[a] = box.hi[a] * m;
  }
  return r;
}

// ---- NodeKey --------------------------------------------------------------------------------

std::string NodeKey::ToString() const {
  return Cat({"L", Str(level), "(", Str(index[0]), ",", Str(index[1]), ",", Str(index[2]), ")"});
}

int OctantOf(const NodeKey& key) {
  return static_cast<int>((key.index[0] & 1) | ((key.index[1] & 1) << 1) |
                          ((key.index[2] & 1) << 2));
}

NodeKey ChildKey(const NodeKey& key, int octant) {
  NodeKey c;
  c.level = key.level - 1;
  for (int a = 0; a < 3; ++a) c.index[a] = 2 * key.index[a] + ((octant >> a) & 1);
  return c;
}

NodeKey ParentKey(const NodeKey& key) {
  NodeKey p;
  p.level = key.level + 1;
  for (int a = 0; a < 3; ++a) p.index[a] = key.index[a] >> 1;
  return p;
}

size_t NodeKeyHash::operator()(const NodeKey& key) const {
  // Indices are < 2^15 and levels < 16: pack into 64 bits, then mix (splitmix64 finaliser) so
  // that neighbouring keys spread over buckets.
  uint64_t h = (static_cast<uint64_t>(key.level) << 60) ^
               (static_cast<uint64_t>(key.index[0]) << 40) ^
               (static_cast<uint64_t>(key.index[1]) << 20) ^ static_cast<uint64_t>(key.index[2]);
  h ^= h >> 30;
  h *= 0xbf58476d1ce4e5b9ULL;
  h ^= h >> 27;
  h *= 0x94d049bb133111ebULL;
  h ^= h >> 31;
  return static_cast<size_t>(h);
}

// ---- BrickGeometry --------------------------------------------------------------------------

Result<BrickGeometry> BrickGeometry::Create(const Params& params) {
  static constexpr std::string_view kAxis[3] = {"x", "y", "z"};
  for (int a = 0; a < 3; ++a) {
    const int64_t s = params.volume_size[a];
    if (s < 1 || s > kMaxVolumeAxis) {
      return InvalidArgumentError(Cat({"brick geometry: volume size ", kAxis[a], " = ", Str(s),
                                       " is outside 1..", Str(kMaxVolumeAxis)}));
    }
    const int64_t b = params.brick_size[a];
    if (b < 2 || b > kMaxBrickAxis || b % 2 != 0) {
      return InvalidArgumentError(Cat({"brick geometry: brick size ", kAxis[a], " = ", Str(b),
                                       " must be even and within 2..", Str(kMaxBrickAxis)}));
    }
  }
  if (params.channels < 1 || params.channels > kMaxChannels) {
    return InvalidArgumentError(Cat(
        {"brick geometry: ", Str(params.channels), " channels, expected 1..", Str(kMaxChannels)}));
  }
  if (params.bytes_per_sample != 1 && params.bytes_per_sample != 2) {
    return InvalidArgumentError(Cat({"brick geometry: ", Str(params.bytes_per_sample),
                                     " bytes per sample, expected 1 (uint8) or 2 (uint16)"}));
  }
  // All factors are small here (<= 1026 each, <= 64 channels), but check anyway: this is the
  // size every brick allocation uses.
  const std::optional<uint64_t> bytes = CheckedProduct(
      {static_cast<uint64_t>(params.brick_size[0] + 2),
       static_cast<uint64_t>(params.brick_size[1] + 2),
       static_cast<uint64_t>(params.brick_size[2] + 2), static_cast<uint64_t>(params.channels),
       static_cast<uint64_t>(params.bytes_per_sample)});
  if (!bytes || *bytes > kMaxBrickBytes) {
    return InvalidArgumentError(
        Cat({"brick geometry: a stored brick of ", Str(params.brick_size[0] + 2), "x",
             Str(params.brick_size[1] + 2), "x", Str(params.brick_size[2] + 2), " voxels x ",
             Str(params.channels), " channels x ", Str(params.bytes_per_sample), " bytes exceeds ",
             Str(static_cast<int64_t>(kMaxBrickBytes)), " bytes"}));
  }

  BrickGeometry g;
  g.volume_size_ = params.volume_size;
  g.brick_size_ = params.brick_size;
  g.channels_ = params.channels;
  g.bytes_per_sample_ = params.bytes_per_sample;
  // Smallest R with bs * 2^R >= size on every axis. size <= 2^16 and bs >= 2 bound R by 15.
  int r = 0;
  for (int a = 0; a < 3; ++a) {
    while ((params.brick_size[a] << r) < params.volume_size[a]) ++r;
  }
  g.root_level_ = r;
  return g;
}

Vec3 BrickGeometry::LevelSize(int level) const {
  const int64_t d = int64_t{1} << level;
  return {CeilDiv(volume_size_[0], d), CeilDiv(volume_size_[1], d), CeilDiv(volume_size_[2], d)};
}

Box BrickGeometry::ValidExtent(int level) const { return Box{{0, 0, 0}, LevelSize(level)}; }

int64_t BrickGeometry::NodesPerAxis(int level) const { return int64_t{1} << (root_level_ - level); }

Box BrickGeometry::NodeGrid(int level) const {
  const int64_t n = NodesPerAxis(level);
  return Box{{0, 0, 0}, {n, n, n}};
}

Box BrickGeometry::NonVirtualNodes(int level) const {
  const Vec3 size = LevelSize(level);
  return Box{{0, 0, 0},
             {CeilDiv(size[0], brick_size_[0]), CeilDiv(size[1], brick_size_[1]),
              CeilDiv(size[2], brick_size_[2])}};
}

uint64_t BrickGeometry::MaxNodeCount() const {
  uint64_t total = 0;
  // 8^(R-L) summed over L = 0..R; with R <= 15 the largest term is 2^45.
  for (int level = 0; level <= root_level_; ++level)
    total += uint64_t{1} << (3 * (root_level_ - level));
  return total;
}

bool BrickGeometry::IsValidKey(const NodeKey& key) const {
  if (key.level < 0 || key.level > root_level_) return false;
  return NodeGrid(key.level).Contains(key.index);
}

NodeKey BrickGeometry::NodeContaining(int level, const Vec3& p) const {
  return NodeKey{level, {p[0] / brick_size_[0], p[1] / brick_size_[1], p[2] / brick_size_[2]}};
}

Box BrickGeometry::NodeBox(const NodeKey& key) const {
  Box b;
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = key.index[a] * brick_size_[a];
    b.hi[a] = b.lo[a] + brick_size_[a];
  }
  return b;
}

Box BrickGeometry::NodeBoxLevel0(const NodeKey& key) const {
  return RefineBox(NodeBox(key), key.level);
}

Box BrickGeometry::StoredBox(const NodeKey& key) const { return NodeBox(key).Dilate(1); }

Box BrickGeometry::ValidBox(const NodeKey& key) const {
  return NodeBox(key).Intersect(ValidExtent(key.level));
}

Box BrickGeometry::StoredValidBox(const NodeKey& key) const {
  return StoredBox(key).Intersect(ValidExtent(key.level));
}

bool BrickGeometry::IsVirtual(const NodeKey& key) const { return ValidBox(key).empty(); }

Box BrickGeometry::NodesIntersecting(int level, const Box& box) const {
  if (box.empty()) return Box{};
  const int64_t n = NodesPerAxis(level);
  Box r;
  for (int a = 0; a < 3; ++a) {
    // Node i covers [i*bs, (i+1)*bs): it meets [lo, hi) iff floor(lo/bs) <= i < ceil(hi/bs).
    r.lo[a] = std::clamp<int64_t>(FloorDiv(box.lo[a], brick_size_[a]), 0, n);
    r.hi[a] = std::clamp<int64_t>(CeilDiv(box.hi[a], brick_size_[a]), 0, n);
  }
  if (r.empty()) return Box{};
  return r;
}

Box BrickGeometry::NodesStoringAny(int level, const Box& box) const {
  // A stored box is the interior dilated by 1, so it meets `box` iff the interior meets `box`
  // dilated by 1.
  return NodesIntersecting(level, box.Dilate(1));
}

uint64_t BrickGeometry::brick_voxels() const {
  const Vec3 s = stored_size();
  return static_cast<uint64_t>(s[0]) * static_cast<uint64_t>(s[1]) * static_cast<uint64_t>(s[2]);
}

uint64_t BrickGeometry::LocalSampleOffset(const Vec3& local, int c) const {
  const uint64_t sx = static_cast<uint64_t>(brick_size_[0] + 2);
  const uint64_t sy = static_cast<uint64_t>(brick_size_[1] + 2);
  const uint64_t voxel =
      (static_cast<uint64_t>(local[2]) * sy + static_cast<uint64_t>(local[1])) * sx +
      static_cast<uint64_t>(local[0]);
  return voxel * static_cast<uint64_t>(channels_) + static_cast<uint64_t>(c);
}

uint64_t BrickGeometry::StoredSampleOffset(const NodeKey& key, const Vec3& p, int c) const {
  Vec3 local;
  for (int a = 0; a < 3; ++a) local[a] = p[a] - (key.index[a] * brick_size_[a] - 1);
  return LocalSampleOffset(local, c);
}

std::string BrickGeometry::ToString() const {
  return Cat({"volume ", Str(volume_size_[0]), "x", Str(volume_size_[1]), "x", Str(volume_size_[2]),
              ", brick ", Str(brick_size_[0]), "x", Str(brick_size_[1]), "x", Str(brick_size_[2]),
              " (+1 apron), ", Str(channels_), " ch x ", Str(bytes_per_sample_), " B, levels 0..",
              Str(root_level_)});
}

uint64_t CompleteTreeStoredVoxels(const Vec3& volume_size, const Vec3& brick_size) {
  BrickGeometry::Params params;
  params.volume_size = volume_size;
  params.brick_size = brick_size;
  auto geometry = BrickGeometry::Create(params);
  if (!geometry.ok()) return 0;
  uint64_t nodes = 0;
  for (int level = 0; level <= geometry->root_level(); ++level) {
    const Box b = geometry->NonVirtualNodes(level);
    nodes += static_cast<uint64_t>(b.Extent(0)) * b.Extent(1) * b.Extent(2);
  }
  const Vec3 stored = geometry->stored_size();
  return nodes * static_cast<uint64_t>(stored[0] * stored[1] * stored[2]);
}

Vec3 AutoBrickSize(const Vec3& volume_size, int64_t max_edge) {
  max_edge = std::max<int64_t>(2, max_edge - max_edge % 2);
  // Candidates per axis: the axis's own size rounded up to even when it is below max_edge, and
  // every even size in [max_edge / 2, max_edge] that is not larger than needed.
  std::array<std::vector<int64_t>, 3> candidates;
  for (int a = 0; a < 3; ++a) {
    const int64_t n = std::max<int64_t>(1, volume_size[a]);
    const int64_t own = std::max<int64_t>(2, n + n % 2);
    if (own <= max_edge) candidates[a].push_back(own);
    for (int64_t b = std::max<int64_t>(2, max_edge / 2 + (max_edge / 2) % 2); b <= max_edge;
         b += 2) {
      if (b < own) candidates[a].push_back(b);
    }
    if (candidates[a].empty()) candidates[a].push_back(own);
  }
  Vec3 best = kDefaultBrickSize;
  uint64_t best_voxels = 0;
  for (int64_t bx : candidates[0]) {
    for (int64_t by : candidates[1]) {
      for (int64_t bz : candidates[2]) {
        const Vec3 brick{bx, by, bz};
        BrickGeometry::Params params;
        params.volume_size = volume_size;
        params.brick_size = brick;
        auto geometry = BrickGeometry::Create(params);
        if (!geometry.ok() || !FitsDeviceEncoding(*geometry)) continue;
        const uint64_t voxels = CompleteTreeStoredVoxels(volume_size, brick);
        const bool larger = bx * by * bz > best[0] * best[1] * best[2];
        if (best_voxels == 0 || voxels < best_voxels || (voxels == best_voxels && larger)) {
          best = brick;
          best_voxels = voxels;
        }
      }
    }
  }
  return best;
}

}  // namespace octoscope::octree
