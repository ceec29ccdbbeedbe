// OctreeCache checkpoints (a live stream's build, resumed across suspensions and restarts): a
// checkpoint reopens as exactly the tree it saved and the build goes on to the same tree as a
// one-shot build; a checkpoint is never served or cleared as a complete cache; and a crash after a
// checkpoint — the pool rewritten in place, brick ids freed and reused since — resumes at exactly
// the checkpoint (the pool's shadow), reported as an unclean stop.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "octree/octree_cache.h"
#include "octree/octree_reference.h"
#include "util/file_reading.h"
#include "volume/value_map.h"

namespace octoscope::octree {
namespace {

namespace fs = std::filesystem;
using testing::DumpTree;
using testing::ExpectSameTree;
using testing::InsertBox;
using testing::NodeDump;
using testing::SourceVolume;

constexpr int64_t kSide = 128;
constexpr int64_t kBrick = 64;  // One brick per page: the pool has several pages.
constexpr uint64_t kRam = uint64_t{64} << 20;

class OctreeCacheCheckpointTest : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() /
            ("octoscope-test-checkpoint-" + std::to_string(::getpid()) + "-" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(root_);
    fs::create_directories(root_);
    dir_ = root_ / "cache";
    params_.info.size = {kSide, kSide, kSide};
    params_.info.channels.resize(1);
    params_.info.dtype = volume::DataType::kUint16;
    params_.brick_size = {kBrick, kBrick, kBrick};
  }
  void TearDown() override { fs::remove_all(root_); }

  static ValueMapping Mapping() {
    return {{volume::FixedValueMap(volume::DataType::kUint16)}, {65535}};
  }
  std::unique_ptr<OctreeCache> Create() {
    auto cache = OctreeCache::CreateResumable(dir_, source_, params_, kRam, Mapping());
    EXPECT_TRUE(cache.ok()) << cache.status().ToString();
    return cache.ok() ? std::move(*cache) : nullptr;
  }
  // z in [z0, z1) of the whole xy extent.
  static Box Slab(int64_t z0, int64_t z1) { return Box{{0, 0, z0}, {kSide, kSide, z1}}; }

  // The tree of `src` inserted in one go.
  static std::vector<NodeDump> Reference(const SourceVolume& src) {
    OctreeOptions options;
    options.brick_size = {kBrick, kBrick, kBrick};
    auto f = testing::TreeFixture::Make(
        testing::Params({kSide, kSide, kSide}, {kBrick, kBrick, kBrick}, 1, 2), options,
        OctreeCache::PageBytesFor(66 * 66 * 66 * 2));
    InsertBox(*f.tree, src, 0, Slab(0, kSide));
    return DumpTree(*f.tree);
  }

  fs::path root_, dir_;
  CacheParams params_;
  SourceIdentity source_{0x5eed, 0};
};

TEST_F(OctreeCacheCheckpointTest, ResumeReopensTheCheckpointAndTheBuildGoesOn) {
  const SourceVolume src = testing::MakePatternVolume({kSide, kSide, kSide}, 1, 2, 3);
  std::vector<NodeDump> saved;
  {
    std::unique_ptr<OctreeCache> cache = Create();
    ASSERT_NE(cache, nullptr);
    EXPECT_EQ(cache->generation(), 0u);
    ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), src, 0, Slab(0, 40)));
    ASSERT_TRUE(cache->Checkpoint({{"notes", "first"}}).ok());
    ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), src, 0, Slab(40, 70)));
    const Status checkpointed = cache->Checkpoint({{"notes", "second"}, {"more", ""}});
    ASSERT_TRUE(checkpointed.ok()) << checkpointed.ToString();
    EXPECT_EQ(cache->generation(), 2u);
    saved = DumpTree(cache->octree());
  }
  // Only the latest generation's files are kept.
  EXPECT_FALSE(fs::exists(dir_ / "checkpoint-1.nodes"));
  EXPECT_TRUE(fs::exists(dir_ / "checkpoint-2.nodes"));
  auto inspected = OctreeCache::Inspect(dir_);
  ASSERT_TRUE(inspected.ok()) << inspected.status().ToString();
  EXPECT_EQ(inspected->manifest.state, CacheManifest::State::kCheckpoint);
  EXPECT_EQ(inspected->manifest.generation, 2u);
  EXPECT_FALSE(inspected->unclean);
  EXPECT_EQ(inspected->attachments, (CheckpointAttachments{{"more", ""}, {"notes", "second"}}));

  auto resumed = OctreeCache::Resume(dir_, kRam);
  ASSERT_TRUE(resumed.ok()) << resumed.status().ToString();
  EXPECT_FALSE(resumed->unclean);
  EXPECT_EQ(resumed->dropped_pages, 0u);
  EXPECT_EQ(resumed->attachments, inspected->attachments);
  OctreeCache& cache = *resumed->cache;
  ExpectSameTree(DumpTree(cache.octree()), saved, "resumed checkpoint");
  // The build goes on (leaf progress included) to the tree a one-shot build makes.
  ASSERT_NO_FATAL_FAILURE(InsertBox(cache.octree(), src, 0, Slab(70, kSide)));
  const std::vector<NodeDump> reference = Reference(src);
  ExpectSameTree(DumpTree(cache.octree()), reference, "resumed build");
  // Completed only from a checkpoint of the last change (until then the pool lacks it).
  EXPECT_EQ(cache.Commit().code(), StatusCode::kFailedPrecondition);
  ASSERT_TRUE(cache.Checkpoint({}).ok());
  ASSERT_TRUE(cache.Commit().ok());
  resumed->cache.reset();
  // Complete now: the checkpoint's files are gone and the cache is served as any other.
  EXPECT_FALSE(fs::exists(dir_ / "checkpoint-2.nodes"));
  EXPECT_FALSE(fs::exists(dir_ / "octree.shadow"));
  EXPECT_EQ(OctreeCache::Resume(dir_, kRam).status().code(), StatusCode::kFailedPrecondition);
  auto served = OctreeCache::Open(dir_, source_, params_, kRam, []() -> Result<ValueMapping> {
    return InternalError("a complete cache needs no mapping");
  });
  ASSERT_TRUE(served.ok()) << served.status().ToString();
  EXPECT_TRUE((*served)->reused());
  ExpectSameTree(DumpTree((*served)->octree()), reference, "committed");
}

TEST_F(OctreeCacheCheckpointTest, ACheckpointIsNeverServedOrClearedAsACompleteCache) {
  const SourceVolume src = testing::MakePatternVolume({kSide, kSide, kSide}, 1, 2, 4);
  {
    std::unique_ptr<OctreeCache> cache = Create();
    ASSERT_NE(cache, nullptr);
    ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), src, 0, Slab(0, 64)));
    ASSERT_TRUE(cache->Checkpoint({}).ok());
    // While its builder holds it, nobody else may resume it.
    EXPECT_EQ(OctreeCache::Resume(dir_, kRam).status().code(), StatusCode::kUnavailable);
  }
  auto manifest = ReadSmallFile(dir_ / "MANIFEST", 1 << 20);
  ASSERT_TRUE(manifest.ok());
  EXPECT_NE(manifest->find("state checkpoint\n"), std::string::npos) << *manifest;
  auto parsed = CacheManifest::Parse(*manifest);
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->state, CacheManifest::State::kCheckpoint);
  // Opening it as a cache (to serve or to rebuild: `octoscope render`, `build`) is refused and
  // changes nothing.
  int derived = 0;
  auto opened = OctreeCache::Open(dir_, source_, params_, kRam, [&]() -> Result<ValueMapping> {
    ++derived;
    return Mapping();
  });
  EXPECT_EQ(opened.status().code(), StatusCode::kFailedPrecondition) << opened.status().ToString();
  EXPECT_EQ(derived, 0);
  EXPECT_EQ(ReadSmallFile(dir_ / "MANIFEST", 1 << 20).value(), *manifest);
  EXPECT_TRUE(fs::exists(dir_ / "checkpoint-1.nodes"));
  // A complete-cache MANIFEST never carries checkpoint keys, nor a checkpoint none.
  std::string complete = *manifest;
  complete.replace(complete.find("state checkpoint"), 16, "state complete");
  EXPECT_EQ(CacheManifest::Parse(complete).status().code(), StatusCode::kCorrupt);
  std::string no_generation = *manifest;
  no_generation.erase(no_generation.find("generation "));
  EXPECT_EQ(CacheManifest::Parse(no_generation).status().code(), StatusCode::kCorrupt);
  // A damaged node table is reported, never guessed around.
  { std::ofstream(dir_ / "checkpoint-1.nodes", std::ios::app) << "x"; }
  auto damaged = OctreeCache::Resume(dir_, kRam);
  EXPECT_EQ(damaged.status().code(), StatusCode::kCorrupt);
  EXPECT_NE(damaged.status().message().find("checkpoint-1.nodes"), std::string::npos);
}

TEST_F(OctreeCacheCheckpointTest, ACrashAfterACheckpointResumesAtExactlyTheCheckpoint) {
  const SourceVolume src = testing::MakePatternVolume({kSide, kSide, kSide}, 1, 2, 5);
  SourceVolume flat({kSide, kSide, kSide}, 1);
  for (uint16_t& v : flat.data[0]) v = 777;
  std::vector<NodeDump> saved;
  const fs::path crashed = root_ / "crashed";
  std::unique_ptr<OctreeCache> cache = Create();
  ASSERT_NE(cache, nullptr);
  ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), src, 0, Slab(0, kBrick)));
  ASSERT_TRUE(cache->Checkpoint({{"planes", "64"}}).ok());
  saved = DumpTree(cache->octree());
  const OctreeStats at_checkpoint = cache->octree().stats();

  // After the checkpoint: the checkpoint's leaf bricks are overwritten with a constant (they
  // drop their bricks: ids freed), the upper half gets bricks (the freed ids are reused), the
  // root's brick is rewritten in place — and all of it reaches the pool file.
  ASSERT_TRUE(cache->MarkDirty().ok());
  ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), flat, 0, Slab(0, kBrick)));
  ASSERT_NO_FATAL_FAILURE(InsertBox(cache->octree(), src, 0, Slab(kBrick, kSide)));
  ASSERT_TRUE(cache->octree().Flush().ok());
  EXPECT_FALSE(DumpTree(cache->octree()) == saved);
  // The process dies here: what is on disk is what it left.
  fs::copy(dir_, crashed, fs::copy_options::recursive);
  cache.reset();

  auto inspected = OctreeCache::Inspect(crashed);
  ASSERT_TRUE(inspected.ok()) << inspected.status().ToString();
  EXPECT_TRUE(inspected->unclean);
  auto resumed = OctreeCache::Resume(crashed, kRam);
  ASSERT_TRUE(resumed.ok()) << resumed.status().ToString();
  EXPECT_TRUE(resumed->unclean);
  EXPECT_GE(resumed->dropped_pages, 2u);  // Leaf pages and the root's page at least.
  EXPECT_EQ(resumed->attachments.at("planes"), "64");
  ExpectSameTree(DumpTree(resumed->cache->octree()), saved, "after the crash");
  EXPECT_EQ(resumed->cache->octree().stats(), at_checkpoint);
  // The build goes on from the checkpoint to the right tree.
  ASSERT_NO_FATAL_FAILURE(InsertBox(resumed->cache->octree(), src, 0, Slab(kBrick, kSide)));
  ExpectSameTree(DumpTree(resumed->cache->octree()), Reference(src), "resumed after the crash");
  // Checkpointed again and closed cleanly: no longer unclean.
  ASSERT_TRUE(resumed->cache->Checkpoint({}).ok());
  resumed->cache.reset();
  auto again = OctreeCache::Resume(crashed, kRam);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_FALSE(again->unclean);
  EXPECT_EQ(again->dropped_pages, 0u);
  ExpectSameTree(DumpTree(again->cache->octree()), Reference(src), "clean resume");
}

}  // namespace
}  // namespace octoscope::octree
