// SlabIngest: slabs of any thickness in any order, staged in RAM or scratch files, give the
// one-shot tree; Flush makes staged planes visible; planes may arrive again; concurrent producers,
// flushers and readers (run under ThreadSanitizer too).
#include "octree/slab_ingest.h"

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <random>
#include <thread>
#include <vector>

#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::BuildReference;
using testing::DumpTree;
using testing::ExpectSameTree;
using testing::MakePatternVolume;
using testing::Params;
using testing::ReferenceStats;
using testing::SourceVolume;
using testing::TreeFixture;

struct Slab {
  int channel;
  int64_t z0, nz;
};

class SlabIngestTest : public ::testing::Test {
 protected:
  void SetUp() override {
    size_ = {21, 13, 19};
    src_ = std::make_unique<SourceVolume>(MakePatternVolume(size_, kChannels, 2, 17));
    options_.brick_size = {4, 4, 4};
    options_.homogeneity_threshold = 0.0;
    reference_ = TreeFixture::Make(Params(size_, options_.brick_size, kChannels, 2), options_);
    for (int c = 0; c < kChannels; ++c) {
      EXPECT_TRUE(testing::InsertBlock(*reference_.tree, *src_, c, Box{{0, 0, 0}, size_}).ok());
    }
    scratch_ =
        std::filesystem::temp_directory_path() / ("octoscope-ingest-" + std::to_string(::getpid()));
    std::filesystem::create_directories(scratch_);
  }
  void TearDown() override { std::filesystem::remove_all(scratch_); }

  TreeFixture NewTree() {
    return TreeFixture::Make(Params(size_, options_.brick_size, kChannels, 2), options_);
  }
  std::vector<std::byte> Planes(int c, int64_t z0, int64_t nz) const {
    return src_->Block(c, Box{{0, 0, z0}, {size_[0], size_[1], z0 + nz}}, 2);
  }
  Status Add(SlabIngest& ingest, const Slab& s) const {
    return ingest.Add(s.channel, s.z0, s.nz, Planes(s.channel, s.z0, s.nz));
  }
  // Slabs of `thickness` planes for every channel, shuffled with `seed`.
  std::vector<Slab> Slabs(int64_t thickness, uint32_t seed) const {
    std::vector<Slab> out;
    for (int c = 0; c < kChannels; ++c)
      for (int64_t z = 0; z < size_[2]; z += thickness)
        out.push_back({c, z, std::min(thickness, size_[2] - z)});
    std::shuffle(out.begin(), out.end(), std::mt19937(seed));
    return out;
  }

  static constexpr int kChannels = 3;
  Vec3 size_;
  std::unique_ptr<SourceVolume> src_;
  OctreeOptions options_;
  TreeFixture reference_;
  std::filesystem::path scratch_;
};

TEST_F(SlabIngestTest, AnyThicknessAndOrderGivesTheOneShotTree) {
  const uint64_t layer_bytes = static_cast<uint64_t>(size_[0] * size_[1]) * 4 * kChannels * 2;
  for (int64_t thickness : {1, 3, 4, 7, 19}) {
    for (uint64_t staging : {uint64_t{1} << 30, layer_bytes, uint64_t{0}}) {
      TreeFixture f = NewTree();
      IngestOptions io;
      io.staging_bytes = staging;
      io.scratch_dir = scratch_;
      WorkerPool pool(2);
      io.workers = thickness == 3 ? &pool : nullptr;
      auto ingest = SlabIngest::Create(f.tree.get(), io);
      ASSERT_TRUE(ingest.ok());
      for (const Slab& s : Slabs(thickness, static_cast<uint32_t>(thickness))) {
        Status st = Add(**ingest, s);
        ASSERT_TRUE(st.ok()) << st.ToString();
      }
      EXPECT_TRUE((*ingest)->complete());
      EXPECT_EQ((*ingest)->pending_planes(), 0u);
      const IngestProgress p = (*ingest)->progress();
      EXPECT_EQ(p.planes_received, p.planes_total);
      EXPECT_EQ(p.planes_inserted, p.planes_total);
      EXPECT_EQ(p.layers_inserted, 5u);  // ceil(19 / 4).
      if (staging == 0) {
        EXPECT_EQ(p.scratch_layers, 5u);
      }
      if (staging > layer_bytes) {
        EXPECT_EQ(p.scratch_layers, 0u);
      }
      ExpectSameTree(
          DumpTree(*reference_.tree), DumpTree(*f.tree),
          "thickness " + std::to_string(thickness) + " staging " + std::to_string(staging));
    }
  }
}

TEST_F(SlabIngestTest, FlushMakesStagedPlanesVisibleAndTheRestStillCompletesTheTree) {
  TreeFixture f = NewTree();
  auto ingest = SlabIngest::Create(f.tree.get(), IngestOptions{});
  ASSERT_TRUE(ingest.ok());
  // Planes 0..5 of channel 0 only (layer 0 complete for channel 0 but not the others, layer 1
  // partial): nothing is inserted until Flush.
  ASSERT_TRUE((*ingest)->Add(0, 0, 6, Planes(0, 0, 6)).ok());
  EXPECT_EQ((*ingest)->pending_planes(), 6u);
  const auto before = f.tree->GetNode(NodeKey{0, {0, 0, 0}});
  EXPECT_FALSE(before.has_value());  // The root has no children yet.
  ASSERT_TRUE((*ingest)->Flush().ok());
  EXPECT_EQ((*ingest)->pending_planes(), 0u);
  EXPECT_EQ((*ingest)->progress().planes_inserted, 6u);
  // The tree now holds exactly those planes: statistics equal the pyramid of what was written.
  std::vector<bool> written(static_cast<size_t>(size_[0] * size_[1] * size_[2]), false);
  std::fill(written.begin(), written.begin() + size_[0] * size_[1] * 6, true);
  const auto ref = BuildReference(*src_, f.tree->geometry().level_count(), {0, 0, 0}, &written);
  for (const testing::NodeDump& d : DumpTree(*f.tree)) {
    if (d.is_virtual) continue;
    const auto r = ReferenceStats(ref, d.key.level, 0, f.tree->geometry().ValidBox(d.key));
    EXPECT_EQ(d.channels[0].min, r.min) << d.key.ToString();
    EXPECT_EQ(d.channels[0].max, r.max) << d.key.ToString();
  }
  // Everything else, in random order; a few planes arrive twice (before and after their layer
  // was inserted).
  for (const Slab& s : Slabs(1, 5)) {
    if (s.channel == 0 && s.z0 < 6) continue;
    ASSERT_TRUE(Add(**ingest, s).ok());
    if (s.z0 % 5 == 0) {
      ASSERT_TRUE(Add(**ingest, s).ok());
    }
  }
  ASSERT_TRUE(Add(**ingest, {1, 2, 3}).ok());  // Layer 0 is done: inserted at once.
  EXPECT_TRUE((*ingest)->complete());
  ExpectSameTree(DumpTree(*reference_.tree), DumpTree(*f.tree), "after flush and the rest");
}

TEST_F(SlabIngestTest, LatestPlaneWinsAndBadArgumentsAreRefused) {
  TreeFixture f = NewTree();
  auto ingest = SlabIngest::Create(f.tree.get(), IngestOptions{});
  ASSERT_TRUE(ingest.ok());
  // A wrong version of plane 2 first, then the right one: the right one is what stays.
  std::vector<std::byte> wrong(Planes(1, 2, 1).size(), std::byte{7});
  ASSERT_TRUE((*ingest)->Add(1, 2, 1, wrong).ok());
  for (const Slab& s : Slabs(2, 1)) ASSERT_TRUE(Add(**ingest, s).ok());
  EXPECT_TRUE((*ingest)->complete());
  ExpectSameTree(DumpTree(*reference_.tree), DumpTree(*f.tree), "latest wins");

  EXPECT_EQ((*ingest)->Add(3, 0, 1, Planes(0, 0, 1)).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ((*ingest)->Add(0, 18, 2, Planes(0, 17, 2)).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*ingest)->Add(0, -1, 1, Planes(0, 0, 1)).code(), StatusCode::kOutOfRange);
  EXPECT_EQ((*ingest)->Add(0, 0, 2, Planes(0, 0, 1)).code(), StatusCode::kInvalidArgument);
}

TEST_F(SlabIngestTest, ALayerBeyondTheStagingBudgetWithoutScratchIsAClearError) {
  TreeFixture f = NewTree();
  IngestOptions io;
  io.staging_bytes = 100;
  auto ingest = SlabIngest::Create(f.tree.get(), io);
  ASSERT_TRUE(ingest.ok());
  Status st = (*ingest)->Add(0, 0, 1, Planes(0, 0, 1));
  EXPECT_EQ(st.code(), StatusCode::kResourceExhausted);
  EXPECT_NE(st.message().find("staging budget"), std::string::npos) << st.ToString();
}

TEST_F(SlabIngestTest, ConcurrentProducersFlushersAndReaders) {
  TreeFixture f = NewTree();
  IngestOptions io;
  io.staging_bytes = static_cast<uint64_t>(size_[0] * size_[1]) * 4 * kChannels * 2 * 2;
  io.scratch_dir = scratch_;
  WorkerPool pool(2);
  io.workers = &pool;
  auto ingest = SlabIngest::Create(f.tree.get(), io);
  ASSERT_TRUE(ingest.ok());
  const std::vector<Slab> slabs = Slabs(1, 99);
  std::atomic<size_t> next{0};
  std::atomic<bool> failed{false}, done{false};
  std::vector<std::thread> threads;
  for (int t = 0; t < 3; ++t) {
    threads.emplace_back([&] {
      for (size_t i; (i = next++) < slabs.size();) {
        if (!Add(**ingest, slabs[i]).ok()) failed = true;
      }
    });
  }
  threads.emplace_back([&] {
    while (!done) {
      if (!(*ingest)->Flush().ok()) failed = true;
      std::this_thread::yield();
    }
  });
  threads.emplace_back([&] {
    std::vector<std::byte> brick(f.tree->geometry().brick_bytes());
    while (!done) {
      for (uint32_t id = 0; id < 200; ++id) {
        auto node = f.tree->GetNode(id);
        if (node && node->has_brick()) {
          Status st = f.tree->ReadBrick(id, brick);
          if (!st.ok() && st.code() != StatusCode::kNotFound) failed = true;
        }
      }
    }
  });
  for (int t = 0; t < 3; ++t) threads[t].join();
  done = true;
  for (size_t t = 3; t < threads.size(); ++t) threads[t].join();
  EXPECT_FALSE(failed.load());
  ASSERT_TRUE((*ingest)->Flush().ok());
  EXPECT_TRUE((*ingest)->complete());
  ExpectSameTree(DumpTree(*reference_.tree), DumpTree(*f.tree), "concurrent");
}

}  // namespace
}  // namespace octoscope::octree

namespace octoscope::octree {
namespace {

// A resumed build: planes the tree holds already count as received and inserted, and a brick
// layer they belong to is inserted as one layer once its other planes arrive.
TEST_F(SlabIngestTest, PlanesInsertedBeforeAResumeCompleteTheirLayers) {
  TreeFixture tree = NewTree();
  std::vector<uint8_t> inserted(static_cast<size_t>(kChannels * size_[2]), 0);
  // Before the "checkpoint": channel 0 of planes 0..5 (layer 0 whole, layer 1 in part), every
  // channel of planes 16..18 (the last layer, z 16..18, complete).
  for (int64_t z = 0; z < 6; ++z) inserted[static_cast<size_t>(z)] = 1;
  for (int c = 0; c < kChannels; ++c) {
    for (int64_t z = 16; z < 19; ++z) inserted[static_cast<size_t>(c * size_[2] + z)] = 1;
  }
  for (const Slab& s : {Slab{0, 0, 6}, Slab{0, 16, 3}, Slab{1, 16, 3}, Slab{2, 16, 3}}) {
    const Box box{{0, 0, s.z0}, {size_[0], size_[1], s.z0 + s.nz}};
    ASSERT_TRUE(testing::InsertBlock(*tree.tree, *src_, s.channel, box).ok());
  }
  IngestOptions options;
  options.inserted = inserted;
  auto ingest = SlabIngest::Create(tree.tree.get(), options);
  ASSERT_TRUE(ingest.ok()) << ingest.status().ToString();
  IngestProgress p = (*ingest)->progress();
  EXPECT_EQ(p.planes_received, 6u + 9u);
  EXPECT_EQ(p.planes_inserted, 6u + 9u);
  EXPECT_EQ(p.layers_inserted, 1u);
  // Channels 1 and 2 of layer 0 complete it: inserted at once, no Flush needed.
  for (int c = 1; c < kChannels; ++c) ASSERT_TRUE(Add(**ingest, {c, 0, 4}).ok());
  p = (*ingest)->progress();
  EXPECT_EQ(p.layers_inserted, 2u);
  EXPECT_EQ(p.planes_inserted, 6u + 9u + 8u);
  EXPECT_EQ((*ingest)->pending_planes(), 0u);
  // The rest, with a plane sent before the resume sent again (it replaces the old one).
  for (int c = 0; c < kChannels; ++c) {
    ASSERT_TRUE(Add(**ingest, {c, c == 0 ? 3 : 4, c == 0 ? 13 : 12}).ok());
  }
  EXPECT_TRUE((*ingest)->complete());
  p = (*ingest)->progress();
  EXPECT_EQ(p.planes_received, uint64_t{kChannels} * 19);
  EXPECT_EQ(p.planes_inserted, uint64_t{kChannels} * 19);
  ExpectSameTree(DumpTree(*tree.tree), DumpTree(*reference_.tree), "resumed ingest");
  options.inserted.pop_back();
  EXPECT_EQ(SlabIngest::Create(tree.tree.get(), options).status().code(),
            StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace octoscope::octree
