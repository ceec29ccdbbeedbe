// ChunkedVolume: slabs assembled from chunks of any dimension order and stored layout (C order,
// transposed), chunks reaching beyond the image, absent chunks as the fill value; each chunk
// decoded once per pass when slabs are chunk-aligned or thinner (the cache), also when channels
// share a chunk; reader errors reach the caller; the stats pass reads chunk-aligned slabs.
#include "io/chunked_volume.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <map>
#include <mutex>

#include "io/volume_stats.h"

namespace octoscope::io {
namespace {

// The value of voxel (x, y, z) of channel c at time t: unique per voxel within uint16.
uint16_t Pattern(int64_t t, int64_t c, int64_t z, int64_t y, int64_t x) {
  return static_cast<uint16_t>((((t * 3 + c) * 7 + z) * 13 + y) * 17 + x);
}

// A reader that computes chunks from Pattern, laid out per `layout`, counting decodes; chunks
// whose index is in `absent` do not exist, `failing` ones fail.
class PatternReader final : public ChunkReader {
 public:
  PatternReader(ChunkLayout layout, std::vector<std::vector<int64_t>> absent = {},
                std::vector<std::vector<int64_t>> failing = {})
      : layout_(std::move(layout)), absent_(std::move(absent)), failing_(std::move(failing)) {}

  Result<bool> ReadChunk(std::span<const int64_t> index, std::span<std::byte> out) override {
    std::vector<int64_t> idx(index.begin(), index.end());
    {
      std::lock_guard lock(mutex_);
      ++decodes_[idx];
    }
    for (const auto& a : absent_) {
      if (a == idx) return false;
    }
    for (const auto& f : failing_) {
      if (f == idx) return CorruptError("chunk file x/y/z is damaged");
    }
    const size_t dims = layout_.shape.size();
    std::vector<int64_t> local(dims, 0);
    uint16_t* v = reinterpret_cast<uint16_t*>(out.data());
    // Every element of the chunk (also beyond the image, as files store them).
    while (true) {
      int64_t coord[5] = {0, 0, 0, 0, 0};  // t, c, z, y, x
      const int named[5] = {layout_.time_dim, layout_.channel_dim, layout_.z_dim, layout_.y_dim,
                            layout_.x_dim};
      for (int k = 0; k < 5; ++k) {
        if (named[k] >= 0) coord[k] = index[named[k]] * layout_.chunk[named[k]] + local[named[k]];
      }
      int64_t at = 0;
      for (size_t d = 0; d < dims; ++d) at += local[d] * layout_.strides[d];
      v[at] = Pattern(coord[0], coord[1], coord[2], coord[3], coord[4]);
      size_t d = dims;
      while (d-- > 0) {
        if (++local[d] < layout_.chunk[d]) break;
        local[d] = 0;
      }
      if (d == static_cast<size_t>(-1)) break;
    }
    return true;
  }

  int MaxDecodes() {
    std::lock_guard lock(mutex_);
    int m = 0;
    for (const auto& [k, n] : decodes_) m = std::max(m, n);
    return m;
  }
  size_t DistinctChunks() {
    std::lock_guard lock(mutex_);
    return decodes_.size();
  }

 private:
  const ChunkLayout layout_;
  std::vector<std::vector<int64_t>> absent_, failing_;
  std::mutex mutex_;
  std::map<std::vector<int64_t>, int> decodes_;
};

struct TestVolume {
  std::unique_ptr<VolumeSource> source;
  PatternReader* reader = nullptr;
};

// dims in the order given by `axes` (letters of "tczyx"), sizes and chunk sizes per letter.
TestVolume Make(const std::string& axes, std::map<char, int64_t> size,
                std::map<char, int64_t> chunk, std::vector<int> order = {}, int time = 0,
                std::vector<std::vector<int64_t>> absent = {},
                std::vector<std::vector<int64_t>> failing = {}, uint64_t cache = 1 << 26) {
  ChunkLayout layout;
  for (size_t d = 0; d < axes.size(); ++d) {
    layout.shape.push_back(size[axes[d]]);
    layout.chunk.push_back(chunk[axes[d]]);
    int& slot = axes[d] == 'x'   ? layout.x_dim
                : axes[d] == 'y' ? layout.y_dim
                : axes[d] == 'z' ? layout.z_dim
                : axes[d] == 'c' ? layout.channel_dim
                                 : layout.time_dim;
    slot = static_cast<int>(d);
  }
  layout.strides = ChunkLayout::StridesFor(layout.chunk, order);
  volume::VolumeInfo info;
  info.format = "test";
  info.dtype = volume::DataType::kUint16;
  info.size = {size['x'], size.count('y') ? size['y'] : 1, size.count('z') ? size['z'] : 1};
  info.channels.resize(static_cast<size_t>(size.count('c') ? size['c'] : 1));
  info.time_points = static_cast<int>(size.count('t') ? size['t'] : 1);
  info.time = time;
  auto reader = std::make_unique<PatternReader>(layout, absent, failing);
  TestVolume s;
  s.reader = reader.get();
  ChunkedVolumeOptions options;
  options.name = "test.zarr";
  options.fill_value = 4242;
  options.cache_bytes = cache;
  options.threads = 3;
  auto made = MakeChunkedVolume(info, layout, std::move(reader), options);
  EXPECT_TRUE(made.ok()) << made.status().ToString();
  if (made.ok()) s.source = std::move(*made);
  return s;
}

// Reads every channel in slabs of `nz` (z-major, channels inner) and checks every voxel.
void ExpectPattern(VolumeSource& source, int64_t nz, int time = 0,
                   const std::vector<std::array<int64_t, 3>>& fill_boxes_zyx_chunk = {},
                   std::array<int64_t, 3> chunk_zyx = {1, 1, 1}) {
  const volume::VolumeInfo& info = source.info();
  for (int64_t z0 = 0; z0 < info.size[2]; z0 += nz) {
    const int64_t n = std::min(nz, info.size[2] - z0);
    for (int c = 0; c < info.channel_count(); ++c) {
      std::vector<std::byte> slab(source.SlabBytes(n));
      ASSERT_TRUE(source.ReadSlab(c, z0, n, slab).ok());
      const uint16_t* v = reinterpret_cast<const uint16_t*>(slab.data());
      for (int64_t z = 0; z < n; ++z) {
        for (int64_t y = 0; y < info.size[1]; ++y) {
          for (int64_t x = 0; x < info.size[0]; ++x) {
            bool fill = false;
            for (const auto& b : fill_boxes_zyx_chunk) {
              fill = fill || ((z0 + z) / chunk_zyx[0] == b[0] && y / chunk_zyx[1] == b[1] &&
                              x / chunk_zyx[2] == b[2]);
            }
            const uint16_t want = fill ? 4242 : Pattern(time, c, z0 + z, y, x);
            ASSERT_EQ(v[(z * info.size[1] + y) * info.size[0] + x], want)
                << "c " << c << " z " << z0 + z << " y " << y << " x " << x;
          }
        }
      }
    }
  }
}

TEST(ChunkedVolume, AnyDimensionOrderAndStoredLayout) {
  const std::map<char, int64_t> size = {{'t', 3}, {'c', 3}, {'z', 9}, {'y', 10}, {'x', 11}};
  const std::map<char, int64_t> chunk = {{'t', 2}, {'c', 2}, {'z', 4}, {'y', 3}, {'x', 5}};
  for (const std::string axes : {"tczyx", "xyzct", "zcytx", "yxz", "cyx"}) {
    for (bool transposed : {false, true}) {
      SCOPED_TRACE(axes + (transposed ? " transposed" : ""));
      std::vector<int> order;
      if (transposed) {
        for (int d = static_cast<int>(axes.size()); d-- > 0;) order.push_back(d);
      }
      std::map<char, int64_t> s, k;
      for (char a : axes) {
        s[a] = size.at(a);
        k[a] = chunk.at(a);
      }
      for (int t : {0, 2}) {
        if (t > 0 && axes.find('t') == std::string::npos) continue;
        TestVolume setup = Make(axes, s, k, order, t);
        ASSERT_TRUE(setup.source);
        for (int64_t nz : {1, 3, 4, 9}) ExpectPattern(*setup.source, nz, t);
      }
    }
  }
}

TEST(ChunkedVolume, AbsentChunksAreTheFillValue) {
  TestVolume s =
      Make("czyx", {{'c', 2}, {'z', 6}, {'y', 7}, {'x', 8}},
           {{'c', 1}, {'z', 3}, {'y', 4}, {'x', 4}}, {}, 0, {{0, 1, 0, 1}, {1, 1, 0, 1}});
  ExpectPattern(*s.source, 6, 0, {{1, 0, 1}}, {3, 4, 4});
}

TEST(ChunkedVolume, EachChunkDecodedOncePerPass) {
  // Aligned slabs, thinner slabs (served by the cache) and one-plane slabs, with two channels
  // sharing each chunk: every chunk is decoded exactly once.
  for (int64_t nz : {4, 2, 1, 3}) {
    SCOPED_TRACE(nz);
    TestVolume s = Make("czyx", {{'c', 2}, {'z', 12}, {'y', 9}, {'x', 9}},
                        {{'c', 2}, {'z', 4}, {'y', 4}, {'x', 4}});
    ExpectPattern(*s.source, nz);
    EXPECT_EQ(s.reader->MaxDecodes(), 1);
    EXPECT_EQ(s.reader->DistinctChunks(), 3u * 3 * 3);
  }
}

TEST(ChunkedVolume, WholePlaneChunksDecodeInPlace) {
  // Chunks of whole planes (as Imaris and many Zarr writers store them), read aligned (in place),
  // thinner (through the cache), across the partial last chunk, with absent chunks.
  for (int64_t nz : {4, 8, 1, 3, 10}) {
    SCOPED_TRACE(nz);
    TestVolume s =
        Make("czyx", {{'c', 2}, {'z', 10}, {'y', 9}, {'x', 7}},
             {{'c', 1}, {'z', 4}, {'y', 9}, {'x', 7}}, {}, 0, {{0, 1, 0, 0}, {1, 1, 0, 0}});
    ExpectPattern(*s.source, nz, 0, {{1, 0, 0}}, {4, 9, 7});
    EXPECT_EQ(s.reader->MaxDecodes(), 1);
  }
}

TEST(ChunkedVolume, PreferredSlabPlanesIsTheChunkDepth) {
  TestVolume s = Make("zyx", {{'z', 12}, {'y', 9}, {'x', 9}}, {{'z', 5}, {'y', 4}, {'x', 4}});
  EXPECT_EQ(s.source->PreferredSlabPlanes(), 5);
  TestVolume flat = Make("yx", {{'y', 9}, {'x', 9}}, {{'y', 4}, {'x', 4}});
  EXPECT_EQ(flat.source->PreferredSlabPlanes(), 1);
}

TEST(ChunkedVolume, StatsPassReadsChunkAlignedSlabs) {
  // Chunks of 8 planes of 64x64: the stats pass (4 MB slabs would be 512 planes here) uses
  // slabs of whole chunk depths; with no cache at all every chunk is still decoded once.
  TestVolume s = Make("czyx", {{'c', 2}, {'z', 40}, {'y', 64}, {'x', 64}},
                      {{'c', 1}, {'z', 8}, {'y', 32}, {'x', 32}}, {}, 0, {}, {}, /*cache=*/0);
  StatsOptions options;
  options.slab_bytes = 64 * 64 * 2 * 3;  // 3 planes: not a multiple of the chunk depth.
  auto stats = ComputeVolumeStats(*s.source, options);
  ASSERT_TRUE(stats.ok());
  EXPECT_EQ(s.reader->MaxDecodes(), 1);
}

TEST(ChunkedVolume, ReaderErrorsReachTheCaller) {
  TestVolume s = Make("zyx", {{'z', 8}, {'y', 8}, {'x', 8}}, {{'z', 4}, {'y', 4}, {'x', 4}}, {}, 0,
                      {}, {{1, 1, 0}});
  std::vector<std::byte> slab(s.source->SlabBytes(8));
  Status st = s.source->ReadSlab(0, 0, 8, slab);
  EXPECT_EQ(st.code(), StatusCode::kCorrupt);
  EXPECT_NE(st.message().find("x/y/z is damaged"), std::string::npos);
  // The failure is not cached: the next read fails the same way, the good half still reads.
  EXPECT_EQ(s.source->ReadSlab(0, 4, 4, std::span(slab).first(s.source->SlabBytes(4))).code(),
            StatusCode::kCorrupt);
  EXPECT_TRUE(s.source->ReadSlab(0, 0, 4, std::span(slab).first(s.source->SlabBytes(4))).ok());
  EXPECT_EQ(s.source->ReadSlab(1, 0, 4, std::span(slab).first(s.source->SlabBytes(4))).code(),
            StatusCode::kOutOfRange);
}

TEST(ChunkedVolume, InconsistentLayoutsAreRefused) {
  ChunkLayout layout;
  layout.shape = {4, 4};
  layout.chunk = {2, 2};
  layout.strides = {2, 2};  // Overlapping: addresses beyond nothing, but x never reaches 3.
  layout.x_dim = 1;
  layout.y_dim = 1;  // Named twice.
  volume::VolumeInfo info;
  info.channels.resize(1);
  info.size = {4, 4, 1};
  auto made = MakeChunkedVolume(info, layout, std::make_unique<PatternReader>(layout), {});
  EXPECT_EQ(made.status().code(), StatusCode::kInternal);
}

}  // namespace
}  // namespace octoscope::io
