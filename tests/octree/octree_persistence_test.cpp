// Octree Save/Load, construction under a tiny page budget, and I/O failures during construction.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "octree/octree.h"
#include "octree_reference.h"
#include "paging/fault_injecting_page_store.h"

namespace octoscope::octree {
namespace {

using testing::DumpTree;
using testing::ExpectSameTree;
using testing::InsertBlock;
using testing::MakePatternVolume;
using testing::Params;
using testing::SourceVolume;
using testing::TreeFixture;
using testing::ZSlabs;

TEST(OctreePersistenceTest, SaveLoadRoundTripsAPartialTreeAndBuildingContinues) {
  const Vec3 size{23, 17, 12};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 8);
  OctreeOptions options;
  options.brick_size = {4, 4, 4};
  options.homogeneity_threshold = 0.05;
  options.background = {3, 4};
  const auto params = Params(size, {4, 4, 4}, 2, 2);
  const auto slabs = ZSlabs(size);

  // The reference: everything inserted into one tree.
  TreeFixture full = TreeFixture::Make(params, options);
  ASSERT_TRUE(full.tree);
  for (const Box& b : slabs)
    for (int c = 0; c < 2; ++c) ASSERT_TRUE(InsertBlock(*full.tree, src, c, b).ok());

  // Half the slabs (channel 1 of the last one missing: partial leaves), then save.
  auto store = std::make_unique<paging::MemoryPageStore>(1 << 14);
  std::string saved;
  std::vector<testing::NodeDump> before;
  {
    auto cache = std::make_unique<paging::PageCache>(store.get(), 1 << 20);
    auto tree = Octree::Create(*BrickGeometry::Create(params), options, cache.get());
    ASSERT_TRUE(tree.ok());
    for (size_t i = 0; i < slabs.size() / 2; ++i) {
      ASSERT_TRUE(InsertBlock(**tree, src, 0, slabs[i]).ok());
      if (i + 1 < slabs.size() / 2) {
        ASSERT_TRUE(InsertBlock(**tree, src, 1, slabs[i]).ok());
      }
    }
    // Partial rows too: half of one row of the next slab.
    const Box half_row{{0, 0, static_cast<int64_t>(slabs.size() / 2)},
                       {11, 1, static_cast<int64_t>(slabs.size() / 2) + 1}};
    ASSERT_TRUE(InsertBlock(**tree, src, 0, half_row).ok());
    before = DumpTree(**tree);
    ASSERT_TRUE((*tree)->Flush().ok());
    std::ostringstream out;
    ASSERT_TRUE((*tree)->Save(out).ok());
    saved = out.str();
  }
  // A fresh cache on the same store: bricks come back from the "disk".
  auto cache = std::make_unique<paging::PageCache>(store.get(), 1 << 20);
  std::istringstream in(saved);
  auto loaded = Octree::Load(in, cache.get());
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  Octree& tree = **loaded;
  ExpectSameTree(before, DumpTree(tree), "after load");
  EXPECT_TRUE(tree.SubscribeChanges().Poll().events.empty());  // Loading reports nothing.
  EXPECT_EQ(tree.tolerance(0), 3276u);
  EXPECT_EQ(tree.background(1), 4);
  std::ostringstream again;
  ASSERT_TRUE(tree.Save(again).ok());
  EXPECT_EQ(again.str(), saved);  // Deterministic: equal trees give equal files.

  // Continue: the rest of the volume (re-writing the half row is harmless: same values).
  for (size_t i = slabs.size() / 2 - 1; i < slabs.size(); ++i) {
    for (int c = 0; c < 2; ++c) ASSERT_TRUE(InsertBlock(tree, src, c, slabs[i]).ok());
  }
  ExpectSameTree(DumpTree(*full.tree), DumpTree(tree), "continued after load");
}

TEST(OctreePersistenceTest, LoadRejectsTruncatedAndCorruptTables) {
  const Vec3 size{13, 9, 6};
  const SourceVolume src = MakePatternVolume(size, 1, 1, 2);
  OctreeOptions options;
  options.brick_size = {4, 2, 2};
  TreeFixture f = TreeFixture::Make(Params(size, {4, 2, 2}, 1, 1), options);
  ASSERT_TRUE(f.tree);
  const auto slabs = ZSlabs(size);
  for (size_t i = 0; i < 4; ++i) ASSERT_TRUE(InsertBlock(*f.tree, src, 0, slabs[i]).ok());
  std::ostringstream out;
  ASSERT_TRUE(f.tree->Save(out).ok());
  const std::string bytes = out.str();
  for (size_t n = 0; n < bytes.size(); n += 1 + n / 16) {
    std::istringstream in(bytes.substr(0, n));
    auto loaded = Octree::Load(in, f.cache.get());
    EXPECT_FALSE(loaded.ok()) << "prefix of " << n << " bytes loaded";
  }
  // Random byte flips: must never crash; most are detected.
  std::mt19937 rng(1);
  int rejected = 0;
  for (int i = 0; i < 300; ++i) {
    std::string bad = bytes;
    bad[rng() % bad.size()] ^= static_cast<char>(1 + rng() % 255);
    std::istringstream in(bad);
    if (!Octree::Load(in, f.cache.get()).ok()) ++rejected;
  }
  EXPECT_GT(rejected, 100);
  std::string wrong_version = bytes;
  wrong_version[8] = 9;
  std::istringstream in(wrong_version);
  EXPECT_EQ(Octree::Load(in, f.cache.get()).status().code(), StatusCode::kUnsupported);
}

// A cache budget of a few pages forces bricks to be evicted and reloaded all through the build;
// the result must equal a build with everything in RAM, and the budget must hold.
TEST(OctreePersistenceTest, TinyPageBudgetGivesTheSameTree) {
  const Vec3 size{24, 20, 14};
  const SourceVolume src = MakePatternVolume(size, 2, 2, 4);
  OctreeOptions options;
  options.brick_size = {4, 4, 2};
  const auto params = Params(size, {4, 4, 2}, 2, 2);
  const uint64_t brick_bytes = 6 * 6 * 4 * 2 * 2;
  TreeFixture roomy = TreeFixture::Make(params, options);
  TreeFixture tight = TreeFixture::Make(params, options, 2 * brick_bytes, 6 * 2 * brick_bytes);
  ASSERT_TRUE(roomy.tree && tight.tree);
  for (const Box& b : ZSlabs(size)) {
    for (int c = 0; c < 2; ++c) {
      ASSERT_TRUE(InsertBlock(*roomy.tree, src, c, b).ok());
      ASSERT_TRUE(InsertBlock(*tight.tree, src, c, b).ok());
    }
  }
  ExpectSameTree(DumpTree(*roomy.tree), DumpTree(*tight.tree), "tight budget");
  const auto stats = tight.cache->stats();
  EXPECT_GT(stats.evictions, 100u);
  EXPECT_LE(stats.peak_resident_bytes, tight.cache->budget_bytes());
}

// A failed page read makes Insert fail; re-inserting the same block after the fault is gone
// repairs the tree completely.
TEST(OctreePersistenceTest, FailedInsertCanBeRepeated) {
  const Vec3 size{16, 12, 10};
  const SourceVolume src = MakePatternVolume(size, 1, 2, 6);
  OctreeOptions options;
  options.brick_size = {4, 4, 2};
  const auto params = Params(size, {4, 4, 2}, 1, 2);
  TreeFixture reference = TreeFixture::Make(params, options);
  ASSERT_TRUE(reference.tree);
  for (const Box& b : ZSlabs(size)) ASSERT_TRUE(InsertBlock(*reference.tree, src, 0, b).ok());

  paging::MemoryPageStore inner(2 * 6 * 6 * 4 * 2);
  paging::FaultInjectingPageStore store(&inner);
  // Budget of 4 pages: reads happen all the time.
  paging::PageCache cache(&store, 4 * inner.page_bytes());
  auto tree = Octree::Create(*BrickGeometry::Create(params), options, &cache);
  ASSERT_TRUE(tree.ok());
  int failures = 0;
  for (const Box& b : ZSlabs(size)) {
    store.FailNthRead(7);
    Status st = InsertBlock(**tree, src, 0, b);
    store.FailNthRead(0);
    if (!st.ok()) {
      ++failures;
      EXPECT_EQ(st.code(), StatusCode::kIoError) << st.ToString();
      ASSERT_TRUE(InsertBlock(**tree, src, 0, b).ok());
    }
  }
  EXPECT_GT(failures, 0);
  ExpectSameTree(DumpTree(*reference.tree), DumpTree(**tree), "after repaired failures");
}

}  // namespace
}  // namespace octoscope::octree

namespace octoscope::octree {
namespace {

// TryReadBrick never waits for the disk: with a one-page budget, a brick whose page was evicted
// is kUnavailable (naming its page), and readable once the page is back in RAM.
TEST(OctreeTryReadBrickTest, NeverLoadsAndNamesTheMissingPage) {
  const Vec3 size{16, 8, 8};
  const testing::SourceVolume src = testing::MakePatternVolume(size, 1, 2, 3);
  OctreeOptions options;
  options.brick_size = {8, 8, 8};
  const uint64_t brick_bytes = 10 * 10 * 10 * 2;
  testing::TreeFixture f = testing::TreeFixture::Make(
      testing::Params(size, options.brick_size, 1, 2), options, brick_bytes, 8 * brick_bytes);
  ASSERT_TRUE(f.tree);
  ASSERT_TRUE(testing::InsertBlock(*f.tree, src, 0, Box{{0, 0, 0}, size}).ok());
  ASSERT_TRUE(f.tree->Flush().ok());
  std::vector<uint32_t> with_bricks;
  for (const testing::NodeDump& d : testing::DumpTree(*f.tree)) {
    if (d.has_brick) with_bricks.push_back(f.tree->GetNode(d.key)->id);
  }
  ASSERT_GE(with_bricks.size(), 2u);
  std::vector<std::byte> a(f.tree->geometry().brick_bytes()), b(a.size());
  // Resident now (just written): same bytes as ReadBrick.
  ASSERT_TRUE(f.tree->TryReadBrick(with_bricks[0], a).ok());
  ASSERT_TRUE(f.tree->ReadBrick(with_bricks[0], b).ok());
  EXPECT_EQ(a, b);
  // Shrink the cache to one page and touch another brick: the first one's page is evicted.
  ASSERT_TRUE(f.cache->SetBudget(brick_bytes).ok());
  ASSERT_TRUE(f.tree->ReadBrick(with_bricks[1], b).ok());
  uint64_t page = ~uint64_t{0};
  Status st = f.tree->TryReadBrick(with_bricks[0], a, &page);
  EXPECT_EQ(st.code(), StatusCode::kUnavailable) << st.ToString();
  EXPECT_NE(page, ~uint64_t{0});
  EXPECT_EQ(f.tree->TryReadBrick(0xfffffff0u, a).code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace octoscope::octree
