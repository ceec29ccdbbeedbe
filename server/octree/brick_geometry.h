// BrickGeometry: the pure arithmetic of the bricked level-of-detail pyramid behind the octree —
// which levels exist, how many VALID voxels each level has, which voxels a node covers and
// stores, which bricks a box touches, and where a voxel lives inside a stored brick. It owns no
// data; the octree, the brick pool and the renderer all derive their coordinates from it, so
// they agree by construction.
//
// Coordinates (all int64_t, all boxes half-open [lo, hi)):
//   * Level L voxel coordinates: level 0 is full resolution; one level-L voxel is the 2x2x2 group
//     of level-(L-1) voxels [2v, 2v+2) per axis.
//   * Level L has LevelSize(L)[a] = ceil(size[a] / 2^L) VALID voxels per axis (a parent voxel
//     exists when at least one of its children is valid). Voxels beyond, up to the node grid's
//     extent, are VIRTUAL: they exist only so that every level is a whole number of bricks
//     (paper, "Handling Volumes of Arbitrary Dimensions") and never count in min/max/avg/means.
//   * Nodes: a node at level L with index i (in bricks, per axis) covers the level-L voxels
//     NodeBox = [i*bs, (i+1)*bs), i.e. bs*2^L voxels of level 0 per axis. The root level R is the
//     smallest level with bs[a] * 2^R >= size[a] on every axis; level L has 2^(R-L) nodes per axis
//     (the virtually extended volume), the root is the single node {R, (0,0,0)}.
//   * Children: a node at level L > 0 has 8 children at level L-1 with indices 2*i + bit, where
//     octant bit 0 selects +x, bit 1 +y, bit 2 +z (octant = x | y << 1 | z << 2).
//   * Stored bricks: every brick stores its node's interior plus a one-voxel APRON on each side
//     (StoredBox = NodeBox dilated by 1), i.e. (bs[0]+2)*(bs[1]+2)*(bs[2]+2) voxels, so trilinear
//     filtering never needs a neighbouring brick. Samples are channel-interleaved, x fastest:
//     sample offset = ((z*sy + y)*sx + x) * channels + c with (x,y,z) relative to StoredBox.lo
//     and (sx,sy,sz) = bs + 2. Apron voxels that fall outside the valid extent are virtual.
//
// Why brick sizes must be EVEN (and >= 2): a parent voxel is the mean of a 2x2x2 child group
// [2v, 2v+2); with even bs the group boundaries coincide with brick boundaries, so every group
// lies inside exactly one child brick (paper, "Arbitrary Dimensions": odd sizes need up to eight
// child bricks per parent voxel), and the parent brick of node i at level L is exactly the
// halved union of its 8 children's interiors.
//
// Limits: each volume axis 1..kMaxVolumeAxis (65536); each brick axis even, 2..kMaxBrickAxis;
// 1..kMaxChannels channels; 1 or 2 bytes per sample; a stored brick at most kMaxBrickBytes. With
// these, R <= 15, node indices are < 2^15, level-L voxel coordinates are within [-1, 2^25 + 1] and
// level-0 coordinates of node boxes within [0, 2^25] (bs * 2^R <= 1024 * 2^15), counts such
// as MaxNodeCount() are < 2^46 and brick offsets < 2^30: no function overflows for any valid
// input (Box::VoxelCount saturates for the one product that could).
//
// Thread safety: BrickGeometry is an immutable value type; all methods are const and may be
// called from any number of threads. Box and NodeKey are plain value types.
#ifndef OCTOSCOPE_OCTREE_BRICK_GEOMETRY_H_
#define OCTOSCOPE_OCTREE_BRICK_GEOMETRY_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>

#include "util/result.h"
#include "util/status.h"

namespace octoscope::octree {

using Vec3 = std::array<int64_t, 3>;

inline constexpr int64_t kMaxVolumeAxis = 65536;
inline constexpr int64_t kMaxBrickAxis = 1024;
inline constexpr int kMaxChannels = 64;
inline constexpr uint64_t kMaxBrickBytes = uint64_t{1} << 30;
inline constexpr Vec3 kDefaultBrickSize{64, 64, 64};

// A half-open axis-aligned box of voxels [lo, hi) in some level's voxel coordinates (or of node
// indices, where a function says so). Empty when hi <= lo on any axis; all empty boxes are
// equivalent for the queries below (operator== compares coordinates literally, though).
struct Box {
  Vec3 lo{0, 0, 0};
  Vec3 hi{0, 0, 0};

  bool empty() const { return hi[0] <= lo[0] || hi[1] <= lo[1] || hi[2] <= lo[2]; }
  // Voxels inside; 0 when empty; saturates at UINT64_MAX when the count does not fit 64 bits
  // (possible only for the level-0 boxes of high nodes in extremely anisotropic geometries, e.g.
  // brick 1024x1024x2 over 1x1x65536: root box 2^25 x 2^25 x 2^16; valid boxes are <= 2^48).
  uint64_t VoxelCount() const;
  int64_t Extent(int axis) const { return hi[axis] > lo[axis] ? hi[axis] - lo[axis] : 0; }
  bool Contains(const Vec3& p) const;
  // True when `other` is empty or lies inside this box.
  bool ContainsBox(const Box& other) const;
  bool Intersects(const Box& other) const { return !Intersect(other).empty(); }
  // The common part (possibly empty).
  Box Intersect(const Box& other) const;
  // lo - d, hi + d on every axis (d may be negative; the result may be empty). An empty box
  // stays empty (returns Box{}).
  Box Dilate(int64_t d) const;
  // "[lo0,hi0)x[lo1,hi1)x[lo2,hi2)".
  std::string ToString() const;

  bool operator==(const Box&) const = default;
};

// Floor division and ceiling division for possibly negative numerators. REQUIRES: d > 0.
int64_t FloorDiv(int64_t n, int64_t d);
int64_t CeilDiv(int64_t n, int64_t d);

// The smallest level-(L+s) box whose voxels cover every level-L voxel of `box`:
// [floor(lo / 2^s), ceil(hi / 2^s)). Works for negative coordinates (apron boxes). With s = 1
// this is the "parent-voxel cover" used to propagate a dirty region one level up.
// An empty box gives Box{}. REQUIRES: 0 <= s <= 62.
Box CoarsenBox(const Box& box, int s = 1);
// The level-(L-s) voxels (children) of the level-L box: [lo * 2^s, hi * 2^s). Empty -> Box{}.
// REQUIRES: 0 <= s and the result fits in int64 (true for any box of a valid geometry and
// s <= its root level).
Box RefineBox(const Box& box, int s = 1);

// Identifies a node: its level (0 = leaves at full resolution, root_level() = root) and its
// index in bricks per axis at that level. Valid for a geometry when 0 <= level <= root_level()
// and 0 <= index[a] < NodesPerAxis(level) (see BrickGeometry::IsValidKey).
struct NodeKey {
  int level = 0;
  Vec3 index{0, 0, 0};

  bool operator==(const NodeKey&) const = default;
  // "L2(1,0,3)".
  std::string ToString() const;
};

// The brick size a volume gets when the user does not choose one: per axis an even size of at
// most `max_edge` (64 by default) that minimises the stored bytes of the complete tree (every
// non-virtual node of every level with a brick, aprons included) — the padding a lossless tree
// pays. A thin stack gets shallow bricks (a 30-plane stack: 30 deep, not 64; a single plane: 2),
// and an axis whose size is not a multiple of 64 gets the even size in [32, 64] (or the axis's
// own size, when smaller) that leaves the least padding; ties go to the larger brick. Only sizes
// whose trees fit 32-bit node ids are considered; falls back to kDefaultBrickSize.
Vec3 AutoBrickSize(const Vec3& volume_size, int64_t max_edge = 64);
// Stored voxels of the complete tree over `volume_size` in bricks of `brick_size` (every
// non-virtual node of every level), or 0 when the geometry is invalid.
uint64_t CompleteTreeStoredVoxels(const Vec3& volume_size, const Vec3& brick_size);

// The octant (0..7) a node occupies inside its parent: bit 0 = index.x odd, bit 1 = y, bit 2 = z.
int OctantOf(const NodeKey& key);
// The child in `octant` (0..7). REQUIRES: key.level >= 1, 0 <= octant < 8.
NodeKey ChildKey(const NodeKey& key, int octant);
// The parent (level + 1, index / 2). REQUIRES: key.level < root level, index >= 0. (Does not
// know the root level; a caller at the root must not ask.)
NodeKey ParentKey(const NodeKey& key);

struct NodeKeyHash {
  size_t operator()(const NodeKey& key) const;
};

class BrickGeometry {
 public:
  struct Params {
    Vec3 volume_size{1, 1, 1};            // Level-0 voxels per axis, each 1..kMaxVolumeAxis.
    Vec3 brick_size = kDefaultBrickSize;  // Interior voxels per brick per axis, even, >= 2.
    int channels = 1;                     // 1..kMaxChannels.
    int bytes_per_sample = 2;             // 1 (uint8) or 2 (uint16).
  };

  // Validates `params` (InvalidArgument naming the offending field and value otherwise).
  static Result<BrickGeometry> Create(const Params& params);

  // --- Parameters ---------------------------------------------------------------------------
  const Vec3& volume_size() const { return volume_size_; }
  const Vec3& brick_size() const { return brick_size_; }
  int channels() const { return channels_; }
  int bytes_per_sample() const { return bytes_per_sample_; }
  Params params() const { return {volume_size_, brick_size_, channels_, bytes_per_sample_}; }

  // --- Levels -------------------------------------------------------------------------------
  // The root level R (see file comment); levels are 0..R, level_count() = R + 1. R <= 15.
  int root_level() const { return root_level_; }
  int level_count() const { return root_level_ + 1; }
  // ceil(size[a] / 2^level) valid voxels per axis. REQUIRES: 0 <= level <= root_level().
  Vec3 LevelSize(int level) const;
  // [0, LevelSize(level)): the valid voxels of a level.
  Box ValidExtent(int level) const;
  // Nodes per axis at `level`: 2^(R - level). REQUIRES: 0 <= level <= root_level().
  int64_t NodesPerAxis(int level) const;
  // [0, NodesPerAxis(level)) per axis: every node index of the level (the extended volume).
  Box NodeGrid(int level) const;
  // The node indices of the level that are NOT virtual: [0, ceil(LevelSize / bs)) per axis.
  Box NonVirtualNodes(int level) const;
  // Nodes of a complete tree over all levels: sum over L of 8^(R-L) (< 2^46). For sizing.
  uint64_t MaxNodeCount() const;

  // --- Nodes --------------------------------------------------------------------------------
  bool IsValidKey(const NodeKey& key) const;
  NodeKey RootKey() const { return NodeKey{root_level_, {0, 0, 0}}; }
  // The node of `level` whose interior contains level-`level` voxel p (p may lie in the virtual
  // extension). REQUIRES: p inside NodeGrid(level) scaled by bs, i.e. 0 <= p < bs*2^(R-level).
  NodeKey NodeContaining(int level, const Vec3& p) const;
  // Interior, level-L voxels: [i*bs, (i+1)*bs). REQUIRES (all node functions): IsValidKey(key).
  Box NodeBox(const NodeKey& key) const;
  // The interior in level-0 voxel coordinates: [i*bs*2^L, (i+1)*bs*2^L) (may extend into the
  // virtual part).
  Box NodeBoxLevel0(const NodeKey& key) const;
  // NodeBox dilated by the one-voxel apron: what the stored brick holds.
  Box StoredBox(const NodeKey& key) const;
  // NodeBox ∩ ValidExtent(level): the voxels that count for statistics and parent means.
  Box ValidBox(const NodeKey& key) const;
  // StoredBox ∩ ValidExtent(level): the stored voxels (apron included) that hold real data.
  Box StoredValidBox(const NodeKey& key) const;
  // True when the node has no valid voxel (it never gets a brick and stores the background).
  bool IsVirtual(const NodeKey& key) const;

  // --- Bricks touching a box ------------------------------------------------------------------
  // These return a box of NODE INDICES at `level` (not voxels), clipped to NodeGrid(level); the
  // caller may further intersect with NonVirtualNodes(level). Empty when nothing is touched.
  // `box` is in level-`level` voxel coordinates and may be empty or reach outside the grid.
  //
  // Nodes whose INTERIOR (NodeBox) intersects `box`: who owns these voxels.
  Box NodesIntersecting(int level, const Box& box) const;
  // Nodes whose STORED box (interior + apron) intersects `box`: every brick that stores a copy
  // of some voxel of `box` and so must be written when those voxels change.
  Box NodesStoringAny(int level, const Box& box) const;

  // --- Stored brick layout ------------------------------------------------------------------
  // Stored brick extent per axis: bs + 2.
  Vec3 stored_size() const { return {brick_size_[0] + 2, brick_size_[1] + 2, brick_size_[2] + 2}; }
  // Voxels, samples (voxels * channels) and bytes (samples * bytes_per_sample) of one stored brick.
  uint64_t brick_voxels() const;
  uint64_t brick_samples() const { return brick_voxels() * static_cast<uint64_t>(channels_); }
  uint64_t brick_bytes() const {
    return brick_samples() * static_cast<uint64_t>(bytes_per_sample_);
  }
  // Sample index inside a stored brick of the voxel at brick-local coordinates `local` (relative
  // to StoredBox.lo, each 0..bs+1) and channel c: ((z*sy + y)*sx + x) * channels + c.
  // REQUIRES: 0 <= local[a] < bs[a] + 2, 0 <= c < channels().
  uint64_t LocalSampleOffset(const Vec3& local, int c) const;
  // Sample index inside `key`'s stored brick of level-L voxel p (global level-L coordinates).
  // REQUIRES: IsValidKey(key), StoredBox(key).Contains(p), 0 <= c < channels().
  uint64_t StoredSampleOffset(const NodeKey& key, const Vec3& p, int c) const;
  // StoredSampleOffset * bytes_per_sample(): the byte offset of that sample in the brick.
  uint64_t StoredByteOffset(const NodeKey& key, const Vec3& p, int c) const {
    return StoredSampleOffset(key, p, c) * static_cast<uint64_t>(bytes_per_sample_);
  }

  // "volume 67x33x5, brick 64x32x16 (+1 apron), 2 ch x 2 B, levels 0..1".
  std::string ToString() const;

  bool operator==(const BrickGeometry&) const = default;

 private:
  BrickGeometry() = default;

  Vec3 volume_size_{1, 1, 1};
  Vec3 brick_size_ = kDefaultBrickSize;
  int channels_ = 1;
  int bytes_per_sample_ = 2;
  int root_level_ = 0;
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_BRICK_GEOMETRY_H_
