// BuildOctree tests: streaming a source slab by slab through the reader threads (recycled slab
// buffers, the identity shortcut that inserts slabs as read, and a real conversion) gives the same
// tree as inserting the converted volume directly.
#include "octree/octree_builder.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <stdexcept>
#include <stop_token>
#include <thread>
#include <vector>

#include "io/volume_source.h"
#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::DumpTree;
using testing::ExpectSameTree;
using testing::MakePatternVolume;
using testing::SourceVolume;
using testing::TreeFixture;

// An in-memory source whose file type is uint16 or int16 (int16 samples are the pattern's values
// minus 32768, so the fixed value map converts them back).
class MemorySource : public io::VolumeSource {
 public:
  MemorySource(const SourceVolume& volume, volume::DataType dtype) : volume_(volume) {
    info_.format = "raw";
    info_.size = volume.size;
    info_.channels.resize(volume.channels);
    info_.dtype = dtype;
  }
  const volume::VolumeInfo& info() const override { return info_; }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    const size_t plane = static_cast<size_t>(volume_.size[0] * volume_.size[1]);
    const uint16_t* src = volume_.data[channel].data() + static_cast<size_t>(z0) * plane;
    const size_t count = static_cast<size_t>(nz) * plane;
    if (out.size() != count * 2) return InvalidArgumentError("slab size");
    for (size_t i = 0; i < count; ++i) {
      const uint16_t v =
          info_.dtype == volume::DataType::kInt16 ? static_cast<uint16_t>(src[i] ^ 0x8000) : src[i];
      std::memcpy(out.data() + 2 * i, &v, 2);
    }
    return Status::Ok();
  }

 private:
  const SourceVolume& volume_;
  volume::VolumeInfo info_;
};

void ExpectBuildMatchesDirectInserts(volume::DataType dtype, uint64_t slab_budget, int threads,
                                     int64_t slab_planes = 0, uint64_t staging = 64 << 20) {
  const Vec3 size{30, 20, 23};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 9);
  BrickGeometry::Params params;
  params.volume_size = size;
  params.brick_size = {8, 8, 4};
  params.channels = 2;
  params.bytes_per_sample = 2;
  OctreeOptions options;
  options.brick_size = params.brick_size;
  options.homogeneity_threshold = 0.01;

  TreeFixture direct = TreeFixture::Make(params, options);
  ASSERT_TRUE(direct.tree);
  const Box all{{0, 0, 0}, size};
  for (int c = 0; c < 2; ++c) ASSERT_TRUE(direct.tree->Insert(c, all, src.Block(c, all, 2)).ok());

  MemorySource source(src, dtype);
  const std::vector<volume::ValueMap> maps(2, volume::FixedValueMap(dtype));
  TreeFixture built = TreeFixture::Make(params, options);
  ASSERT_TRUE(built.tree);
  BuildOptions build_options;
  build_options.threads = threads;
  build_options.slab_budget_bytes = slab_budget;
  build_options.slab_planes = slab_planes;
  build_options.staging_bytes = staging;
  build_options.scratch_dir = std::filesystem::temp_directory_path();
  uint64_t last_planes = 0;
  build_options.progress = [&](const BuildProgress& p) { last_planes = p.planes_done; };
  Status st = BuildOctree(source, maps, *built.tree, build_options);
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(last_planes, static_cast<uint64_t>(size[2]) * 2);
  ExpectSameTree(DumpTree(*direct.tree), DumpTree(*built.tree), "built");
  EXPECT_EQ(built.tree->stats(), direct.tree->stats());
}

TEST(OctreeBuilderTest, IdentitySlabsAreInsertedAsRead) {
  // 4-plane slabs (one brick deep) with 3 readers: 6 slabs per channel, the last one 3 planes,
  // buffers recycled.
  const uint64_t plane_bytes = 30 * 20 * 2;
  ExpectBuildMatchesDirectInserts(volume::DataType::kUint16, 2 * 3 * 4 * plane_bytes, 3);
}

TEST(OctreeBuilderTest, ConvertedSlabsGiveTheSameTree) {
  // 2-plane slabs: each slab splits the bricks' z range.
  const uint64_t plane_bytes = 30 * 20 * 2;
  ExpectBuildMatchesDirectInserts(volume::DataType::kInt16, 2 * 2 * 2 * plane_bytes, 2);
}

TEST(OctreeBuilderTest, PlaneByPlaneReadsAndScratchStagingGiveTheSameTree) {
  // One plane per read, as a live acquisition delivers them; staging too small for a layer, so
  // every layer goes through a scratch file and is inserted brick row by brick row.
  ExpectBuildMatchesDirectInserts(volume::DataType::kUint16, 1 << 20, 3, 1, 0);
}

// A build stopped by its stop token or by a throwing progress callback returns an error, joins
// its threads and leaves a consistent tree.
TEST(OctreeBuilderTest, CancellationAndThrowingCallbacksEndTheBuildCleanly) {
  const Vec3 size{30, 20, 64};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 9);
  MemorySource source(src, volume::DataType::kUint16);
  const std::vector<volume::ValueMap> maps(2, volume::FixedValueMap(volume::DataType::kUint16));
  OctreeOptions options;
  options.brick_size = {8, 8, 4};
  const auto params = testing::Params(size, options.brick_size, 2, 2);
  {
    TreeFixture f = TreeFixture::Make(params, options);
    std::stop_source stop;
    BuildOptions b;
    b.slab_planes = 1;
    b.stop = stop.get_token();
    stop.request_stop();  // Before anything is read.
    Status st = BuildOctree(source, maps, *f.tree, b);
    EXPECT_EQ(st.code(), StatusCode::kCancelled) << st.ToString();
  }
  {
    // A source that, like a slow disk, cannot deliver planes beyond 10 until the build is stopped
    // (at most 10 s): the build is surely still running when the progress callback stops it.
    class StallingSource : public MemorySource {
     public:
      using MemorySource::MemorySource;
      std::stop_token stop;
      Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
        for (int i = 0; z0 >= 10 && !stop.stop_requested() && i < 10000; ++i) {
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        return MemorySource::ReadSlab(channel, z0, nz, out);
      }
    };
    StallingSource stalling(src, volume::DataType::kUint16);
    TreeFixture f = TreeFixture::Make(params, options);
    std::stop_source stop;
    stalling.stop = stop.get_token();
    BuildOptions b;
    b.slab_planes = 1;
    b.stop = stop.get_token();
    b.progress = [&](const BuildProgress& p) {
      if (p.planes_read > 0) stop.request_stop();
    };
    Status st = BuildOctree(stalling, maps, *f.tree, b);
    EXPECT_EQ(st.code(), StatusCode::kCancelled) << st.ToString();
    EXPECT_FALSE(f.tree->GetNode(f.tree->geometry().RootKey())->complete);
  }
  {
    TreeFixture f = TreeFixture::Make(params, options);
    BuildOptions b;
    b.slab_planes = 1;
    b.progress = [](const BuildProgress&) { throw std::runtime_error("callback failed"); };
    Status st = BuildOctree(source, maps, *f.tree, b);
    EXPECT_EQ(st.code(), StatusCode::kInternal) << st.ToString();
    EXPECT_NE(st.message().find("callback failed"), std::string::npos);
  }
}

// on_slab sees every plane of every channel exactly once, in the stored type, from the reader
// threads; a throwing hook fails the build.
TEST(OctreeBuilderTest, OnSlabSeesEveryStoredPlaneOnce) {
  const Vec3 size{30, 20, 23};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 5);
  MemorySource source(src, volume::DataType::kInt16);  // Converted: the hook sees stored values.
  const std::vector<volume::ValueMap> maps(2, volume::FixedValueMap(volume::DataType::kInt16));
  OctreeOptions options;
  options.brick_size = {8, 8, 4};
  const auto params = testing::Params(size, options.brick_size, 2, 2);
  TreeFixture f = TreeFixture::Make(params, options);
  std::mutex mu;
  std::vector<int> seen(2 * size[2], 0);
  std::vector<std::vector<uint16_t>> stored(2, std::vector<uint16_t>(src.data[0].size()));
  const size_t plane = static_cast<size_t>(size[0] * size[1]);
  BuildOptions b;
  b.threads = 3;
  b.slab_planes = 2;
  b.on_slab = [&](int c, int64_t z0, int64_t nz, std::span<const std::byte> data) {
    std::lock_guard lock(mu);
    ASSERT_EQ(data.size(), static_cast<size_t>(nz) * plane * 2);
    for (int64_t z = z0; z < z0 + nz; ++z) ++seen[c * size[2] + z];
    std::memcpy(stored[c].data() + static_cast<size_t>(z0) * plane, data.data(), data.size());
  };
  Status st = BuildOctree(source, maps, *f.tree, b);
  ASSERT_TRUE(st.ok()) << st.ToString();
  for (int n : seen) EXPECT_EQ(n, 1);
  EXPECT_EQ(stored, src.data);  // int16 file values converted back to the pattern.

  TreeFixture g = TreeFixture::Make(params, options);
  b.on_slab = [](int, int64_t, int64_t, std::span<const std::byte>) {
    throw std::runtime_error("hook failed");
  };
  st = BuildOctree(source, maps, *g.tree, b);
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message().find("hook failed"), std::string::npos) << st.ToString();
}

TEST(OctreeBuilderTest, SlabPlanesPrefersDivisorsOfTheBrickDepth) {
  volume::VolumeInfo info;
  info.size = {100, 100, 200};
  info.channels.resize(2);
  info.dtype = volume::DataType::kUint16;
  const uint64_t plane = 100 * 100 * 2;
  EXPECT_EQ(SlabPlanes(info, 64, 2, 4 * 64 * plane), 64);
  EXPECT_EQ(SlabPlanes(info, 64, 2, 4 * 40 * plane), 32);  // 40 planes fit: largest divisor 32.
  EXPECT_EQ(SlabPlanes(info, 64, 2, 1), 1);                // At least one plane.
}

}  // namespace
}  // namespace octoscope::octree
