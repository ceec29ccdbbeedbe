#include "octree/octree.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>

#include "octree/node_encoding.h"
#include "util/checked_math.h"

namespace octoscope::octree {
namespace {

// Index of voxel p in a buffer laid out over `box`, x fastest.
inline size_t BufferIndex(const Box& box, int64_t x, int64_t y, int64_t z) {
  return static_cast<size_t>(((z - box.lo[2]) * box.Extent(1) + (y - box.lo[1])) * box.Extent(0) +
                             (x - box.lo[0]));
}

template <typename F>
void ForEachIndex(const Box& b, F&& f) {
  for (int64_t z = b.lo[2]; z < b.hi[2]; ++z)
    for (int64_t y = b.lo[1]; y < b.hi[1]; ++y)
      for (int64_t x = b.lo[0]; x < b.hi[0]; ++x) f(Vec3{x, y, z});
}

// The parts of `a` outside `b`: at most 6 disjoint boxes, cut off along z, then y, then x (so
// the big pieces are whole planes and rows).
std::vector<Box> Subtract(const Box& a, const Box& b) {
  if (a.empty()) return {};
  const Box common = a.Intersect(b);
  if (common.empty()) return {a};
  std::vector<Box> out;
  Box rest = a;
  for (int axis = 2; axis >= 0; --axis) {
    if (rest.lo[axis] < common.lo[axis]) {
      Box piece = rest;
      piece.hi[axis] = common.lo[axis];
      out.push_back(piece);
      rest.lo[axis] = common.lo[axis];
    }
    if (common.hi[axis] < rest.hi[axis]) {
      Box piece = rest;
      piece.lo[axis] = common.hi[axis];
      out.push_back(piece);
      rest.hi[axis] = common.hi[axis];
    }
  }
  return out;
}

// --- Row kernels ----------------------------------------------------------------------------
// The hot loops of construction work on rows: `n` consecutive voxels along x of one channel of
// a stored brick (samples `stride` = channels apart) or of a uint16 buffer (contiguous). They
// are templates over a Layout, the stored sample type and — for the common channel counts 1..4 —
// a compile-time stride, so that the compiler vectorises them; other channel counts use the
// run-time stride. Brick bytes are accessed as T: the page buffers are std::byte arrays, which
// implicitly create the sample objects (C++20 [intro.object]).

template <typename T, int kStride>
struct Layout {
  using Sample = T;
  static constexpr int kFixedStride = kStride;  // 0: run-time stride.
  static size_t Stride(size_t stride) {
    return kStride > 0 ? static_cast<size_t>(kStride) : stride;
  }
};

// Calls f(Layout<T, kStride>{}) for the stored sample type (1 or 2 bytes) and channel count.
template <typename F>
decltype(auto) WithLayout(int bytes_per_sample, int channels, F&& f) {
  auto with_type = [&]<typename T>() -> decltype(auto) {
    switch (channels) {
      case 1:
        return f(Layout<T, 1>{});
      case 2:
        return f(Layout<T, 2>{});
      case 3:
        return f(Layout<T, 3>{});
      case 4:
        return f(Layout<T, 4>{});
      default:
        return f(Layout<T, 0>{});
    }
  };
  if (bytes_per_sample == 1) return with_type.template operator()<uint8_t>();
  return with_type.template operator()<uint16_t>();
}

// A whole voxel (all channels) as one unsigned word, when that is 2, 4 or 8 bytes: channel c of
// a voxel is then bits [8 * sizeof(T) * c, +8 * sizeof(T)) of it (little-endian).
template <typename L>
using VoxelWord = std::conditional_t<
    sizeof(typename L::Sample) * L::kFixedStride == 2, uint16_t,
    std::conditional_t<
        sizeof(typename L::Sample) * L::kFixedStride == 4, uint32_t,
        std::conditional_t<sizeof(typename L::Sample) * L::kFixedStride == 8, uint64_t, void>>>;
static_assert(std::endian::native == std::endian::little, "VoxelWord assumes little-endian");

template <typename L>
inline void StoreRow(std::byte* brick_row, size_t stride, int c, const uint16_t* __restrict src,
                     int64_t n) {
  using T = typename L::Sample;
  using W = VoxelWord<L>;
  if constexpr (L::kFixedStride > 1 && !std::is_void_v<W>) {
    // Interleaved channels: rewrite whole voxels, keeping the other channels' bits. Unlike
    // scattered sample stores this vectorises, and it moves the same cache lines.
    W* __restrict dst = reinterpret_cast<W*>(brick_row - c * sizeof(T));
    const unsigned shift = 8 * sizeof(T) * static_cast<unsigned>(c);
    const W keep = static_cast<W>(~(static_cast<W>(std::numeric_limits<T>::max()) << shift));
    for (int64_t x = 0; x < n; ++x) {
      dst[x] = static_cast<W>((dst[x] & keep) | (static_cast<W>(static_cast<T>(src[x])) << shift));
    }
  } else {
    T* __restrict dst = reinterpret_cast<T*>(brick_row);
    const size_t s = L::Stride(stride);
    for (int64_t x = 0; x < n; ++x) dst[x * s] = static_cast<T>(src[x]);
  }
}

template <typename L>
inline void FillRow(std::byte* brick_row, size_t stride, uint16_t value, int64_t n) {
  using T = typename L::Sample;
  T* dst = reinterpret_cast<T*>(brick_row);
  const size_t s = L::Stride(stride);
  const T v = static_cast<T>(value);
  for (int64_t x = 0; x < n; ++x) dst[x * s] = v;
}

template <typename L>
inline void LoadRow(const std::byte* brick_row, size_t stride, uint16_t* __restrict dst,
                    int64_t n) {
  using T = typename L::Sample;
  const T* __restrict src = reinterpret_cast<const T*>(brick_row);
  const size_t s = L::Stride(stride);
  for (int64_t x = 0; x < n; ++x) dst[x] = src[x * s];
}

// Accumulates min, max and sum of one brick row. The row sum fits 32 bits (n <= kMaxBrickAxis).
template <typename L>
inline void ScanRow(const std::byte* brick_row, size_t stride, int64_t n, uint32_t& lo,
                    uint32_t& hi, uint64_t& sum) {
  using T = typename L::Sample;
  const T* src = reinterpret_cast<const T*>(brick_row);
  const size_t s = L::Stride(stride);
  T row_lo = std::numeric_limits<T>::max(), row_hi = 0;
  uint32_t row_sum = 0;
  for (int64_t x = 0; x < n; ++x) {
    const T v = src[x * s];
    row_lo = std::min(row_lo, v);
    row_hi = std::max(row_hi, v);
    row_sum += v;
  }
  lo = std::min<uint32_t>(lo, row_lo);
  hi = std::max<uint32_t>(hi, row_hi);
  sum += row_sum;
}

// Accumulates min, max and sum of `n` contiguous values (the loop vectorises).
inline void ScanValues(const uint16_t* values, int64_t n, uint32_t& lo, uint32_t& hi,
                       uint64_t& sum) {
  uint16_t row_lo = 0xffff, row_hi = 0;
  uint32_t row_sum = 0;  // n <= kMaxBrickAxis: fits.
  for (int64_t x = 0; x < n; ++x) {
    row_lo = std::min(row_lo, values[x]);
    row_hi = std::max(row_hi, values[x]);
    row_sum += values[x];
  }
  lo = std::min<uint32_t>(lo, row_lo);
  hi = std::max<uint32_t>(hi, row_hi);
  sum += row_sum;
}

// Where the samples of a stored brick lie: level-L voxel (x, y, z) of channel c is sample
// (((z - o.z) * sy + (y - o.y)) * sx + (x - o.x)) * channels + c, with o = StoredBox(key).lo
// (BrickGeometry::StoredSampleOffset, without the per-voxel function call).
struct BrickLayout {
  Vec3 origin;
  int64_t sx, sy;
  size_t channels;
  size_t bytes_per_sample;

  BrickLayout(const BrickGeometry& g, const NodeKey& key)
      : origin(g.StoredBox(key).lo),
        sx(g.stored_size()[0]),
        sy(g.stored_size()[1]),
        channels(static_cast<size_t>(g.channels())),
        bytes_per_sample(static_cast<size_t>(g.bytes_per_sample())) {}
  // Byte offset of voxel (x, y, z), channel c. REQUIRES: the voxel lies in the stored box.
  size_t ByteOffset(int64_t x, int64_t y, int64_t z, int c) const {
    const int64_t local = ((z - origin[2]) * sy + (y - origin[1])) * sx + (x - origin[0]);
    return (static_cast<size_t>(local) * channels + static_cast<size_t>(c)) * bytes_per_sample;
  }
};

// Writes EVERY channel of a row of n voxels from the channels' source rows, in one pass of
// sequential stores (kFixedStride channels, known at compile time so the inner loop unrolls).
template <typename L>
inline void InterleaveRow(std::byte* voxel_row, const uint16_t* const* src, int64_t n) {
  using T = typename L::Sample;
  constexpr int kC = L::kFixedStride;
  T* __restrict dst = reinterpret_cast<T*>(voxel_row);
  const uint16_t* __restrict s0 = src[0];
  const uint16_t* __restrict s1 = src[kC > 1 ? 1 : 0];
  const uint16_t* __restrict s2 = src[kC > 2 ? 2 : 0];
  const uint16_t* __restrict s3 = src[kC > 3 ? 3 : 0];
  for (int64_t x = 0; x < n; ++x) {
    dst[x * kC] = static_cast<T>(s0[x]);
    if constexpr (kC > 1) dst[x * kC + 1] = static_cast<T>(s1[x]);
    if constexpr (kC > 2) dst[x * kC + 2] = static_cast<T>(s2[x]);
    if constexpr (kC > 3) dst[x * kC + 3] = static_cast<T>(s3[x]);
  }
}

// Writes the lanes' channels of `region` (inside the brick's stored box) from their values, laid
// out over `src_box` (which contains region). With `fill` (a new brick), every channel of a row is
// first set to fill[ch], so that channels without a lane show their uniform value. With `stats`
// (non-null), accumulates the written values inside `stats_box` (a part of region) per lane and
// z plane into stats[lane * stats_box.Extent(2) + z - stats_box.lo[2]], row by row while the
// rows are in L1. Each row is a few hundred bytes: the per-lane passes over it stay in cache, so
// the brick's memory is traversed once whatever the number of lanes.
template <typename L, typename LaneSpan, typename Stats>
void WriteBrickRegion(std::byte* brick, const BrickLayout& layout, const Box& region,
                      const LaneSpan& lanes, const Box& src_box, const uint16_t* fill,
                      const Box& stats_box, Stats* stats) {
  using T = typename L::Sample;
  const int64_t n = region.Extent(0);
  const int channels = static_cast<int>(layout.channels);
  const int64_t stats_planes = stats_box.Extent(2);
  // Every channel has a lane (lanes are sorted by channel): one interleaving pass per row.
  const bool all_lanes = L::kFixedStride > 0 && static_cast<int>(lanes.size()) == channels;
  const uint16_t* rows[4] = {};
  for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
    for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
      std::byte* voxel_row = brick + layout.ByteOffset(region.lo[0], y, z, 0);
      const size_t src = BufferIndex(src_box, region.lo[0], y, z);
      if (all_lanes) {
        for (int c = 0; c < channels; ++c) rows[c] = lanes[c].values + src;
        InterleaveRow<L>(voxel_row, rows, n);
      } else if (fill != nullptr) {
        for (int ch = 0; ch < channels; ++ch) {
          FillRow<L>(voxel_row + ch * sizeof(T), layout.channels, fill[ch], n);
        }
      }
      const bool scan = stats != nullptr && stats_box.lo[1] <= y && y < stats_box.hi[1] &&
                        stats_box.lo[2] <= z && z < stats_box.hi[2];
      for (size_t li = 0; li < lanes.size(); ++li) {
        const int c = lanes[li].channel;
        const uint16_t* row = lanes[li].values + src;
        if (!all_lanes) StoreRow<L>(voxel_row + c * sizeof(T), layout.channels, c, row, n);
        if (scan) {
          auto& st = stats[static_cast<int64_t>(li) * stats_planes + (z - stats_box.lo[2])];
          ScanValues(row + (stats_box.lo[0] - region.lo[0]), stats_box.Extent(0), st.lo, st.hi,
                     st.sum);
        }
      }
    }
  }
}

template <typename L>
void FillBrickRegion(std::byte* brick, const BrickLayout& layout, const Box& region, int c,
                     uint16_t value) {
  const int64_t n = region.Extent(0);
  for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
    for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
      FillRow<L>(brick + layout.ByteOffset(region.lo[0], y, z, c), layout.channels, value, n);
    }
  }
}

// One output row of step 2: out[i] = the rounded mean of the children of parent voxel i, taken
// from the kRows child rows (1, 2 or 4: the child rows present in y and z) of `child_x` voxels.
// Every parent has 2 children along x except, when child_x is odd, the last one; so every count
// n is a power of two and (sum + n/2) / n is a shift.
template <int kRows>
void DownsampleRow(const uint16_t* const* rows, int64_t child_x, uint16_t* __restrict out) {
  constexpr int kShift = kRows == 1 ? 1 : kRows == 2 ? 2 : 3;  // log2(2 * kRows)
  const uint16_t* __restrict r0 = rows[0];
  const uint16_t* __restrict r1 = rows[kRows > 1 ? 1 : 0];
  const uint16_t* __restrict r2 = rows[kRows > 2 ? 2 : 0];
  const uint16_t* __restrict r3 = rows[kRows > 2 ? 3 : 0];
  const int64_t pairs = child_x / 2;
  for (int64_t i = 0; i < pairs; ++i) {
    uint32_t sum = uint32_t{r0[2 * i]} + r0[2 * i + 1];
    if constexpr (kRows > 1) sum += uint32_t{r1[2 * i]} + r1[2 * i + 1];
    if constexpr (kRows > 2) sum += uint32_t{r2[2 * i]} + r2[2 * i + 1] + r3[2 * i] + r3[2 * i + 1];
    out[i] = static_cast<uint16_t>((sum + (1u << (kShift - 1))) >> kShift);
  }
  if (child_x % 2 != 0) {  // The last parent has one child along x: n = kRows.
    const int64_t x = child_x - 1;
    uint32_t sum = r0[x];
    if constexpr (kRows > 1) sum += r1[x];
    if constexpr (kRows > 2) sum += uint32_t{r2[x]} + r3[x];
    out[pairs] = static_cast<uint16_t>((sum + kRows / 2) >> (kShift - 1));
  }
}

// Step 2 for one level: `out`, laid out over `cover` (level L), gets the integer mean, round half
// up, of the VALID children of each voxel, read from `children`, laid out over child_box =
// RefineBox(cover) clipped to the valid extent of level L-1. So child_box.lo = 2 * cover.lo and
// only the last parent per axis may lack its second child.
void Downsample(const uint16_t* children, const Box& child_box, const Box& cover, uint16_t* out) {
  const int64_t cx = child_box.Extent(0), cy = child_box.Extent(1), cz = child_box.Extent(2);
  const int64_t py = cover.Extent(1), pz = cover.Extent(2), px = cover.Extent(0);
  for (int64_t z = 0; z < pz; ++z) {
    const int64_t kz = std::min<int64_t>(2, cz - 2 * z);
    for (int64_t y = 0; y < py; ++y) {
      const int64_t ky = std::min<int64_t>(2, cy - 2 * y);
      const uint16_t* rows[4];
      int k = 0;
      for (int64_t dz = 0; dz < kz; ++dz)
        for (int64_t dy = 0; dy < ky; ++dy)
          rows[k++] = children + static_cast<size_t>(((2 * z + dz) * cy + 2 * y + dy) * cx);
      uint16_t* row_out = out + static_cast<size_t>((z * py + y) * px);
      if (k == 4) {
        DownsampleRow<4>(rows, cx, row_out);
      } else if (k == 2) {
        DownsampleRow<2>(rows, cx, row_out);
      } else {
        DownsampleRow<1>(rows, cx, row_out);
      }
    }
  }
}

}  // namespace

// --------------------------------------------------------------------------------------------
// Construction.

Octree::Octree(const BrickGeometry& geometry, paging::PageCache* cache, uint32_t bricks_per_page)
    : geometry_(geometry),
      channels_(geometry.channels()),
      cache_(cache),
      pool_(cache, geometry.brick_bytes(), bricks_per_page) {}

Octree::~Octree() = default;

Result<std::unique_ptr<Octree>> Octree::Create(const BrickGeometry& geometry,
                                               const OctreeOptions& options,
                                               paging::PageCache* cache) {
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<Octree> tree, CreateImpl(geometry, options, cache));
  // The root: group 0, id 0, storing the background.
  tree->nodes_.assign(8, NodeRecord{});
  tree->stats_.assign(8 * static_cast<size_t>(tree->channels_), ChannelStats{});
  tree->group_parent_.assign(1, 0);
  tree->nodes_[0].level = static_cast<uint8_t>(geometry.root_level());
  tree->nodes_[0].flags = kLive;
  for (int c = 0; c < tree->channels_; ++c) {
    const uint16_t bg = tree->background_[c];
    tree->Stat(0, c) = ChannelStats{bg, bg, bg, bg, static_cast<double>(bg)};
  }
  tree->changes_.Append(0, NodeChangeKind::kCreated);
  return tree;
}

Result<std::unique_ptr<Octree>> Octree::Create(const volume::VolumeInfo& info,
                                               const OctreeOptions& options,
                                               paging::PageCache* cache) {
  OCTO_RETURN_IF_ERROR(info.Validate());
  BrickGeometry::Params params;
  params.volume_size = info.size;
  params.brick_size = options.brick_size;
  params.channels = info.channel_count();
  params.bytes_per_sample = options.bytes_per_sample;
  if (params.bytes_per_sample == 0) {
    params.bytes_per_sample = volume::BytesPerSample(info.dtype) == 1 ? 1 : 2;
  }
  OCTO_ASSIGN_OR_RETURN(BrickGeometry geometry, BrickGeometry::Create(params));
  return Create(geometry, options, cache);
}

Result<std::unique_ptr<Octree>> Octree::CreateImpl(const BrickGeometry& geometry,
                                                   const OctreeOptions& options,
                                                   paging::PageCache* cache) {
  if (cache == nullptr) return InvalidArgumentError("octree: no page cache");
  const int channels = geometry.channels();
  const uint64_t brick_bytes = geometry.brick_bytes();
  if (cache->page_bytes() < brick_bytes) {
    return InvalidArgumentError("octree: a page of " + std::to_string(cache->page_bytes()) +
                                " bytes cannot hold one brick of " + std::to_string(brick_bytes) +
                                " bytes (" + geometry.ToString() + ")");
  }
  const uint64_t per_page =
      std::min<uint64_t>(cache->page_bytes() / brick_bytes, std::numeric_limits<uint32_t>::max());
  if (!(options.homogeneity_threshold >= 0.0 && options.homogeneity_threshold <= 1.0)) {
    return InvalidArgumentError("octree: homogeneity threshold " +
                                std::to_string(options.homogeneity_threshold) +
                                " is outside [0, 1]");
  }
  auto check_size = [&](size_t n, const char* what) -> Status {
    if (n != 0 && n != static_cast<size_t>(channels)) {
      return InvalidArgumentError(std::string("octree: ") + what + " has " + std::to_string(n) +
                                  " entries for " + std::to_string(channels) + " channels");
    }
    return Status::Ok();
  };
  OCTO_RETURN_IF_ERROR(check_size(options.value_range.size(), "value_range"));
  OCTO_RETURN_IF_ERROR(check_size(options.homogeneity_tolerance.size(), "homogeneity_tolerance"));
  OCTO_RETURN_IF_ERROR(check_size(options.background.size(), "background"));
  const uint32_t type_max = geometry.bytes_per_sample() == 1 ? 255u : 65535u;

  if (!FitsDeviceEncoding(geometry)) {
    return InvalidArgumentError("octree: " + geometry.ToString() + " could need more than " +
                                std::to_string(kChildGroupCapacity) +
                                " child groups (node ids are 32-bit); use larger bricks");
  }
  std::unique_ptr<Octree> tree(new Octree(geometry, cache, static_cast<uint32_t>(per_page)));
  tree->tolerance_.resize(channels);
  tree->background_.resize(channels);
  for (int c = 0; c < channels; ++c) {
    if (!options.homogeneity_tolerance.empty()) {
      tree->tolerance_[c] = options.homogeneity_tolerance[c];
    } else {
      const double range = options.value_range.empty() ? type_max : options.value_range[c];
      // A tiny epsilon so that e.g. 0.05 * 65535 is not floored one below its decimal value.
      tree->tolerance_[c] =
          static_cast<uint32_t>(std::floor(options.homogeneity_threshold * range + 1e-9));
    }
    const uint16_t bg = options.background.empty() ? 0 : options.background[c];
    if (bg > type_max) {
      return InvalidArgumentError("octree: background " + std::to_string(bg) +
                                  " does not fit the stored sample type");
    }
    tree->background_[c] = bg;
  }
  return tree;
}

// --------------------------------------------------------------------------------------------
// Node table queries.

Octree::Located Octree::Locate(const NodeKey& key) const {
  uint32_t id = 0;
  int level = geometry_.root_level();
  while (level > key.level) {
    const uint32_t group = nodes_[id].child_group;
    if (group == 0) break;
    const int shift = level - 1 - key.level;
    int octant = 0;
    for (int a = 0; a < 3; ++a) octant |= static_cast<int>((key.index[a] >> shift) & 1) << a;
    id = group * 8 + static_cast<uint32_t>(octant);
    --level;
  }
  return Located{id, level == key.level};
}

NodeKey Octree::KeyOf(uint32_t id) const {
  NodeKey key;
  key.level = nodes_[id].level;
  int shift = 0;
  uint32_t cur = id;
  while (cur != 0) {
    const uint32_t octant = cur % 8;
    for (int a = 0; a < 3; ++a) key.index[a] |= static_cast<int64_t>((octant >> a) & 1) << shift;
    ++shift;
    cur = group_parent_[cur / 8];
  }
  return key;
}

uint16_t Octree::Uniform(uint32_t id, int c) const {
  const double v = std::floor(Stat(id, c).avg + 0.5);
  const double type_max = geometry_.bytes_per_sample() == 1 ? 255.0 : 65535.0;
  return static_cast<uint16_t>(std::clamp(v, 0.0, type_max));
}

bool Octree::IsLiveId(uint32_t id) const {
  if (id >= nodes_.size() || (nodes_[id].flags & kLive) == 0) return false;
  return id == 0 || id >= 8;
}

NodeSnapshot Octree::SnapshotLocked(uint32_t id) const {
  const NodeRecord& r = nodes_[id];
  NodeSnapshot s;
  s.id = id;
  s.key = KeyOf(id);
  s.child_group = r.child_group;
  s.brick = r.brick;
  s.is_virtual = (r.flags & kVirtual) != 0;
  s.complete = (r.flags & kComplete) != 0;
  s.channels.resize(channels_);
  for (int c = 0; c < channels_; ++c) {
    const ChannelStats& st = Stat(id, c);
    s.channels[c] = ChannelSummary{st.min, st.max, st.sub_min, st.sub_max, st.avg};
  }
  return s;
}

std::optional<NodeSnapshot> Octree::GetNode(const NodeKey& key) const {
  if (!geometry_.IsValidKey(key)) return std::nullopt;
  std::shared_lock<std::shared_mutex> lock(mu_);
  const Located loc = Locate(key);
  if (!loc.exact) return std::nullopt;
  return SnapshotLocked(loc.id);
}

std::optional<NodeSnapshot> Octree::GetNode(uint32_t id) const {
  std::shared_lock<std::shared_mutex> lock(mu_);
  if (!IsLiveId(id)) return std::nullopt;
  return SnapshotLocked(id);
}

Status Octree::ReadBrick(uint32_t id, std::span<std::byte> out) const {
  if (out.size() != geometry_.brick_bytes()) {
    return InvalidArgumentError("octree: ReadBrick buffer of " + std::to_string(out.size()) +
                                " bytes, brick has " + std::to_string(geometry_.brick_bytes()));
  }
  // The shared lock keeps the brick from being dropped (that takes mu_ exclusively) while we
  // copy; the stripe lock keeps the inserting thread from modifying its bytes meanwhile.
  std::shared_lock<std::shared_mutex> lock(mu_);
  if (!IsLiveId(id)) return NotFoundError("octree: node " + std::to_string(id) + " does not exist");
  const uint32_t brick = nodes_[id].brick;
  if (brick == 0) return NotFoundError("octree: node " + std::to_string(id) + " has no brick");
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
  std::span<const std::byte> src = std::as_const(handle).data();
  std::memcpy(out.data(), src.data(), src.size());
  return Status::Ok();
}

Status Octree::TryReadBrick(uint32_t id, std::span<std::byte> out, uint64_t* page) const {
  if (out.size() != geometry_.brick_bytes()) {
    return InvalidArgumentError("octree: TryReadBrick buffer of " + std::to_string(out.size()) +
                                " bytes, brick has " + std::to_string(geometry_.brick_bytes()));
  }
  std::shared_lock<std::shared_mutex> lock(mu_);
  if (!IsLiveId(id)) return NotFoundError("octree: node " + std::to_string(id) + " does not exist");
  const uint32_t brick = nodes_[id].brick;
  if (brick == 0) return NotFoundError("octree: node " + std::to_string(id) + " has no brick");
  std::optional<BrickHandle> handle = pool_.TryPin(brick);
  if (!handle.has_value()) {
    if (page != nullptr) *page = pool_.PageOf(brick);
    return UnavailableError("octree: the page of node " + std::to_string(id) +
                            "'s brick is not in RAM");
  }
  std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
  std::span<const std::byte> src = std::as_const(*handle).data();
  std::memcpy(out.data(), src.data(), src.size());
  return Status::Ok();
}

OctreeStats Octree::stats() const {
  OctreeStats s;
  {
    std::shared_lock<std::shared_mutex> lock(mu_);
    for (uint32_t id = 0; id < nodes_.size(); ++id) {
      if (!IsLiveId(id)) continue;
      ++s.nodes;
      if ((nodes_[id].flags & kVirtual) == 0 && nodes_[id].brick == 0) ++s.homogeneous_nodes;
    }
  }
  s.bricks = pool_.live_bricks();
  s.pool_bytes = pool_.pool_bytes();
  return s;
}

Status Octree::Flush() { return cache_->Flush(); }

// --------------------------------------------------------------------------------------------
// Structure mutations. All run on the inserting thread (insert_mu_ held), read the table without
// a lock (no one else writes it) and take mu_ exclusively only to modify it, never while holding
// a page pin (a reader may hold mu_ shared while it waits in PageCache::Pin).

Status Octree::CreateChildren(uint32_t id) {
  const NodeKey key = KeyOf(id);
  std::unique_lock<std::shared_mutex> lock(mu_);
  uint32_t group;
  if (!free_groups_.empty()) {
    group = *free_groups_.begin();
    free_groups_.erase(free_groups_.begin());
  } else {
    if (group_parent_.size() >= kChildGroupCapacity) {
      return ResourceExhaustedError("octree: more than " + std::to_string(kChildGroupCapacity) +
                                    " child groups");
    }
    group = static_cast<uint32_t>(group_parent_.size());
    group_parent_.push_back(kFreeGroup);
    nodes_.resize(nodes_.size() + 8);
    stats_.resize(stats_.size() + 8 * static_cast<size_t>(channels_));
  }
  group_parent_[group] = id;
  const bool parent_complete = (nodes_[id].flags & kComplete) != 0;
  for (int octant = 0; octant < 8; ++octant) {
    const uint32_t child = group * 8 + static_cast<uint32_t>(octant);
    const bool is_virtual = geometry_.IsVirtual(ChildKey(key, octant));
    NodeRecord& r = nodes_[child];
    r = NodeRecord{};
    r.level = static_cast<uint8_t>(key.level - 1);
    r.flags = static_cast<uint8_t>(kLive | (is_virtual ? kVirtual : 0) |
                                   (is_virtual || parent_complete ? kComplete : 0));
    for (int c = 0; c < channels_; ++c) {
      // New children show what the parent showed for their region: its average (the background
      // for a fresh parent; the pruned average when re-opening a pruned node).
      if (is_virtual) {
        const uint16_t bg = background_[c];
        Stat(child, c) = ChannelStats{bg, bg, bg, bg, static_cast<double>(bg)};
      } else {
        const uint16_t u = Uniform(id, c);
        Stat(child, c) = ChannelStats{u, u, u, u, Stat(id, c).avg};
      }
    }
  }
  nodes_[id].child_group = group;
  lock.unlock();
  for (int octant = 0; octant < 8; ++octant) {
    changes_.Append(group * 8 + static_cast<uint32_t>(octant), NodeChangeKind::kCreated);
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  return Status::Ok();
}

Result<uint32_t> Octree::EnsureNode(const NodeKey& key) {
  for (;;) {
    const Located loc = Locate(key);
    if (loc.exact) return loc.id;
    // Locate stopped at a childless ancestor: give it its 8 children and descend further.
    OCTO_RETURN_IF_ERROR(CreateChildren(loc.id));
  }
}

Status Octree::InitBrick(uint32_t brick, uint32_t id, const NodeKey& key, Lanes lanes,
                         const Box& src_box, Touched* touched) const {
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  // The new brick shows exactly what the node showed without it: its interior is the node's
  // uniform value, its apron the neighbours' current representation, except that the lanes'
  // channels of `written` take the inserted values. The core (written interior; for slab inserts
  // most of the brick) is initialised row by row for all channels at once; the rest region by
  // region. The brick is published by the caller only when it is complete.
  const Box stored = geometry_.StoredBox(key);
  const Box interior = geometry_.NodeBox(key);
  const Box written = stored.Intersect(src_box);
  const Box core = written.Intersect(interior);
  const BrickLayout layout(geometry_, key);
  std::vector<uint16_t> uniform(channels_);
  for (int ch = 0; ch < channels_; ++ch) uniform[ch] = Uniform(id, ch);
  uint64_t lane_mask = 0;
  for (const Lane& lane : lanes) lane_mask |= uint64_t{1} << lane.channel;
  handle.MarkDirty();
  std::byte* data = handle.data().data();
  std::vector<uint16_t> apron;
  return WithLayout(geometry_.bytes_per_sample(), channels_, [&](auto l) -> Status {
    using L = decltype(l);
    // Readers never see an unpublished brick; the stripe lock only keeps sanitizers and a reader
    // of a previous owner of the id honest. It is not held while reading neighbours.
    for (int ch = 0; ch < channels_; ++ch) {
      const bool is_lane = (lane_mask >> ch) & 1;
      for (const Box& part : Subtract(stored, is_lane ? written : core)) {
        const Box own = part.Intersect(interior);
        if (!own.empty()) {
          std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
          FillBrickRegion<L>(data, layout, own, ch, uniform[ch]);
        }
        // The node is not yet published with a brick, so outside its interior this reads the
        // neighbours (their brick, or their uniform value) and the background.
        for (const Box& around : Subtract(part, interior)) {
          apron.resize(around.VoxelCount());
          OCTO_RETURN_IF_ERROR(ReadRepresentation(key.level, around, ch, apron.data()));
          const Lane one{ch, apron.data()};
          std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
          WriteBrickRegion<L>(data, layout, around, std::span<const Lane>(&one, 1), around, nullptr,
                              Box{}, static_cast<SampleStats*>(nullptr));
        }
      }
    }
    std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
    // The lanes over the written apron.
    for (const Box& part : Subtract(written, core)) {
      WriteBrickRegion<L>(data, layout, part, lanes, src_box, nullptr, Box{},
                          static_cast<SampleStats*>(nullptr));
    }
    // The core last: the apron passes above touch the first and last cache line of every row,
    // which this pass then finds in cache. touched->written (the valid written interior) lies
    // inside the core.
    if (!core.empty()) {
      WriteBrickRegion<L>(data, layout, core, lanes, src_box, uniform.data(), touched->written,
                          touched->planes.data());
    }
    return Status::Ok();
  });
}

Status Octree::DropBrick(uint32_t id, const NodeKey& key) {
  uint32_t brick;
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    brick = nodes_[id].brick;
    nodes_[id].brick = 0;
  }
  plane_tables_.erase(id);
  pool_.Free(brick);
  changes_.Append(id, NodeChangeKind::kUpdated);
  // Neighbours' aprons showed this node's voxels; now they must show its average.
  return RefreshAprons(key.level, geometry_.NodeBox(key));
}

Status Octree::DeleteChildren(uint32_t id, const NodeKey& key) {
  std::vector<uint32_t> groups;
  std::vector<uint32_t> stack{nodes_[id].child_group};
  while (!stack.empty()) {
    const uint32_t g = stack.back();
    stack.pop_back();
    groups.push_back(g);
    for (uint32_t n = g * 8; n < g * 8 + 8; ++n) {
      if (nodes_[n].child_group != 0) stack.push_back(nodes_[n].child_group);
    }
  }
  std::vector<uint32_t> bricks;
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    for (uint32_t g : groups) {
      for (uint32_t n = g * 8; n < g * 8 + 8; ++n) {
        if (nodes_[n].brick != 0) bricks.push_back(nodes_[n].brick);
        nodes_[n] = NodeRecord{};
        progress_.erase(n);
        plane_tables_.erase(n);
      }
      group_parent_[g] = kFreeGroup;
      free_groups_.insert(g);
    }
    nodes_[id].child_group = 0;
  }
  for (uint32_t b : bricks) pool_.Free(b);
  for (uint32_t g : groups) {
    for (uint32_t n = g * 8; n < g * 8 + 8; ++n) changes_.Append(n, NodeChangeKind::kDeleted);
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  // At every level below, the bricks around this node's region showed the deleted nodes'
  // averages; now the region is represented by this node's average.
  for (int level = key.level - 1; level >= 0; --level) {
    OCTO_RETURN_IF_ERROR(
        RefreshAprons(level, RefineBox(geometry_.NodeBox(key), key.level - level)));
  }
  return Status::Ok();
}

Status Octree::RefreshAprons(int level, const Box& region) {
  const Box valid_region = region.Intersect(geometry_.ValidExtent(level));
  if (valid_region.empty()) return Status::Ok();
  const Box storing =
      geometry_.NodesStoringAny(level, valid_region).Intersect(geometry_.NonVirtualNodes(level));
  const Box owning = geometry_.NodesIntersecting(level, valid_region);
  std::vector<uint16_t> values;
  for (int64_t z = storing.lo[2]; z < storing.hi[2]; ++z) {
    for (int64_t y = storing.lo[1]; y < storing.hi[1]; ++y) {
      const bool yz_inside =
          owning.lo[1] <= y && y < owning.hi[1] && owning.lo[2] <= z && z < owning.hi[2];
      for (int64_t x = storing.lo[0]; x < storing.hi[0]; ++x) {
        // Only the shell around the region: nodes inside it are the ones that changed.
        if (yz_inside && owning.lo[0] <= x && x < owning.hi[0]) {
          x = owning.hi[0] - 1;
          continue;
        }
        const NodeKey nk{level, {x, y, z}};
        const Located loc = Locate(nk);
        if (!loc.exact || nodes_[loc.id].brick == 0) continue;
        const Box part = geometry_.StoredBox(nk).Intersect(valid_region);
        if (part.empty()) continue;
        values.resize(part.VoxelCount());
        for (int c = 0; c < channels_; ++c) {
          OCTO_RETURN_IF_ERROR(ReadRepresentation(level, part, c, values.data()));
          const Lane lane{c, values.data()};
          OCTO_RETURN_IF_ERROR(
              PutRegion(nodes_[loc.id].brick, nk, part, std::span<const Lane>(&lane, 1), part));
        }
        changes_.Append(loc.id, NodeChangeKind::kUpdated);
      }
    }
  }
  return Status::Ok();
}

// --------------------------------------------------------------------------------------------
// Voxel access.

Status Octree::PutRegion(uint32_t brick, const NodeKey& key, const Box& region, Lanes lanes,
                         const Box& src_box, Touched* touched) const {
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  handle.MarkDirty();
  std::lock_guard<std::mutex> brick_lock(BrickLock(brick));
  const BrickLayout layout(geometry_, key);
  WithLayout(geometry_.bytes_per_sample(), channels_, [&](auto l) {
    if (touched != nullptr) {
      WriteBrickRegion<decltype(l)>(handle.data().data(), layout, region, lanes, src_box, nullptr,
                                    touched->written, touched->planes.data());
    } else {
      WriteBrickRegion<decltype(l)>(handle.data().data(), layout, region, lanes, src_box, nullptr,
                                    Box{}, static_cast<SampleStats*>(nullptr));
    }
  });
  return Status::Ok();
}

Result<Octree::SampleStats> Octree::ScanPlane(uint32_t brick, const NodeKey& key, int c,
                                              int64_t z) const {
  OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
  const std::byte* data = std::as_const(handle).data().data();
  const BrickLayout layout(geometry_, key);
  const Box valid = geometry_.ValidBox(key);
  SampleStats st;
  WithLayout(geometry_.bytes_per_sample(), channels_, [&](auto l) {
    for (int64_t y = valid.lo[1]; y < valid.hi[1]; ++y) {
      ScanRow<decltype(l)>(data + layout.ByteOffset(valid.lo[0], y, z, c), layout.channels,
                           valid.Extent(0), st.lo, st.hi, st.sum);
    }
  });
  return st;
}

Status Octree::ForEach(size_t n, const std::function<Status(size_t)>& fn) const {
  if (workers_ != nullptr && n > 1) return workers_->ParallelFor(n, fn);
  for (size_t i = 0; i < n; ++i) OCTO_RETURN_IF_ERROR(fn(i));
  return Status::Ok();
}

Status Octree::ReadRepresentation(int level, const Box& box, int c, uint16_t* out) const {
  const Box valid = box.Intersect(geometry_.ValidExtent(level));
  if (valid != box) std::fill(out, out + box.VoxelCount(), background_[c]);  // Virtual voxels.
  if (valid.empty()) return Status::Ok();
  const Box nodes =
      geometry_.NodesIntersecting(level, valid).Intersect(geometry_.NonVirtualNodes(level));
  return WithLayout(geometry_.bytes_per_sample(), channels_, [&](auto l) -> Status {
    using L = decltype(l);
    for (int64_t iz = nodes.lo[2]; iz < nodes.hi[2]; ++iz) {
      for (int64_t iy = nodes.lo[1]; iy < nodes.hi[1]; ++iy) {
        for (int64_t ix = nodes.lo[0]; ix < nodes.hi[0]; ++ix) {
          const NodeKey key{level, {ix, iy, iz}};
          const Box region = geometry_.NodeBox(key).Intersect(valid);
          const int64_t n = region.Extent(0);
          const Located loc = Locate(key);
          const uint32_t brick = loc.exact ? nodes_[loc.id].brick : 0;
          if (brick == 0) {
            // The node (or its deepest existing ancestor) shows its uniform value.
            const uint16_t u = Uniform(loc.id, c);
            for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
              for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
                uint16_t* row = out + BufferIndex(box, region.lo[0], y, z);
                std::fill(row, row + n, u);
              }
            }
            continue;
          }
          OCTO_ASSIGN_OR_RETURN(BrickHandle handle, pool_.Pin(brick));
          const std::byte* data = std::as_const(handle).data().data();
          const BrickLayout layout(geometry_, key);
          for (int64_t z = region.lo[2]; z < region.hi[2]; ++z) {
            for (int64_t y = region.lo[1]; y < region.hi[1]; ++y) {
              LoadRow<L>(data + layout.ByteOffset(region.lo[0], y, z, c), layout.channels,
                         out + BufferIndex(box, region.lo[0], y, z), n);
            }
          }
        }
      }
    }
    return Status::Ok();
  });
}

Status Octree::WriteLevel(int level, const Box& box, Lanes lanes, std::vector<Touched>* touched) {
  const Box nodes =
      geometry_.NodesStoringAny(level, box).Intersect(geometry_.NonVirtualNodes(level));
  // Serial: the work list, with the nodes (and so the structure) created first.
  std::vector<LevelItem> items;
  for (int64_t iz = nodes.lo[2]; iz < nodes.hi[2]; ++iz) {
    for (int64_t iy = nodes.lo[1]; iy < nodes.hi[1]; ++iy) {
      for (int64_t ix = nodes.lo[0]; ix < nodes.hi[0]; ++ix) {
        LevelItem item;
        item.key = NodeKey{level, {ix, iy, iz}};
        const Box interior = geometry_.NodeBox(item.key).Intersect(box);
        if (interior.empty()) {
          // Only the apron of this node overlaps: update it if the node exists with a brick.
          const Located loc = Locate(item.key);
          if (!loc.exact || nodes_[loc.id].brick == 0) continue;
          item.id = loc.id;
          item.brick = nodes_[loc.id].brick;
          item.apron_only = true;
          items.push_back(std::move(item));
          continue;
        }
        OCTO_ASSIGN_OR_RETURN(item.id, EnsureNode(item.key));
        if (level == 0) {
          for (const Lane& lane : lanes) MarkLeafWritten(item.id, item.key, interior, lane.channel);
        }
        item.brick = nodes_[item.id].brick;
        items.push_back(std::move(item));
      }
    }
  }
  // Parallel, read-only on the node table: which brickless nodes receive a value different from
  // their uniform one (only those need a brick).
  OCTO_RETURN_IF_ERROR(ForEach(items.size(), [&](size_t i) -> Status {
    LevelItem& item = items[i];
    if (item.apron_only || item.brick != 0) return Status::Ok();
    const Box interior = geometry_.NodeBox(item.key).Intersect(box);
    const int64_t n = interior.Extent(0);
    bool differs = false;
    for (const Lane& lane : lanes) {
      const uint16_t u = Uniform(item.id, lane.channel);
      for (int64_t z = interior.lo[2]; z < interior.hi[2] && !differs; ++z) {
        for (int64_t y = interior.lo[1]; y < interior.hi[1] && !differs; ++y) {
          const uint16_t* row = lane.values + BufferIndex(box, interior.lo[0], y, z);
          differs = std::any_of(row, row + n, [u](uint16_t v) { return v != u; });
        }
      }
      if (differs) break;
    }
    item.unchanged = !differs;
    item.allocate = differs;
    return Status::Ok();
  }));
  // Serial: brick ids for the nodes that need one (deterministic order).
  Status status;
  for (LevelItem& item : items) {
    if (!item.allocate) continue;
    auto brick = pool_.Allocate();
    if (!brick.ok()) {
      status = brick.status();
      break;
    }
    item.brick = *brick;
  }
  // Parallel: every item writes only its own brick (the new ones are not published yet, so a
  // neighbour's apron initialisation sees their uniform value — what the new brick holds outside
  // the block too); statistics of the written values are gathered per item.
  if (status.ok()) {
    status = ForEach(items.size(), [&](size_t i) -> Status {
      LevelItem& item = items[i];
      if (item.unchanged) return Status::Ok();
      const Box part = geometry_.StoredBox(item.key).Intersect(box);
      if (item.apron_only) return PutRegion(item.brick, item.key, part, lanes, box);
      Touched& t = item.touched;
      t.id = item.id;
      t.written = geometry_.ValidBox(item.key).Intersect(box);
      t.planes.assign(lanes.size() * static_cast<size_t>(t.written.Extent(2)), SampleStats{});
      if (item.allocate) return InitBrick(item.brick, item.id, item.key, lanes, box, &t);
      return PutRegion(item.brick, item.key, part, lanes, box, &t);
    });
  }
  // Serial: publish the new bricks (or return them on error), record the changes.
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    for (LevelItem& item : items) {
      if (item.allocate && item.brick != 0 && status.ok()) nodes_[item.id].brick = item.brick;
    }
  }
  for (LevelItem& item : items) {
    if (!status.ok()) {
      if (item.allocate && item.brick != 0) pool_.Free(item.brick);
      continue;
    }
    if (!item.unchanged) changes_.Append(item.id, NodeChangeKind::kUpdated);
    if (item.apron_only) continue;
    if (item.unchanged) item.touched.id = item.id;
    touched->push_back(std::move(item.touched));
  }
  return status;
}

void Octree::MarkLeafWritten(uint32_t id, const NodeKey& key, const Box& box, int c) {
  if ((nodes_[id].flags & kComplete) != 0) return;
  LeafProgress& progress = progress_[id];
  if ((progress.complete_channels >> c) & 1) return;
  if (progress.channels.empty()) progress.channels.resize(channels_);
  const Box valid = geometry_.ValidBox(key);
  std::unique_ptr<WriteCoverage>& coverage = progress.channels[c];
  if (!coverage) {
    coverage =
        std::make_unique<WriteCoverage>(Vec3{valid.Extent(0), valid.Extent(1), valid.Extent(2)});
  }
  const Box b = box.Intersect(valid);
  coverage->Mark(Box{{b.lo[0] - valid.lo[0], b.lo[1] - valid.lo[1], b.lo[2] - valid.lo[2]},
                     {b.hi[0] - valid.lo[0], b.hi[1] - valid.lo[1], b.hi[2] - valid.lo[2]}});
  if (!coverage->complete()) return;
  coverage.reset();
  progress.complete_channels |= uint64_t{1} << c;
  const uint64_t all = channels_ == 64 ? ~uint64_t{0} : (uint64_t{1} << channels_) - 1;
  if (progress.complete_channels == all) {
    progress_.erase(id);
    std::unique_lock<std::shared_mutex> lock(mu_);
    nodes_[id].flags |= kComplete;
  }
}

// Step 3 for one node: statistics of the lanes' channels, completeness, pruning.
Status Octree::UpdateNode(const Touched& touched, Lanes lanes) {
  const uint32_t id = touched.id;
  if ((nodes_[id].flags & kLive) == 0) return Status::Ok();  // Deleted by an ancestor meanwhile.
  const NodeKey key = KeyOf(id);
  const uint32_t brick = nodes_[id].brick;
  const Box valid = geometry_.ValidBox(key);
  const int64_t valid_planes = valid.Extent(2);
  const int64_t written_planes = touched.written.Extent(2);
  // A write that covers whole planes of the valid interior gives those planes' statistics; a
  // partial one leaves them to a rescan of the plane.
  const bool whole_planes = !touched.written.empty() &&
                            touched.written.Extent(0) == valid.Extent(0) &&
                            touched.written.Extent(1) == valid.Extent(1);
  std::vector<ChannelStats> updated(lanes.size());
  for (size_t li = 0; li < lanes.size(); ++li) {
    const int c = lanes[li].channel;
    ChannelStats s = Stat(id, c);
    if (brick != 0) {
      SampleStats total;
      if (touched.written == valid) {
        // The whole brick was just written: its statistics are known.
        const SampleStats* written = touched.planes.data() + li * written_planes;
        for (int64_t z = 0; z < written_planes; ++z) total.Add(written[z]);
        if (auto it = plane_tables_.find(id);
            it != plane_tables_.end() && ((it->second.known >> c) & 1) != 0) {
          std::copy(written, written + written_planes,
                    it->second.planes.begin() + static_cast<size_t>(c) * valid_planes);
        }
      } else {
        // Keep exact per-plane statistics of this incomplete node, so that the rest of the brick
        // is never rescanned.
        PlaneTable& table = plane_tables_[id];
        if (table.planes.empty())
          table.planes.resize(static_cast<size_t>(channels_ * valid_planes));
        SampleStats* planes = table.planes.data() + static_cast<size_t>(c) * valid_planes;
        if (((table.known >> c) & 1) == 0) {
          // First partial write of this channel: one scan of every plane (already written ones
          // included).
          for (int64_t z = 0; z < valid_planes; ++z) {
            OCTO_ASSIGN_OR_RETURN(planes[z], ScanPlane(brick, key, c, valid.lo[2] + z));
          }
          table.known |= uint64_t{1} << c;
        } else {
          for (int64_t z = touched.written.lo[2]; z < touched.written.hi[2]; ++z) {
            const int64_t p = z - valid.lo[2];
            if (whole_planes) {
              planes[p] = touched.planes[li * written_planes + (z - touched.written.lo[2])];
            } else {
              OCTO_ASSIGN_OR_RETURN(planes[p], ScanPlane(brick, key, c, z));
            }
          }
        }
        for (int64_t z = 0; z < valid_planes; ++z) total.Add(planes[z]);
      }
      s.min = static_cast<uint16_t>(total.lo);
      s.max = static_cast<uint16_t>(total.hi);
      s.avg = static_cast<double>(total.sum) / static_cast<double>(valid.VoxelCount());
    } else {
      s.min = s.max = Uniform(id, c);
    }
    // A childless node's subtree is itself, unless its children were deleted as homogeneous:
    // then the stored subtree range (their data's) stays.
    const bool children_deleted =
        key.level > 0 && nodes_[id].child_group == 0 && (nodes_[id].flags & kComplete) != 0;
    if (!children_deleted) {
      s.sub_min = s.min;
      s.sub_max = s.max;
    } else {
      s.sub_min = std::min(s.sub_min, s.min);
      s.sub_max = std::max(s.sub_max, s.max);
    }
    const uint32_t group = nodes_[id].child_group;
    if (group != 0) {
      for (uint32_t child = group * 8; child < group * 8 + 8; ++child) {
        if ((nodes_[child].flags & kVirtual) != 0) continue;  // Virtual voxels never count.
        s.sub_min = std::min(s.sub_min, Stat(child, c).sub_min);
        s.sub_max = std::max(s.sub_max, Stat(child, c).sub_max);
      }
    }
    updated[li] = s;
  }
  bool complete = (nodes_[id].flags & kComplete) != 0;
  const uint32_t group = nodes_[id].child_group;
  if (group != 0) {
    complete = true;
    for (uint32_t child = group * 8; child < group * 8 + 8; ++child) {
      if ((nodes_[child].flags & kComplete) == 0) complete = false;
    }
  }
  {
    std::unique_lock<std::shared_mutex> lock(mu_);
    for (size_t li = 0; li < lanes.size(); ++li) Stat(id, lanes[li].channel) = updated[li];
    if (complete) nodes_[id].flags |= kComplete;
  }
  changes_.Append(id, NodeChangeKind::kUpdated);
  if (!complete) return Status::Ok();  // Incomplete nodes are never pruned.
  plane_tables_.erase(id);             // Its statistics are final until the next overwrite.

  bool brick_homogeneous = true, subtree_homogeneous = true;
  for (int ch = 0; ch < channels_; ++ch) {
    const ChannelStats& t = Stat(id, ch);
    if (t.max - t.min > static_cast<int64_t>(tolerance_[ch])) brick_homogeneous = false;
    if (t.sub_max - t.sub_min > static_cast<int64_t>(tolerance_[ch])) subtree_homogeneous = false;
  }
  if (brick != 0 && brick_homogeneous) OCTO_RETURN_IF_ERROR(DropBrick(id, key));
  // The subtree statistics keep describing the deleted subtree's data (its true range), so an
  // ancestor's homogeneity test sees the same numbers whenever the deletion happened.
  if (group != 0 && subtree_homogeneous) OCTO_RETURN_IF_ERROR(DeleteChildren(id, key));
  return Status::Ok();
}

// --------------------------------------------------------------------------------------------
// Insert.

Status Octree::Insert(int channel, const Box& box, std::span<const std::byte> data) {
  const ChannelBlock block{channel, data};
  return Insert(box, std::span<const ChannelBlock>(&block, 1));
}

Status Octree::Insert(const Box& box, std::span<const ChannelBlock> blocks, WorkerPool* workers) {
  if (box.empty() || !geometry_.ValidExtent(0).ContainsBox(box)) {
    return OutOfRangeError("octree: block " + box.ToString() + " is empty or outside the volume " +
                           geometry_.ValidExtent(0).ToString());
  }
  const int bps = geometry_.bytes_per_sample();
  const uint64_t voxels = box.VoxelCount();
  uint64_t seen = 0;
  for (const ChannelBlock& b : blocks) {
    if (b.channel < 0 || b.channel >= channels_) {
      return InvalidArgumentError("octree: channel " + std::to_string(b.channel) + " of " +
                                  std::to_string(channels_));
    }
    if ((seen >> b.channel) & 1) {
      return InvalidArgumentError("octree: channel " + std::to_string(b.channel) +
                                  " given twice in one insert");
    }
    seen |= uint64_t{1} << b.channel;
    if (b.data.size() != voxels * static_cast<uint64_t>(bps)) {
      return InvalidArgumentError("octree: block " + box.ToString() + " needs " +
                                  std::to_string(voxels * bps) + " bytes, got " +
                                  std::to_string(b.data.size()));
    }
  }
  if (blocks.empty()) return Status::Ok();
  std::lock_guard<std::mutex> insert_lock(insert_mu_);
  workers_ = workers;
  // The blocks as uint16 samples, ascending by channel. 16-bit data is used in place when it is
  // aligned.
  const size_t n_lanes = blocks.size();
  std::vector<std::vector<uint16_t>> level_values(n_lanes);
  std::vector<Lane> lanes(n_lanes);
  for (size_t li = 0; li < n_lanes; ++li) {
    const ChannelBlock& b = blocks[li];
    lanes[li].channel = b.channel;
    if (bps == 2 && reinterpret_cast<uintptr_t>(b.data.data()) % alignof(uint16_t) == 0) {
      lanes[li].values = reinterpret_cast<const uint16_t*>(b.data.data());
      continue;
    }
    level_values[li].resize(voxels);
    if (bps == 2) {
      std::memcpy(level_values[li].data(), b.data.data(), b.data.size());
    } else {
      const auto* bytes = reinterpret_cast<const uint8_t*>(b.data.data());
      std::copy(bytes, bytes + voxels, level_values[li].begin());
    }
    lanes[li].values = level_values[li].data();
  }
  std::sort(lanes.begin(), lanes.end(),
            [](const Lane& a, const Lane& b) { return a.channel < b.channel; });

  const int root = geometry_.root_level();
  std::vector<std::vector<Touched>> touched(root + 1);
  // Step 1: the leaves.
  OCTO_RETURN_IF_ERROR(WriteLevel(0, box, lanes, &touched[0]));
  // Step 2: the path to the root, one level at a time. The lanes hold level L-1 over `dirty`.
  Box dirty = box;
  std::vector<std::vector<uint16_t>> children(n_lanes), parents(n_lanes);
  for (int level = 1; level <= root; ++level) {
    const Box cover = CoarsenBox(dirty).Intersect(geometry_.ValidExtent(level));
    const Box child_box = RefineBox(cover).Intersect(geometry_.ValidExtent(level - 1));
    OCTO_RETURN_IF_ERROR(ForEach(n_lanes, [&](size_t li) -> Status {
      const uint16_t* child_values = lanes[li].values;
      if (child_box != dirty) {
        // The cover's children reach beyond what was just written: read them all back. (When
        // they coincide, the level's representation over `dirty` is exactly the lane.)
        children[li].resize(child_box.VoxelCount());
        OCTO_RETURN_IF_ERROR(
            ReadRepresentation(level - 1, child_box, lanes[li].channel, children[li].data()));
        child_values = children[li].data();
      }
      parents[li].resize(cover.VoxelCount());
      Downsample(child_values, child_box, cover, parents[li].data());
      return Status::Ok();
    }));
    for (size_t li = 0; li < n_lanes; ++li) {
      level_values[li].swap(parents[li]);  // Keeps the values alive; `parents` is reused.
      lanes[li].values = level_values[li].data();
    }
    OCTO_RETURN_IF_ERROR(WriteLevel(level, cover, lanes, &touched[level]));
    dirty = cover;
  }
  // Step 3: statistics, completeness and pruning, bottom-up so children are final first.
  for (int level = 0; level <= root; ++level) {
    // Each node is written at most once per level and insert; ascending ids keep the order
    // of pruning (and so brick id reuse) deterministic.
    std::vector<Touched>& nodes = touched[level];
    std::sort(nodes.begin(), nodes.end(),
              [](const Touched& a, const Touched& b) { return a.id < b.id; });
    for (const Touched& t : nodes) OCTO_RETURN_IF_ERROR(UpdateNode(t, lanes));
  }
  return Status::Ok();
}

std::vector<uint32_t> Octree::PruningError() const {
  std::vector<uint32_t> error(channels_, 0);
  std::shared_lock<std::shared_mutex> lock(mu_);
  for (uint32_t id = 0; id < nodes_.size(); ++id) {
    if (!IsLiveId(id)) continue;
    const NodeRecord& r = nodes_[id];
    // A terminal node without a brick shows its uniform value for its whole region.
    if ((r.flags & kVirtual) != 0 || r.brick != 0 || r.child_group != 0) continue;
    for (int c = 0; c < channels_; ++c) {
      const ChannelStats& st = Stat(id, c);
      const int u = Uniform(id, c);
      const int e = std::max(static_cast<int>(st.sub_max) - u, u - static_cast<int>(st.sub_min));
      error[c] = std::max<uint32_t>(error[c], static_cast<uint32_t>(std::max(e, 0)));
    }
  }
  return error;
}

}  // namespace octoscope::octree
