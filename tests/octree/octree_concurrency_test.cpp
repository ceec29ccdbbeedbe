// One insert thread per channel plus concurrent readers (the paper's builder threads and render
// thread). Meant to be run under ThreadSanitizer too; the final tree must equal a sequential
// build.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "change_mirror.h"
#include "octree/octree.h"
#include "octree_reference.h"

namespace octoscope::octree {
namespace {

using testing::ChangeMirror;
using testing::DumpTree;
using testing::ExpectMirrors;
using testing::ExpectSameTree;
using testing::MakePatternVolume;
using testing::Params;
using testing::SourceVolume;
using testing::TreeFixture;

TEST(OctreeConcurrencyTest, PerChannelInsertThreadsWithConcurrentReaders) {
  const Vec3 size{24, 20, 16};
  const int channels = 3;
  const SourceVolume src = MakePatternVolume(size, channels, 2, 21);
  BrickGeometry::Params params;
  params.volume_size = size;
  params.brick_size = {4, 4, 4};
  params.channels = channels;
  params.bytes_per_sample = 2;
  OctreeOptions options;
  options.brick_size = params.brick_size;
  options.homogeneity_threshold = 0.02;

  std::vector<Box> slabs;
  for (int64_t z = 0; z < size[2]; ++z) slabs.push_back(Box{{0, 0, z}, {size[0], size[1], z + 1}});

  TreeFixture sequential = TreeFixture::Make(params, options);
  ASSERT_TRUE(sequential.tree);
  for (const Box& b : slabs)
    for (int c = 0; c < channels; ++c)
      ASSERT_TRUE(sequential.tree->Insert(c, b, src.Block(c, b, 2)).ok());

  // A small budget so that readers and writers also contend for pages.
  TreeFixture f = TreeFixture::Make(params, options, 1 << 13, 24 << 13);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;
  std::atomic<int> writers_left{channels};
  std::atomic<bool> failed{false};
  std::vector<std::thread> threads;
  for (int c = 0; c < channels; ++c) {
    threads.emplace_back([&, c] {
      std::vector<Box> order = slabs;
      std::shuffle(order.begin(), order.end(), std::mt19937(100 + c));
      for (const Box& b : order) {
        if (!tree.Insert(c, b, src.Block(c, b, 2)).ok()) failed = true;
      }
      --writers_left;
    });
  }
  std::atomic<uint64_t> bricks_read{0}, nodes_read{0};
  for (int r = 0; r < 2; ++r) {
    threads.emplace_back([&, r] {
      std::mt19937 rng(r);
      std::vector<std::byte> brick(tree.geometry().brick_bytes());
      ChangeSubscription changes = tree.SubscribeChanges();
      // Keep reading while the writers run (and a little after, so the readers surely ran).
      for (int after = 0; writers_left.load() > 0 || after < 300;
           after += writers_left.load() == 0) {
        const uint32_t id = rng() % 600;
        auto node = tree.GetNode(id);
        if (node) {
          ++nodes_read;
          // A snapshot is self-consistent: a virtual node never has a brick or children.
          if (node->is_virtual && (node->has_brick() || node->has_children())) failed = true;
          if (node->has_brick()) {
            Status st = tree.ReadBrick(id, brick);
            // The brick may have been dropped since the snapshot: then kNotFound, never garbage.
            if (st.ok()) {
              ++bricks_read;
            } else if (st.code() != StatusCode::kNotFound) {
              failed = true;
            }
          }
        }
        const NodeKey key{static_cast<int>(rng() % 2), {static_cast<int64_t>(rng() % 6), 0, 0}};
        (void)tree.GetNode(key);
        if (r == 0) {
          (void)changes.Poll();
          (void)tree.stats();
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_FALSE(failed.load());
  EXPECT_GT(nodes_read.load(), 0u);
  ExpectSameTree(DumpTree(*sequential.tree), DumpTree(tree), "concurrent vs sequential");
  EXPECT_EQ(sequential.tree->stats(), tree.stats());
}

// Change subscriptions created and polled on their own threads while another thread inserts
// (and prunes and re-creates): each consumer subscribes and walks the tree mid-construction, and
// its mirror equals the tree once the inserts are done and it has polled once more. One is
// allowed a tiny backlog, so under load it is also told to resynchronise.
TEST(OctreeConcurrencyTest, ChangeSubscriptionsFollowConcurrentInserts) {
  const Vec3 size{24, 20, 16};
  const int channels = 2;
  const SourceVolume src = MakePatternVolume(size, channels, 2, 33);
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  TreeFixture f = TreeFixture::Make(Params(size, options.brick_size, channels, 2), options);
  ASSERT_TRUE(f.tree);
  Octree& tree = *f.tree;

  const std::vector<size_t> backlogs = {kDefaultChangeBacklog, 32};
  std::atomic<size_t> subscribed{0};
  std::atomic<bool> done{false};
  std::atomic<bool> failed{false};
  std::thread inserter([&] {
    while (subscribed.load() < backlogs.size()) std::this_thread::yield();
    const Box all{{0, 0, 0}, size};
    const std::vector<uint16_t> constant(all.VoxelCount(), 900);
    for (int round = 0; round < 4; ++round) {
      for (int64_t z = 0; z < size[2]; ++z) {
        const Box slab{{0, 0, z}, {size[0], size[1], z + 1}};
        for (int c = 0; c < channels; ++c) {
          if (!tree.Insert(c, slab, src.Block(c, slab, 2)).ok()) failed = true;
        }
      }
      if (round == 3) break;
      // Everything constant: the whole tree below the root is deleted, then built again.
      for (int c = 0; c < channels; ++c) {
        if (!tree.Insert(c, all, std::as_bytes(std::span(constant))).ok()) failed = true;
      }
    }
    done = true;
  });
  std::vector<std::unique_ptr<ChangeMirror>> mirrors(backlogs.size());
  std::vector<std::thread> pollers;
  for (size_t i = 0; i < backlogs.size(); ++i) {
    pollers.emplace_back([&, i] {
      ChangeSubscription subscription = tree.SubscribeChanges(backlogs[i]);
      ++subscribed;  // The inserter starts: the mirror's first walk races with it.
      auto mirror = std::make_unique<ChangeMirror>(&tree, std::move(subscription));
      while (!done.load()) {
        mirror->Sync();
        std::this_thread::yield();
      }
      mirror->Sync();  // Everything the inserter appended is in the log now.
      mirrors[i] = std::move(mirror);
    });
  }
  inserter.join();
  for (std::thread& t : pollers) t.join();
  ASSERT_FALSE(failed.load());
  for (size_t i = 0; i < mirrors.size(); ++i) {
    std::printf("[          ] mirror %zu: %llu events, %d resyncs\n", i,
                static_cast<unsigned long long>(mirrors[i]->events()), mirrors[i]->resyncs());
    ExpectMirrors(tree, *mirrors[i], "mirror " + std::to_string(i));
  }
  EXPECT_GT(mirrors[0]->created(), 0u);
  EXPECT_EQ(mirrors[0]->resyncs(), 0);
}

}  // namespace
}  // namespace octoscope::octree
