// DeviceOctree (server/render/device_octree.h) against independent CPU data: the device node
// buffer is read back and compared with an encoding made here by walking the octree by node KEY
// (Octree::GetNode(NodeKey), octree::EncodeNode); device bricks are read back (directly or
// through a test kernel that goes through OctoBrickAllocation) and compared with
// Octree::ReadBrick, widened to uint16 for uint8 trees. The device is never its own oracle.
#include "render/device_octree.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <set>
#include <span>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "cl_test_env.h"
#include "octree/node_encoding.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "render/cell_ranges.h"
#include "render/cl_handles.h"
#include "render_fixture.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::kTestBuildOptions;
using ::octoscope::render::testing::MakeRenderScene;
using ::octoscope::render::testing::RenderScene;
using ::octoscope::render::testing::SceneSpec;
using ::octoscope::render::testing::SharedClTestEnv;
using octree::NodeKey;
using octree::NodeSnapshot;
using octree::Octree;

constexpr double kNoTimeLimit = std::numeric_limits<double>::infinity();

uint32_t Hash(int64_t x, int64_t y, int64_t z, int c) {
  uint32_t h = static_cast<uint32_t>(x * 73856093 ^ y * 19349663 ^ z * 83492791 ^ c * 2654435761u);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

// Noise everywhere (no brick is ever homogeneous, so no node is ever pruned or deleted), except
// a constant slab at z >= 40 whose nodes are homogeneous.
SceneSpec NoiseSpec(volume::DataType type, int channels) {
  SceneSpec spec;
  spec.size = {48, 40, 48};
  spec.brick = {8, 8, 8};
  spec.channels = channels;
  spec.stored_type = type;
  const uint32_t mask = type == volume::DataType::kUint8 ? 0xffu : 0xffffu;
  spec.value = [mask](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    if (z >= 40) return static_cast<uint16_t>(100 + c);
    return static_cast<uint16_t>(Hash(x, y, z, c) & mask);
  };
  return spec;
}

std::unique_ptr<RenderScene> Scene(const SceneSpec& spec, bool insert = true) {
  auto scene = MakeRenderScene(spec, insert);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return scene.ok() ? std::move(*scene) : nullptr;
}

// An empty scene like MakeRenderScene(spec, false), but whose octree has a non-zero background
// in every channel: then every entry ever written for a node has a non-zero average word, so an
// all-zero entry is one that was never written.
std::unique_ptr<RenderScene> EmptySceneWithBackground(const SceneSpec& spec) {
  auto scene = std::make_unique<RenderScene>();
  scene->spec = spec;
  octree::BrickGeometry::Params params;
  params.volume_size = {spec.size[0], spec.size[1], spec.size[2]};
  params.brick_size = spec.brick;
  params.channels = spec.channels;
  params.bytes_per_sample = spec.stored_type == volume::DataType::kUint8 ? 1 : 2;
  auto geometry = octree::BrickGeometry::Create(params);
  EXPECT_TRUE(geometry.ok());
  if (!geometry.ok()) return nullptr;
  octree::OctreeOptions options;
  options.brick_size = spec.brick;
  options.background.assign(static_cast<size_t>(spec.channels), 7);
  scene->store = std::make_unique<paging::MemoryPageStore>(geometry->brick_bytes() * 8);
  scene->cache = std::make_unique<paging::PageCache>(scene->store.get(), uint64_t{1} << 30);
  auto tree = Octree::Create(*geometry, options, scene->cache.get());
  EXPECT_TRUE(tree.ok()) << tree.status().ToString();
  if (!tree.ok()) return nullptr;
  scene->tree = std::move(*tree);
  const auto& n = spec.size;
  scene->voxels.assign(static_cast<size_t>(spec.channels),
                       std::vector<uint16_t>(static_cast<size_t>(n[0] * n[1] * n[2])));
  for (int c = 0; c < spec.channels; ++c) {
    size_t i = 0;
    for (int64_t z = 0; z < n[2]; ++z)
      for (int64_t y = 0; y < n[1]; ++y)
        for (int64_t x = 0; x < n[0]; ++x) scene->voxels[c][i++] = spec.value(c, x, y, z);
  }
  return scene;
}

const ComputeContext& Cc() { return *SharedClTestEnv().context; }

std::unique_ptr<DeviceOctree> MakeDevice(Octree* tree, const DeviceOctreeOptions& options = {}) {
  auto dev = DeviceOctree::Create(&Cc(), tree, options);
  EXPECT_TRUE(dev.ok()) << dev.status().ToString();
  return dev.ok() ? std::move(*dev) : nullptr;
}

// A mirror of `tree` with exactly 8 brick slots (kMinBrickSlots).
std::unique_ptr<DeviceOctree> MakeEightSlotDevice(Octree* tree) {
  DeviceOctreeOptions options;
  options.brick_buffer_bytes = 8 * tree->geometry().brick_samples() * 2;
  auto dev = MakeDevice(tree, options);
  if (dev != nullptr) {
    EXPECT_EQ(dev->slot_count(), 8u);
  }
  return dev;
}

// Every live node reachable from the root, found by KEY (not by child-group ids).
std::vector<NodeSnapshot> NodesByKey(const Octree& tree) {
  std::vector<NodeSnapshot> out;
  std::vector<NodeKey> keys = {tree.geometry().RootKey()};
  while (!keys.empty()) {
    const NodeKey key = keys.back();
    keys.pop_back();
    std::optional<NodeSnapshot> node = tree.GetNode(key);
    if (!node.has_value()) continue;
    if (node->has_children()) {
      for (int o = 0; o < 8; ++o) keys.push_back(octree::ChildKey(key, o));
    }
    out.push_back(std::move(*node));
  }
  return out;
}

// The node buffer this test expects: every node encoded at its id; in_buffer and slot from
// `dev`'s SlotOf when given, else not resident.
// With `strict` false a node beyond `capacity` (a tree still growing) gives an empty result
// instead of a test failure.
std::vector<uint32_t> ExpectedNodes(const Octree& tree, uint64_t capacity,
                                    const DeviceOctree* dev = nullptr, bool strict = true) {
  const int channels = tree.geometry().channels();
  std::vector<uint32_t> out(capacity * static_cast<uint64_t>(octree::NodeWords(channels)), 0);
  for (const NodeSnapshot& n : NodesByKey(tree)) {
    octree::DeviceNode d;
    d.has_brick = n.has_brick();
    d.child_group = n.child_group;
    if (dev != nullptr && dev->SlotOf(n.id).has_value()) {
      d.in_buffer = true;
      d.brick_slot = *dev->SlotOf(n.id);
    }
    for (const auto& c : n.channels) {
      d.averages.push_back(octree::QuantizeAverage(c.avg, tree.geometry().bytes_per_sample()));
      d.range_min.push_back(c.subtree_min);
      d.range_max.push_back(c.subtree_max);
    }
    const Status written = octree::WriteNode(out, n.id, d);
    if (!strict && !written.ok()) return {};
    EXPECT_TRUE(written.ok()) << "node " << n.id << " capacity " << capacity;
  }
  return out;
}

std::vector<uint32_t> DeviceNodes(const DeviceOctree& dev) {
  const size_t words =
      dev.node_capacity() * static_cast<size_t>(octree::NodeWords(dev.geometry().channels()));
  std::vector<uint32_t> out(words);
  const ClMem buffer = ClMem::Retain(dev.node_buffer());
  EXPECT_TRUE(Cc().ReadBuffer(buffer, 0, words * 4, out.data()).ok());
  return out;
}

// The first differing node id, for messages (-1 when equal).
int64_t FirstDifference(const std::vector<uint32_t>& a, const std::vector<uint32_t>& b,
                        int channels) {
  const size_t words = static_cast<size_t>(octree::NodeWords(channels));
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) {
    if (a[i] != b[i]) return static_cast<int64_t>(i / words);
  }
  return a.size() == b.size() ? -1 : static_cast<int64_t>(std::min(a.size(), b.size()) / words);
}

// Node `id`'s brick as the device must hold it: ReadBrick, widened to uint16 for uint8 trees.
std::vector<uint16_t> HostBrick(const Octree& tree, uint32_t id) {
  const octree::BrickGeometry& g = tree.geometry();
  std::vector<std::byte> raw(g.brick_bytes());
  EXPECT_TRUE(tree.ReadBrick(id, raw).ok()) << id;
  std::vector<uint16_t> out(g.brick_samples());
  if (g.bytes_per_sample() == 1) {
    for (size_t i = 0; i < out.size(); ++i) out[i] = static_cast<uint16_t>(raw[i]);
  } else {
    std::memcpy(out.data(), raw.data(), raw.size());
  }
  return out;
}

// The bytes of `slot` read straight from its allocation.
std::vector<uint16_t> DeviceBrick(const DeviceOctree& dev, uint32_t slot) {
  std::vector<uint16_t> out(dev.geometry().brick_samples());
  const uint32_t spa = dev.slots_per_allocation();
  const ClMem buffer = ClMem::Retain(dev.brick_buffers()[slot / spa]);
  EXPECT_TRUE(Cc().ReadBuffer(buffer, (slot % spa) * dev.device_brick_bytes(),
                              dev.device_brick_bytes(), out.data())
                  .ok());
  return out;
}

// The cell ranges of `slot` read straight from the device.
std::vector<uint32_t> DeviceCells(const DeviceOctree& dev, uint32_t slot) {
  const uint64_t words = dev.cell_range_words();
  std::vector<uint32_t> out(words);
  const ClMem buffer = ClMem::Retain(dev.cell_ranges());
  EXPECT_TRUE(Cc().ReadBuffer(buffer, slot * words * 4, words * 4, out.data()).ok());
  return out;
}

// The cell ranges node `id`'s brick must have (ComputeCellRanges is checked against brute force
// in cell_ranges_test.cpp).
std::vector<uint32_t> HostCells(const Octree& tree, uint32_t id) {
  std::vector<uint32_t> out(CellRangeWords(tree.geometry()));
  ComputeCellRanges(tree.geometry(), HostBrick(tree, id), out);
  return out;
}

std::vector<NodeSnapshot> Bricked(const Octree& tree, int level = -1) {
  std::vector<NodeSnapshot> out;
  for (NodeSnapshot& n : NodesByKey(tree)) {
    if (n.has_brick() && (level < 0 || n.key.level == level)) out.push_back(std::move(n));
  }
  std::sort(out.begin(), out.end(),
            [](const NodeSnapshot& a, const NodeSnapshot& b) { return a.id < b.id; });
  return out;
}

std::vector<uint32_t> Ids(const std::vector<NodeSnapshot>& nodes) {
  std::vector<uint32_t> ids;
  for (const NodeSnapshot& n : nodes) ids.push_back(n.id);
  return ids;
}

// ---------------------------------------------------------------------------------------------

class DeviceOctreeTypedTest : public ::testing::TestWithParam<volume::DataType> {};

INSTANTIATE_TEST_SUITE_P(StoredTypes, DeviceOctreeTypedTest,
                         ::testing::Values(volume::DataType::kUint16, volume::DataType::kUint8),
                         [](const auto& info) {
                           return info.param == volume::DataType::kUint8 ? "Uint8" : "Uint16";
                         });

TEST_P(DeviceOctreeTypedTest, CreateWritesEveryNodeLikeAnIndependentEncoding) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(GetParam(), 3));
  ASSERT_NE(scene, nullptr);
  auto dev = MakeDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  SyncStats stats;
  ASSERT_TRUE(dev->Sync(&stats).ok());
  EXPECT_EQ(stats.changes, 0u);  // Create drained the construction's events.
  const std::vector<uint32_t> device = DeviceNodes(*dev);
  const std::vector<uint32_t> expected = ExpectedNodes(*scene->tree, dev->node_capacity());
  EXPECT_EQ(FirstDifference(device, expected, 3), -1);
  EXPECT_TRUE(std::equal(device.begin(), device.end(), dev->node_mirror().begin(),
                         dev->node_mirror().end()));
  const size_t words = static_cast<size_t>(octree::NodeWords(3));
  for (size_t i = 0; i < device.size(); i += words) {
    ASSERT_FALSE(octree::Word0InBuffer(device[i])) << "node " << i / words;
  }
  EXPECT_EQ(dev->resident_bricks(), 0u);
  EXPECT_EQ(dev->device_brick_bytes(), dev->geometry().brick_samples() * 2);
}

TEST_P(DeviceOctreeTypedTest, UploadsCoarseFirstAndBricksMatchReadBrick) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(GetParam(), 2));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  auto dev = MakeDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  // The independent chain: every bricked leaf plus every bricked ancestor, coarse first.
  const std::vector<NodeSnapshot> all = Bricked(tree);
  const std::vector<uint32_t> leaves = Ids(Bricked(tree, 0));
  ASSERT_GT(leaves.size(), 20u);
  std::vector<std::pair<int, uint32_t>> chain;
  for (const NodeSnapshot& n : all) chain.emplace_back(-n.key.level, n.id);
  std::sort(chain.begin(), chain.end());
  ASSERT_GE(dev->slot_count(), chain.size());

  const uint64_t n = 12;
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.max_bricks = n;
  UploadStats stats;
  ASSERT_TRUE(dev->Upload(leaves, budget, &stats).ok());
  EXPECT_EQ(stats.requested, chain.size());
  EXPECT_EQ(stats.uploaded, n);
  EXPECT_EQ(stats.deferred, chain.size() - n);
  EXPECT_EQ(stats.evicted, 0u);
  EXPECT_EQ(stats.bytes, n * dev->device_brick_bytes());
  for (size_t i = 0; i < chain.size(); ++i) {
    EXPECT_EQ(dev->SlotOf(chain[i].second).has_value(), i < n) << "chain position " << i;
  }

  ASSERT_TRUE(dev->UploadAll(leaves, 0, &stats).ok());
  EXPECT_EQ(stats.uploaded, chain.size() - n);
  EXPECT_EQ(dev->resident_bricks(), chain.size());
  EXPECT_EQ(dev->total_uploaded(), chain.size());
  std::set<uint32_t> slots;
  for (const NodeSnapshot& node : all) {
    const std::optional<uint32_t> slot = dev->SlotOf(node.id);
    ASSERT_TRUE(slot.has_value()) << node.id;
    EXPECT_TRUE(slots.insert(*slot).second) << "slot " << *slot << " used twice";
    ASSERT_EQ(DeviceBrick(*dev, *slot), HostBrick(tree, node.id)) << "node " << node.id;
  }
  // in_buffer and slot words as SlotOf says, everything else as the independent encoding.
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
      -1);
}

TEST(DeviceOctreeTest, IncrementalSyncWritesOnlyChangedEntries) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  auto dev = MakeDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  const size_t node_count = NodesByKey(*scene->tree).size();
  ASSERT_GT(node_count, 200u);
  // Overwrite a 3^3 block inside one leaf: that leaf and its ancestors change.
  const octree::Box box{{9, 9, 9}, {12, 12, 12}};
  std::vector<uint16_t> data(27, 12345);
  ASSERT_TRUE(scene->tree->Insert(0, box, std::as_bytes(std::span(data))).ok());
  SyncStats stats;
  ASSERT_TRUE(dev->Sync(&stats).ok());
  EXPECT_GT(stats.changes, 0u);
  EXPECT_GT(stats.entries_written, 0u);
  EXPECT_LT(stats.entries_written * 10, node_count);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(*scene->tree, dev->node_capacity()), 1), -1);
  // A second Sync has nothing to do.
  ASSERT_TRUE(dev->Sync(&stats).ok());
  EXPECT_EQ(stats.changes, 0u);
  EXPECT_EQ(stats.entries_written, 0u);
}

// With `change_backlog` small, Syncs also resynchronise (walk the tree again) mid-construction.
void SyncDuringConstruction(size_t change_backlog) {
  SceneSpec spec = NoiseSpec(volume::DataType::kUint16, 2);
  auto scene = EmptySceneWithBackground(spec);
  ASSERT_NE(scene, nullptr);
  DeviceOctreeOptions options;
  options.change_backlog = change_backlog;
  auto dev = MakeDevice(scene->tree.get(), options);
  ASSERT_NE(dev, nullptr);
  std::atomic<bool> done{false};
  Status insert_status;
  std::thread inserter([&] {
    for (int64_t z = 0; z < spec.size[2] && insert_status.ok(); ++z) {
      insert_status = scene->InsertPlanes(z, z + 1);
    }
    done.store(true);
  });
  const size_t words = static_cast<size_t>(octree::NodeWords(2));
  int syncs = 0;
  int partial = 0;  // Syncs whose buffer differed from the tree a moment later (mid-insert).
  int resyncs = 0;
  uint64_t checked_groups = 0;
  for (bool last = false; !last;) {
    last = done.load();  // One more Sync after the inserter finished.
    SyncStats stats;
    const Status sync = dev->Sync(&stats);
    ASSERT_TRUE(sync.ok()) << sync.ToString();
    ++syncs;
    resyncs += stats.resynchronised ? 1 : 0;
    // Follow the DEVICE buffer's child groups from the root: every child entry it reaches must
    // be a live node of the tree (nothing is ever deleted in this volume), encoded as that node.
    const std::vector<uint32_t> device = DeviceNodes(*dev);
    if (!last && device != ExpectedNodes(*scene->tree, dev->node_capacity(), nullptr, false)) {
      ++partial;
    }
    std::vector<uint32_t> stack = {0};
    while (!stack.empty()) {
      const uint32_t id = stack.back();
      stack.pop_back();
      const uint32_t group = octree::Word0ChildGroup(device[id * words]);
      if (group == 0) continue;
      ++checked_groups;
      for (uint32_t o = 0; o < 8; ++o) {
        const uint32_t child = group * 8 + o;
        ASSERT_LT(uint64_t{child}, dev->node_capacity());
        const std::optional<NodeSnapshot> node = scene->tree->GetNode(child);
        ASSERT_TRUE(node.has_value()) << "node " << id << " points at dead child " << child;
        const NodeSnapshot parent = *scene->tree->GetNode(id);
        ASSERT_EQ(parent.child_group, group);
        // The child's entry was written (the background makes every written average word
        // non-zero) and claims no children the node does not have.
        ASSERT_NE(device[child * words + 2], 0u)
            << "node " << id << " points at unwritten " << child;
        const uint32_t child_group = octree::Word0ChildGroup(device[child * words]);
        ASSERT_TRUE(child_group == 0 || child_group == node->child_group) << child;
        stack.push_back(child);
      }
    }
  }
  inserter.join();
  ASSERT_TRUE(insert_status.ok()) << insert_status.ToString();
  EXPECT_GT(syncs, 1);
  EXPECT_GT(checked_groups, 0u);
  std::printf(
      "[          ] backlog %zu: %d syncs while inserting, %d saw a partial tree, %d "
      "resynchronised\n",
      change_backlog, syncs, partial, resyncs);
  if (change_backlog >= octree::kDefaultChangeBacklog) {
    EXPECT_EQ(resyncs, 0);
  }
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(*scene->tree, dev->node_capacity()), 2), -1);
}

TEST(DeviceOctreeTest, SyncDuringConstructionNeverPointsAtUnwrittenChildren) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SyncDuringConstruction(octree::kDefaultChangeBacklog);
}

TEST(DeviceOctreeTest, ResyncDuringConstructionNeverPointsAtUnwrittenChildren) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SyncDuringConstruction(8);  // Fewer than one plane inserts: Syncs often walk the tree.
}

// A mirror whose Syncs stopped while the tree changed a lot (everything pruned, then built
// again with other values, reusing ids) is told by its change subscription to resynchronise: Sync
// walks the tree and the node buffer equals an independent encoding again; resident bricks that
// kept their node are refreshed first by the next upload and equal ReadBrick; afterwards Sync is
// incremental again.
TEST(DeviceOctreeTest, AMirrorThatFellBehindResynchronisesFromTheTree) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec(volume::DataType::kUint16, 2);
  spec.size = {32, 32, 32};
  auto scene = Scene(spec);
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  DeviceOctreeOptions options;
  options.change_backlog = 16;
  auto dev = MakeDevice(&tree, options);
  ASSERT_NE(dev, nullptr);
  ASSERT_TRUE(dev->UploadAll(Ids(Bricked(tree)), 0).ok());
  ASSERT_GT(dev->resident_bricks(), 16u);

  const octree::Box all{{0, 0, 0}, {32, 32, 32}};
  std::vector<uint16_t> constant(all.VoxelCount(), 500);
  for (int c = 0; c < 2; ++c) {
    ASSERT_TRUE(tree.Insert(c, all, std::as_bytes(std::span(constant))).ok());
  }
  ASSERT_FALSE(tree.GetNode(0)->has_children());
  for (auto& channel : scene->voxels) {
    for (auto& v : channel) v = static_cast<uint16_t>(v ^ 0x3c3cu);
  }
  ASSERT_TRUE(scene->InsertPlanes(0, 32).ok());

  SyncStats sync;
  ASSERT_TRUE(dev->Sync(&sync).ok());
  EXPECT_TRUE(sync.resynchronised);
  EXPECT_EQ(sync.changes, 0u);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
      -1);
  // Bricks still resident belong to a node with the same key that owns a brick: stale until the
  // next upload refreshes them; those that lost theirs were freed.
  EXPECT_EQ(sync.stale_bricks, dev->resident_bricks());
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  UploadStats up;
  ASSERT_TRUE(dev->Upload({}, budget, &up).ok());
  EXPECT_EQ(up.reuploaded, sync.stale_bricks);
  ASSERT_TRUE(dev->UploadAll(Ids(Bricked(tree)), 0).ok());
  for (const NodeSnapshot& node : Bricked(tree)) {
    ASSERT_TRUE(dev->SlotOf(node.id).has_value()) << node.id;
    ASSERT_EQ(DeviceBrick(*dev, *dev->SlotOf(node.id)), HostBrick(tree, node.id)) << node.id;
  }
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
      -1);

  // A small change fits the backlog: incremental again.
  const octree::Box box{{9, 9, 9}, {11, 11, 10}};
  std::vector<uint16_t> data(box.VoxelCount(), 4242);
  ASSERT_TRUE(tree.Insert(0, box, std::as_bytes(std::span(data))).ok());
  ASSERT_TRUE(dev->Sync(&sync).ok());
  EXPECT_FALSE(sync.resynchronised);
  EXPECT_GT(sync.changes, 0u);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
      -1);
}

// Two mirrors of one tree (two devices, or a renderer and a slicer) each get every change, at
// their own pace.
TEST(DeviceOctreeTest, TwoMirrorsOfOneTreeEachGetEveryChange) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec(volume::DataType::kUint16, 1);
  auto scene = EmptySceneWithBackground(spec);
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  auto often = MakeDevice(&tree);
  auto rarely = MakeDevice(&tree);
  ASSERT_NE(often, nullptr);
  ASSERT_NE(rarely, nullptr);
  for (int64_t z = 0; z < spec.size[2]; z += 8) {
    ASSERT_TRUE(scene->InsertPlanes(z, z + 8).ok());
    SyncStats stats;
    ASSERT_TRUE(often->Sync(&stats).ok());
    EXPECT_GT(stats.changes, 0u);
    EXPECT_EQ(FirstDifference(DeviceNodes(*often), ExpectedNodes(tree, often->node_capacity()), 1),
              -1)
        << "planes " << z;
    if (z % 16 == 8) {
      ASSERT_TRUE(rarely->Sync(&stats).ok());
      EXPECT_GT(stats.changes, 0u);
      EXPECT_FALSE(stats.resynchronised);
      EXPECT_EQ(
          FirstDifference(DeviceNodes(*rarely), ExpectedNodes(tree, rarely->node_capacity()), 1),
          -1)
          << "planes " << z;
    }
  }
  // A mirror created now starts from the tree as it is and then follows the changes too.
  auto late = MakeDevice(&tree);
  ASSERT_NE(late, nullptr);
  const octree::Box box{{3, 3, 3}, {6, 6, 6}};
  std::vector<uint16_t> data(box.VoxelCount(), 60000);
  ASSERT_TRUE(tree.Insert(0, box, std::as_bytes(std::span(data))).ok());
  for (DeviceOctree* dev : {often.get(), rarely.get(), late.get()}) {
    ASSERT_TRUE(dev->Sync().ok());
    EXPECT_EQ(FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity()), 1), -1);
  }
}

// Both transfer paths (mapped slots; pinned staging ring + non-blocking writes), both stored
// types: a split buffer of 10 slots, a staging ring of 3 bricks (it wraps), uploads of 7 bricks
// at a time that evict: after every Upload each resident slot holds exactly ReadBrick's bytes.
class DeviceOctreeUploadPathTest
    : public ::testing::TestWithParam<std::tuple<UploadPath, volume::DataType>> {};

INSTANTIATE_TEST_SUITE_P(
    Paths, DeviceOctreeUploadPathTest,
    ::testing::Combine(::testing::Values(UploadPath::kMapped, UploadPath::kStaged),
                       ::testing::Values(volume::DataType::kUint16, volume::DataType::kUint8)),
    [](const auto& info) {
      return std::string(std::get<0>(info.param) == UploadPath::kMapped ? "Mapped" : "Staged") +
             (std::get<1>(info.param) == volume::DataType::kUint8 ? "Uint8" : "Uint16");
    });

TEST_P(DeviceOctreeUploadPathTest, EveryResidentSlotHoldsItsBrick) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const auto [path, type] = GetParam();
  auto scene = Scene(NoiseSpec(type, 2));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  const uint64_t brick = tree.geometry().brick_samples() * 2;
  DeviceOctreeOptions options;
  options.upload_path = path;
  options.staging_bytes = 3 * brick;
  options.max_allocation_bytes = 3 * brick + brick / 2;
  options.brick_buffer_bytes = 10 * brick;
  auto dev = MakeDevice(scene->tree.get(), options);
  ASSERT_NE(dev, nullptr);
  EXPECT_EQ(dev->upload_path(), path);
  ASSERT_EQ(dev->allocation_count(), 4);
  const std::vector<uint32_t> leaves = Ids(Bricked(tree, 0));
  ASSERT_GT(leaves.size(), 30u);
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.max_bricks = 7;
  budget.protect_frame = 1;  // No frame ran: every slot's stamp is 0, so all are evictable.
  uint64_t evicted = 0;
  for (size_t first = 0; first < leaves.size(); first += 5) {
    const std::span<const uint32_t> some =
        std::span(leaves).subspan(first, std::min<size_t>(5, leaves.size() - first));
    UploadStats stats;
    ASSERT_TRUE(dev->Upload(some, budget, &stats).ok());
    EXPECT_GT(stats.uploaded, 0u);
    evicted += stats.evicted;
    for (const NodeSnapshot& node : Bricked(tree)) {
      const std::optional<uint32_t> slot = dev->SlotOf(node.id);
      if (!slot.has_value()) continue;
      ASSERT_EQ(DeviceBrick(*dev, *slot), HostBrick(tree, node.id))
          << "node " << node.id << " slot " << *slot << " after leaves from " << first;
      ASSERT_EQ(DeviceCells(*dev, *slot), HostCells(tree, node.id))
          << "node " << node.id << " slot " << *slot << " after leaves from " << first;
    }
  }
  EXPECT_GT(evicted, 0u);
  EXPECT_EQ(dev->resident_bricks(), 10u);
}

// A full buffer and bricks whose pages are not in RAM: the reads fail before the victims'
// slots (the reads' destinations on the mapped path) are touched, nothing is evicted and every
// resident slot still holds its own brick.
TEST_P(DeviceOctreeUploadPathTest, FailedReadsEvictNothingAndLeaveVictimsIntact) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const auto [path, type] = GetParam();
  SceneSpec spec = NoiseSpec(type, 1);
  spec.page_bytes = 4 * 10 * 10 * 10 * (type == volume::DataType::kUint8 ? 1 : 2);
  auto scene = Scene(spec);
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  DeviceOctreeOptions options;
  options.upload_path = path;
  options.brick_reads = BrickReads::kResidentOnly;
  options.brick_buffer_bytes = 8 * tree.geometry().brick_samples() * 2;
  auto dev = MakeDevice(&tree, options);
  ASSERT_NE(dev, nullptr);
  ASSERT_EQ(dev->slot_count(), 8u);
  const int root = tree.geometry().root_level();
  const std::vector<uint32_t> coarse = Ids(Bricked(tree, root - 1));
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.protect_frame = 1;  // Every stamp is 0: all slots are evictable.
  UploadStats stats;
  ASSERT_TRUE(dev->Upload(coarse, budget, &stats).ok());
  ASSERT_EQ(dev->resident_bricks(), 8u);
  std::map<uint32_t, std::vector<uint16_t>> before;
  for (const NodeSnapshot& n : Bricked(tree)) {
    if (const auto slot = dev->SlotOf(n.id)) before[n.id] = HostBrick(tree, n.id);
  }
  // Every page dropped from RAM, then leaves requested.
  ASSERT_TRUE(tree.Flush().ok());
  ASSERT_TRUE(scene->cache->SetBudget(0).ok());
  ASSERT_TRUE(scene->cache->SetBudget(uint64_t{1} << 30).ok());
  ASSERT_TRUE(dev->Upload(Ids(Bricked(tree, 0)), budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, 0u);
  EXPECT_EQ(stats.evicted, 0u);
  EXPECT_GT(stats.unavailable, 0u);
  EXPECT_EQ(dev->resident_bricks(), 8u);
  for (const auto& [id, bytes] : before) {
    const std::optional<uint32_t> slot = dev->SlotOf(id);
    ASSERT_TRUE(slot.has_value()) << id;
    EXPECT_EQ(DeviceBrick(*dev, *slot), bytes) << "node " << id;
  }
}

// A device whose brick transfers or cell-range write fail (DeviceOctreeOptions::transfer_fault):
// the failing Upload reports the error and leaves none of its bricks resident (the entries say
// so), the bricks resident before stay resident and intact, and the next Upload brings all.
TEST_P(DeviceOctreeUploadPathTest, AFailedTransferLeavesNoneOfItsBricksResident) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const auto [path, type] = GetParam();
  auto scene = Scene(NoiseSpec(type, 2));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  for (const char* failing : {"bricks", "cells"}) {
    SCOPED_TRACE(failing);
    std::string fail_now;
    DeviceOctreeOptions options;
    options.upload_path = path;
    options.staging_bytes = 3 * tree.geometry().brick_samples() * 2;  // The ring wraps.
    options.transfer_fault = [&fail_now](std::string_view transfer) {
      return transfer == fail_now ? InternalError("injected: " + fail_now) : Status::Ok();
    };
    auto dev = MakeDevice(scene->tree.get(), options);
    ASSERT_NE(dev, nullptr);
    const int root = tree.geometry().root_level();
    const std::vector<uint32_t> coarse = Ids(Bricked(tree, root - 1));
    const std::vector<uint32_t> leaves = Ids(Bricked(tree, 0));
    UploadBudget budget;
    budget.max_ms = kNoTimeLimit;
    ASSERT_TRUE(dev->Upload(coarse, budget).ok());
    const uint64_t before = dev->resident_bricks();
    ASSERT_GT(before, 0u);
    fail_now = failing;
    UploadStats stats;
    const Status failed = dev->Upload(std::span(leaves).first(10), budget, &stats);
    EXPECT_EQ(failed.code(), StatusCode::kInternal);
    EXPECT_NE(failed.message().find("injected"), std::string::npos) << failed.ToString();
    EXPECT_EQ(stats.uploaded, 0u);
    EXPECT_EQ(dev->resident_bricks(), before);
    for (uint32_t id : std::span(leaves).first(10)) EXPECT_FALSE(dev->SlotOf(id).has_value());
    EXPECT_EQ(
        FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
        -1);
    fail_now.clear();
    ASSERT_TRUE(dev->Upload(std::span(leaves).first(10), budget, &stats).ok());
    EXPECT_GE(stats.uploaded, 10u);  // And the ancestors they need.
    for (uint32_t id : std::span(leaves).first(10)) EXPECT_TRUE(dev->SlotOf(id).has_value());
    for (const NodeSnapshot& node : Bricked(tree)) {
      const std::optional<uint32_t> slot = dev->SlotOf(node.id);
      if (!slot.has_value()) continue;
      ASSERT_EQ(DeviceBrick(*dev, *slot), HostBrick(tree, node.id)) << "node " << node.id;
      ASSERT_EQ(DeviceCells(*dev, *slot), HostCells(tree, node.id)) << "node " << node.id;
    }
  }
}

TEST(DeviceOctreeTest, SplitBrickBufferHoldsEveryBrickInItsAllocation) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint8, 2));
  ASSERT_NE(scene, nullptr);
  const uint64_t brick = scene->tree->geometry().brick_samples() * 2;
  DeviceOctreeOptions options;
  options.max_allocation_bytes = 3 * brick + brick / 2;  // 3 whole slots per allocation.
  options.brick_buffer_bytes = 10 * brick;
  auto dev = MakeDevice(scene->tree.get(), options);
  ASSERT_NE(dev, nullptr);
  EXPECT_EQ(dev->slot_count(), 10u);
  EXPECT_EQ(dev->slots_per_allocation(), 3u);
  EXPECT_EQ(dev->allocation_count(), 4);
  const auto buffers = dev->brick_buffers();
  EXPECT_EQ(std::set<cl_mem>(buffers.begin(), buffers.end()).size(), 4u);

  // Ten bricked nodes (level 1 and up: few enough ancestors) fill all slots.
  std::vector<uint32_t> ids = Ids(Bricked(*scene->tree));
  ASSERT_TRUE(dev->UploadAll(ids, 0).ok());
  ASSERT_EQ(dev->resident_bricks(), 10u);

  const testing::ClTestEnv& env = SharedClTestEnv();
  auto kernel = env.programs->CreateKernel("device_octree_test.cl", "CopyBrick", kTestBuildOptions);
  ASSERT_TRUE(kernel.ok()) << kernel.status().ToString();
  const cl_ulong samples = scene->tree->geometry().brick_samples();
  auto out = Cc().CreateBuffer(CL_MEM_WRITE_ONLY, samples * 2);
  ASSERT_TRUE(out.ok());
  std::set<uint32_t> slots;
  for (uint32_t id : ids) {
    const std::optional<uint32_t> slot = dev->SlotOf(id);
    if (!slot.has_value()) continue;
    slots.insert(*slot);
    ASSERT_TRUE(SetKernelArgs(kernel->get(), buffers[0], buffers[1], buffers[2], buffers[3],
                              static_cast<cl_uint>(dev->slots_per_allocation()),
                              static_cast<cl_uint>(*slot), samples, *out)
                    .ok());
    ASSERT_TRUE(Cc().EnqueueKernel1D(kernel->get(), samples).ok());
    std::vector<uint16_t> copied(samples);
    ASSERT_TRUE(Cc().ReadBuffer(*out, 0, samples * 2, copied.data()).ok());
    ASSERT_EQ(copied, HostBrick(*scene->tree, id)) << "node " << id << " slot " << *slot;
  }
  EXPECT_EQ(slots.size(), 10u);
}

// Stamps slots through the test kernel, as a render pass would.
void MarkSlots(const DeviceOctree& dev, const std::vector<uint32_t>& slots, uint32_t frame) {
  const testing::ClTestEnv& env = SharedClTestEnv();
  auto kernel = env.programs->CreateKernel("device_octree_test.cl", "MarkSlots", kTestBuildOptions);
  ASSERT_TRUE(kernel.ok()) << kernel.status().ToString();
  auto list = Cc().CreateBuffer(CL_MEM_READ_ONLY, slots.size() * 4, slots.data());
  ASSERT_TRUE(list.ok());
  ASSERT_TRUE(SetKernelArgs(kernel->get(), *list, static_cast<cl_uint>(slots.size()),
                            dev.slot_used(), frame)
                  .ok());
  ASSERT_TRUE(Cc().EnqueueKernel1D(kernel->get(), slots.size()).ok());
  ASSERT_TRUE(Cc().Finish().ok());
}

TEST(DeviceOctreeTest, EvictsLeastRecentlyUsedAndNeverProtectedOrFreshSlots) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  auto dev = MakeEightSlotDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  const int root = tree.geometry().root_level();
  // A: the root and 7 of its children (a closed chain: no ancestors to add).
  std::vector<uint32_t> a = {0};
  const std::vector<NodeSnapshot> level2 = Bricked(tree, root - 1);
  ASSERT_EQ(level2.size(), 8u);
  for (int i = 0; i < 7; ++i) a.push_back(level2[i].id);
  UploadStats stats;
  ASSERT_TRUE(dev->UploadAll(a, 0, &stats).ok());
  ASSERT_EQ(stats.uploaded, 8u);
  // Stamps: a[1..3] used in frame 1, a[4..5] in frame 2, a[6] in frame 3; a[0], a[7] never.
  auto slots_of = [&](size_t lo, size_t hi) {
    std::vector<uint32_t> s;
    for (size_t i = lo; i < hi; ++i) s.push_back(*dev->SlotOf(a[i]));
    return s;
  };
  const uint32_t f1 = *dev->BeginFrame();
  MarkSlots(*dev, slots_of(1, 4), f1);
  const uint32_t f2 = *dev->BeginFrame();
  MarkSlots(*dev, slots_of(4, 6), f2);
  const uint32_t f3 = *dev->BeginFrame();
  MarkSlots(*dev, slots_of(6, 7), f3);
  ASSERT_TRUE(dev->ReadFeedback().ok());
  EXPECT_EQ(dev->slot_stamps()[*dev->SlotOf(a[4])], f2);

  // B: three bricked children of the protected a[4..6] (resident parents: no chain to add).
  std::vector<uint32_t> b;
  for (size_t i = 4; i < 7; ++i) {
    const NodeSnapshot parent = *tree.GetNode(a[i]);
    for (uint32_t o = 0; o < 8 && b.size() < 3; ++o) {
      const auto child = tree.GetNode(parent.child_group * 8 + o);
      if (child.has_value() && child->has_brick()) b.push_back(child->id);
    }
  }
  ASSERT_EQ(b.size(), 3u);
  // Slots stamped >= f2 are protected. Victims, oldest first: a[7] (stamp 0, level 2), the root
  // a[0] (stamp 0, coarser: evicted after a[7]), then the lowest slot of a[1..3] (stamp f1).
  uint32_t lru_f1 = a[1];
  for (size_t i = 2; i < 4; ++i) {
    if (*dev->SlotOf(a[i]) < *dev->SlotOf(lru_f1)) lru_f1 = a[i];
  }
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.protect_frame = f2;
  ASSERT_TRUE(dev->Upload(b, budget, &stats).ok());
  EXPECT_EQ(stats.requested, 3u);
  EXPECT_EQ(stats.uploaded, 3u);
  EXPECT_EQ(stats.evicted, 3u);
  EXPECT_FALSE(dev->SlotOf(a[7]).has_value());
  EXPECT_FALSE(dev->SlotOf(a[0]).has_value());
  EXPECT_FALSE(dev->SlotOf(lru_f1).has_value());
  for (size_t i = 1; i < 7; ++i) {
    if (a[i] != lru_f1) {
      EXPECT_TRUE(dev->SlotOf(a[i]).has_value()) << i;
    }
  }
  for (uint32_t id : b) EXPECT_TRUE(dev->SlotOf(id).has_value()) << id;

  // Everything is evictable now, but not what this very call uploads: more new requests than
  // slots fill the 8 slots once and defer the rest.
  std::vector<uint32_t> previous;
  for (uint32_t id : a) {
    if (dev->SlotOf(id).has_value()) previous.push_back(id);
  }
  previous.insert(previous.end(), b.begin(), b.end());
  std::vector<uint32_t> c;
  for (const NodeSnapshot& n : Bricked(tree, root - 2)) {
    if (std::find(b.begin(), b.end(), n.id) == b.end()) c.push_back(n.id);
  }
  ASSERT_GE(c.size(), 9u);
  budget.protect_frame = std::numeric_limits<uint32_t>::max();
  ASSERT_TRUE(dev->Upload(c, budget, &stats).ok());
  EXPECT_GE(stats.requested, c.size());
  EXPECT_EQ(stats.uploaded, 8u);
  EXPECT_EQ(stats.evicted, 8u);
  EXPECT_EQ(stats.deferred, stats.requested - 8);
  EXPECT_EQ(dev->resident_bricks(), 8u);
  for (uint32_t id : previous) EXPECT_FALSE(dev->SlotOf(id).has_value()) << id;
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 1),
      -1);
}

TEST(DeviceOctreeTest, StaleResidentBricksAreReuploadedFirst) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 2));
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  auto dev = MakeDevice(&tree);
  ASSERT_NE(dev, nullptr);
  const std::vector<uint32_t> ids = Ids(Bricked(tree));
  ASSERT_TRUE(dev->UploadAll(ids, 0).ok());
  std::map<uint32_t, std::vector<uint16_t>> before;
  for (uint32_t id : ids) before[id] = DeviceBrick(*dev, *dev->SlotOf(id));

  // Re-insert a block of different values in channel 1 inside one leaf.
  const octree::Box box{{17, 17, 17}, {21, 21, 21}};
  std::vector<uint16_t> data(64, 777);
  ASSERT_TRUE(tree.Insert(1, box, std::as_bytes(std::span(data))).ok());
  SyncStats sync;
  ASSERT_TRUE(dev->Sync(&sync).ok());
  EXPECT_GE(sync.stale_bricks, 1u);
  // Until the re-upload the old bytes stay visible, still resident.
  uint64_t changed = 0;
  for (uint32_t id : ids) {
    ASSERT_TRUE(dev->SlotOf(id).has_value());
    EXPECT_EQ(DeviceBrick(*dev, *dev->SlotOf(id)), before[id]);
    if (HostBrick(tree, id) != before[id]) ++changed;
  }
  EXPECT_GE(changed, 1u);
  EXPECT_GE(sync.stale_bricks, changed);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
      -1);

  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  UploadStats stats;
  ASSERT_TRUE(dev->Upload({}, budget, &stats).ok());
  EXPECT_EQ(stats.reuploaded, sync.stale_bricks);
  EXPECT_EQ(stats.uploaded, stats.reuploaded);
  EXPECT_EQ(stats.evicted, 0u);
  for (uint32_t id : ids) {
    ASSERT_TRUE(dev->SlotOf(id).has_value());
    EXPECT_EQ(DeviceBrick(*dev, *dev->SlotOf(id)), HostBrick(tree, id)) << id;
    EXPECT_EQ(DeviceCells(*dev, *dev->SlotOf(id)), HostCells(tree, id)) << id;
  }
  // Nothing is stale any more.
  ASSERT_TRUE(dev->Upload({}, budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, 0u);
}

TEST(DeviceOctreeTest, PruningFreesSlotsAndReusedIdsGetTheirOwnBricks) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec(volume::DataType::kUint16, 1);
  spec.size = {32, 32, 32};
  auto scene = Scene(spec);
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  auto dev = MakeDevice(&tree);
  ASSERT_NE(dev, nullptr);
  const std::vector<uint32_t> before = Ids(Bricked(tree));
  ASSERT_TRUE(dev->UploadAll(before, 0).ok());
  ASSERT_EQ(dev->resident_bricks(), before.size());

  // A constant volume: every node becomes homogeneous, the root drops all its descendants.
  const octree::Box all{{0, 0, 0}, {32, 32, 32}};
  std::vector<uint16_t> constant(all.VoxelCount(), 500);
  ASSERT_TRUE(tree.Insert(0, all, std::as_bytes(std::span(constant))).ok());
  ASSERT_FALSE(tree.GetNode(0)->has_children());
  SyncStats sync;
  ASSERT_TRUE(dev->Sync(&sync).ok());
  EXPECT_EQ(dev->resident_bricks(), 0u);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 1),
      -1);

  // Noise again (other values): the groups, and so the ids, are created anew.
  for (auto& v : scene->voxels[0]) v = static_cast<uint16_t>(v ^ 0x5555u);
  ASSERT_TRUE(scene->InsertPlanes(0, 32).ok());
  ASSERT_TRUE(dev->Sync(&sync).ok());
  const std::vector<uint32_t> after = Ids(Bricked(tree));
  ASSERT_TRUE(dev->UploadAll(after, 0).ok());
  EXPECT_EQ(dev->resident_bricks(), after.size());
  for (uint32_t id : after) {
    ASSERT_TRUE(dev->SlotOf(id).has_value()) << id;
    ASSERT_EQ(DeviceBrick(*dev, *dev->SlotOf(id)), HostBrick(tree, id)) << id;
  }
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 1),
      -1);
}

// Runs RequestNodes over `ids` in frame `frame`.
void RequestNodes(const DeviceOctree& dev, const std::vector<uint32_t>& ids, uint32_t frame) {
  const testing::ClTestEnv& env = SharedClTestEnv();
  auto kernel =
      env.programs->CreateKernel("device_octree_test.cl", "RequestNodes", kTestBuildOptions);
  ASSERT_TRUE(kernel.ok()) << kernel.status().ToString();
  auto list = Cc().CreateBuffer(CL_MEM_READ_ONLY, ids.size() * 4, ids.data());
  ASSERT_TRUE(list.ok());
  ASSERT_TRUE(SetKernelArgs(kernel->get(), *list, static_cast<cl_uint>(ids.size()),
                            dev.request_flags(), dev.request_list(),
                            static_cast<cl_uint>(dev.request_capacity()), frame)
                  .ok());
  ASSERT_TRUE(Cc().EnqueueKernel1D(kernel->get(), ids.size()).ok());
  ASSERT_TRUE(Cc().Finish().ok());
}

TEST(DeviceOctreeTest, FeedbackReturnsEachRequestOnceAndDropsOverflow) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  const std::vector<uint32_t> distinct = {0, 9, 17, 33, 40, 63};
  std::vector<uint32_t> ids;
  for (int i = 0; i < 2000; ++i) ids.push_back(distinct[(i * 7) % distinct.size()]);

  auto dev = MakeDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  for (int round = 0; round < 2; ++round) {  // The next frame asks again.
    const uint32_t frame = *dev->BeginFrame();
    EXPECT_EQ(frame, static_cast<uint32_t>(round + 1));
    RequestNodes(*dev, ids, frame);
    auto got = dev->ReadFeedback();
    ASSERT_TRUE(got.ok()) << got.status().ToString();
    std::vector<uint32_t> sorted = *got;
    std::sort(sorted.begin(), sorted.end());
    EXPECT_EQ(sorted, distinct) << "round " << round;
  }

  // A capacity of 3: three distinct requested ids come back, the rest is dropped.
  DeviceOctreeOptions small;
  small.request_capacity = 3;
  auto tight = MakeDevice(scene->tree.get(), small);
  ASSERT_NE(tight, nullptr);
  const uint32_t frame = *tight->BeginFrame();
  RequestNodes(*tight, ids, frame);
  // Slot stamps: slots 0, 2 and 5 used by this frame.
  MarkSlots(*tight, {0, 2, 5, 2, 0}, frame);
  auto got = tight->ReadFeedback();
  ASSERT_TRUE(got.ok());
  ASSERT_EQ(got->size(), 3u);
  std::set<uint32_t> unique(got->begin(), got->end());
  EXPECT_EQ(unique.size(), 3u);
  for (uint32_t id : unique) {
    EXPECT_TRUE(std::binary_search(distinct.begin(), distinct.end(), id)) << id;
  }
  const std::span<const uint32_t> stamps = tight->slot_stamps();
  for (uint32_t s = 0; s < tight->slot_count(); ++s) {
    EXPECT_EQ(stamps[s], (s == 0 || s == 2 || s == 5) ? frame : 0u) << "slot " << s;
  }
  // A new frame clears the list.
  ASSERT_TRUE(tight->BeginFrame().ok());
  got = tight->ReadFeedback();
  ASSERT_TRUE(got.ok());
  EXPECT_TRUE(got->empty());
}

TEST(DeviceOctreeTest, RejectsABrickBufferThatNeedsTooManyAllocations) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  const uint64_t brick = scene->tree->geometry().brick_samples() * 2;
  DeviceOctreeOptions options;
  options.max_allocation_bytes = brick;     // One slot per allocation ...
  options.brick_buffer_bytes = 10 * brick;  // ... but ten slots.
  auto dev = DeviceOctree::Create(&Cc(), scene->tree.get(), options);
  ASSERT_FALSE(dev.ok());
  EXPECT_EQ(dev.status().code(), StatusCode::kResourceExhausted) << dev.status().ToString();
  options.max_allocation_bytes = brick - 1;  // Not even one brick.
  options.brick_buffer_bytes = 8 * brick;
  dev = DeviceOctree::Create(&Cc(), scene->tree.get(), options);
  ASSERT_FALSE(dev.ok());
  EXPECT_EQ(dev.status().code(), StatusCode::kResourceExhausted);
  // Exactly kMaxBrickAllocations allocations is fine.
  options.max_allocation_bytes = 2 * brick;
  dev = DeviceOctree::Create(&Cc(), scene->tree.get(), options);
  ASSERT_TRUE(dev.ok()) << dev.status().ToString();
  EXPECT_EQ((*dev)->allocation_count(), kMaxBrickAllocations);
}

TEST(DeviceOctreeTest, ReservedBricksSurviveOtherOwnersUploads) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  auto dev = MakeEightSlotDevice(scene->tree.get());
  ASSERT_NE(dev, nullptr);
  const int root = tree.geometry().root_level();
  const std::vector<NodeSnapshot> level2 = Bricked(tree, root - 1);
  ASSERT_EQ(level2.size(), 8u);
  // Owner 1 asks for four level-2 nodes: they and their ancestor (the root) are uploaded; the
  // four requested ones are reserved (the cap is 8 / (1 owner + 1) = 4), the root is not.
  const std::vector<uint32_t> owned = {level2[0].id, level2[1].id, level2[2].id, level2[3].id};
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.reserve_for = 1;
  UploadStats stats;
  ASSERT_TRUE(dev->Upload(owned, budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, 5u);
  EXPECT_EQ(stats.reserved, 4u);
  EXPECT_EQ(dev->reserved_slots(), 4u);
  // An upload without owner that may evict everything else (protect nothing) needs more slots
  // than there are: it gets the 3 free ones and the root's, never a reserved one.
  std::vector<uint32_t> children;
  for (uint32_t parent : owned) {
    const NodeSnapshot p = *tree.GetNode(parent);
    for (uint32_t o = 0; o < 8 && children.size() < 8; ++o) {
      const auto child = tree.GetNode(p.child_group * 8 + o);
      if (child.has_value() && child->has_brick()) children.push_back(child->id);
    }
  }
  ASSERT_EQ(children.size(), 8u);
  UploadBudget anyone;
  anyone.max_ms = kNoTimeLimit;
  anyone.protect_frame = std::numeric_limits<uint32_t>::max();
  ASSERT_TRUE(dev->Upload(children, anyone, &stats).ok());
  EXPECT_EQ(stats.uploaded, 4u);
  EXPECT_EQ(stats.evicted, 1u);
  EXPECT_EQ(stats.deferred, 4u);
  EXPECT_EQ(stats.reserved, 0u);
  EXPECT_FALSE(dev->SlotOf(0).has_value());  // The root was not reserved.
  for (uint32_t id : owned) EXPECT_TRUE(dev->SlotOf(id).has_value()) << id;
  // Owner 2: its cap is 8 / (2 owners + 1) = 2 of the three nodes it uploads.
  const std::vector<uint32_t> second = {level2[4].id, level2[5].id, level2[6].id};
  budget.reserve_for = 2;
  budget.protect_frame = std::numeric_limits<uint32_t>::max();
  ASSERT_TRUE(dev->Upload(second, budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, 4u);  // With the root (their ancestor), over the unreserved slots.
  EXPECT_EQ(stats.evicted, 4u);
  EXPECT_EQ(stats.reserved, 2u);
  EXPECT_EQ(dev->reserved_slots(), 6u);
  // Owner 1's next upload releases its reservation first (its pass has used those bricks).
  budget.reserve_for = 1;
  ASSERT_TRUE(dev->Upload({}, budget, &stats).ok());
  EXPECT_EQ(dev->reserved_slots(), 2u);
  // Now an upload without owner may evict owner 1's bricks but not owner 2's.
  std::vector<uint32_t> reserved_by_2;
  for (uint32_t id : second) {
    if (dev->SlotOf(id).has_value()) reserved_by_2.push_back(id);
  }
  ASSERT_EQ(reserved_by_2.size(), 3u);
  std::vector<uint32_t> many;
  for (const NodeSnapshot& n : Bricked(tree, root - 2)) {
    if (!dev->SlotOf(n.id).has_value()) many.push_back(n.id);
  }
  ASSERT_GE(many.size(), 8u);
  ASSERT_TRUE(dev->Upload(many, anyone, &stats).ok());
  EXPECT_EQ(stats.uploaded, 6u);
  int survivors = 0;
  for (uint32_t id : reserved_by_2) survivors += dev->SlotOf(id).has_value() ? 1 : 0;
  EXPECT_EQ(survivors, 2);
  for (uint32_t id : owned) EXPECT_FALSE(dev->SlotOf(id).has_value()) << id;
  dev->ReleaseReservations(2);
  EXPECT_EQ(dev->reserved_slots(), 0u);
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 1),
      -1);
}

TEST(DeviceOctreeTest, ResidentOnlyReadsNeverLoadAPageAndNameTheMissingOnes) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  SceneSpec spec = NoiseSpec(volume::DataType::kUint16, 1);
  spec.page_bytes = 4 * 8 * 8 * 8 * 2;  // Four bricks per page.
  auto scene = Scene(spec);
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  paging::PageCache& cache = *scene->cache;
  // Nothing in RAM: written back, then dropped.
  ASSERT_TRUE(tree.Flush().ok());
  ASSERT_TRUE(cache.SetBudget(0).ok());
  ASSERT_TRUE(cache.SetBudget(uint64_t{1} << 30).ok());
  ASSERT_EQ(cache.stats().resident_bytes, 0u);
  DeviceOctreeOptions options;
  options.brick_reads = BrickReads::kResidentOnly;
  auto dev = MakeDevice(&tree, options);
  ASSERT_NE(dev, nullptr);
  const int root = tree.geometry().root_level();
  std::vector<uint32_t> wanted = Ids(Bricked(tree, root - 1));
  wanted.push_back(0);
  // The pages those bricks live on, as the octree names them.
  std::set<uint64_t> pages;
  std::vector<std::byte> raw(tree.geometry().brick_bytes());
  for (uint32_t id : wanted) {
    uint64_t page = 0;
    ASSERT_EQ(tree.TryReadBrick(id, raw, &page).code(), StatusCode::kUnavailable);
    pages.insert(page);
  }
  const uint64_t misses = cache.stats().misses;
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  UploadStats stats;
  ASSERT_TRUE(dev->Upload(wanted, budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, 0u);
  EXPECT_EQ(stats.unavailable, wanted.size());
  EXPECT_EQ(dev->resident_bricks(), 0u);
  EXPECT_EQ(cache.stats().misses, misses);  // No load was started.
  const std::vector<uint64_t> missing = dev->TakeMissingPages();
  EXPECT_EQ(std::set<uint64_t>(missing.begin(), missing.end()), pages);
  EXPECT_EQ(missing.size(), pages.size());  // Each page once.
  EXPECT_TRUE(dev->TakeMissingPages().empty());
  // Once the pages are in RAM the same upload brings every brick.
  for (uint64_t page : pages) ASSERT_TRUE(cache.Pin(page).ok());
  ASSERT_TRUE(dev->Upload(wanted, budget, &stats).ok());
  EXPECT_EQ(stats.uploaded, wanted.size());
  EXPECT_EQ(stats.unavailable, 0u);
  EXPECT_TRUE(dev->TakeMissingPages().empty());
  for (uint32_t id : wanted) {
    ASSERT_TRUE(dev->SlotOf(id).has_value());
    EXPECT_EQ(DeviceBrick(*dev, *dev->SlotOf(id)), HostBrick(tree, id)) << id;
  }
}

TEST(DeviceOctreeTest, CoarseLevelsAreUploadedWholeLevelsWithinTheCap) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 2));
  ASSERT_NE(scene, nullptr);
  Octree& tree = *scene->tree;
  const int root = tree.geometry().root_level();
  ASSERT_GE(root, 2);
  const std::vector<uint32_t> top = {0};
  const std::vector<uint32_t> second = Ids(Bricked(tree, root - 1));
  const std::vector<uint32_t> third = Ids(Bricked(tree, root - 2));
  ASSERT_GT(second.size(), 1u);
  const auto resident_exactly = [&](const DeviceOctree& dev, const std::vector<uint32_t>& ids) {
    EXPECT_EQ(dev.resident_bricks(), ids.size());
    for (uint32_t id : ids) {
      const std::optional<uint32_t> slot = dev.SlotOf(id);
      ASSERT_TRUE(slot.has_value()) << id;
      EXPECT_EQ(DeviceBrick(dev, *slot), HostBrick(tree, id)) << id;
    }
  };
  std::vector<uint32_t> two_levels = top;
  two_levels.insert(two_levels.end(), second.begin(), second.end());
  {
    // Room for exactly the two coarsest levels: both, and nothing of the third.
    auto dev = MakeDevice(&tree);
    ASSERT_NE(dev, nullptr);
    ASSERT_GE(dev->slot_count() / 4, two_levels.size() + third.size());
    UploadStats stats;
    ASSERT_TRUE(
        dev->UploadCoarseLevels(two_levels.size() * dev->device_brick_bytes(), &stats).ok());
    EXPECT_EQ(stats.uploaded, two_levels.size());
    resident_exactly(*dev, two_levels);
    // The node buffer says so too.
    EXPECT_EQ(
        FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 2),
        -1);
  }
  {
    // One brick short of the second level: the root alone (levels are never split).
    auto dev = MakeDevice(&tree);
    ASSERT_NE(dev, nullptr);
    ASSERT_TRUE(dev->UploadCoarseLevels((two_levels.size() - 1) * dev->device_brick_bytes()).ok());
    resident_exactly(*dev, top);
  }
  {
    // At most a quarter of the slots, whatever the bytes allow.
    DeviceOctreeOptions options;
    options.brick_buffer_bytes = 4 * second.size() * tree.geometry().brick_samples() * 2;
    auto dev = MakeDevice(&tree, options);
    ASSERT_NE(dev, nullptr);
    ASSERT_LT(dev->slot_count() / 4, two_levels.size());
    ASSERT_TRUE(dev->UploadCoarseLevels(uint64_t{1} << 30).ok());
    resident_exactly(*dev, top);
  }
  {
    // Resident-only reads with nothing in RAM: nothing uploaded, the pages named for a prefetch.
    ASSERT_TRUE(tree.Flush().ok());
    ASSERT_TRUE(scene->cache->SetBudget(0).ok());
    ASSERT_TRUE(scene->cache->SetBudget(uint64_t{1} << 30).ok());
    DeviceOctreeOptions options;
    options.brick_reads = BrickReads::kResidentOnly;
    auto dev = MakeDevice(&tree, options);
    ASSERT_NE(dev, nullptr);
    UploadStats stats;
    ASSERT_TRUE(dev->UploadCoarseLevels(uint64_t{1} << 30, &stats).ok());
    EXPECT_EQ(stats.uploaded, 0u);
    EXPECT_GE(stats.unavailable, two_levels.size());
    EXPECT_FALSE(dev->TakeMissingPages().empty());
  }
}

TEST(DeviceOctreeTest, ResizingTheBrickBufferDropsResidencyAndKeepsWorking) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec(volume::DataType::kUint16, 1));
  ASSERT_NE(scene, nullptr);
  const Octree& tree = *scene->tree;
  const uint64_t brick = tree.geometry().brick_samples() * 2;
  // 48 x 40 x 48 voxels in 8^3 bricks: 6*5*6 + 3*3*3 + 2*2*2 + 1 nodes can ever own a brick.
  EXPECT_EQ(DeviceOctree::MaxBrickBufferBytes(tree.geometry()), 216 * brick);
  DeviceOctreeOptions options;
  options.brick_buffer_bytes = 8 * brick;
  auto dev = MakeDevice(scene->tree.get(), options);
  ASSERT_NE(dev, nullptr);
  const int root = tree.geometry().root_level();
  const std::vector<uint32_t> level2 = Ids(Bricked(tree, root - 1));
  UploadBudget budget;
  budget.max_ms = kNoTimeLimit;
  budget.reserve_for = 7;
  ASSERT_TRUE(dev->Upload(level2, budget, nullptr).ok());
  ASSERT_EQ(dev->resident_bricks(), 8u);
  ASSERT_GT(dev->reserved_slots(), 0u);
  // The same size: nothing changes.
  ASSERT_TRUE(dev->ResizeBrickBuffer(8 * brick + brick / 2).ok());
  EXPECT_EQ(dev->resident_bricks(), 8u);
  // Twice as many slots: no brick is resident any more (and the entries say so).
  ASSERT_TRUE(dev->ResizeBrickBuffer(16 * brick).ok());
  EXPECT_EQ(dev->slot_count(), 16u);
  EXPECT_EQ(dev->brick_buffer_bytes(), 16 * brick);
  EXPECT_EQ(dev->resident_bricks(), 0u);
  EXPECT_EQ(dev->reserved_slots(), 0u);
  EXPECT_EQ(FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity()), 1), -1);
  // It fills the new slots with the right bytes.
  std::vector<uint32_t> wanted = level2;
  for (const NodeSnapshot& n : Bricked(tree, root - 2)) {
    if (wanted.size() < 15) wanted.push_back(n.id);
  }
  wanted.push_back(0);
  ASSERT_TRUE(dev->UploadAll(wanted, 0).ok());
  EXPECT_EQ(dev->resident_bricks(), 16u);
  for (uint32_t id : wanted) {
    ASSERT_TRUE(dev->SlotOf(id).has_value()) << id;
    EXPECT_EQ(DeviceBrick(*dev, *dev->SlotOf(id)), HostBrick(tree, id)) << id;
  }
  EXPECT_EQ(
      FirstDifference(DeviceNodes(*dev), ExpectedNodes(tree, dev->node_capacity(), dev.get()), 1),
      -1);
  // More than the tree can use is clamped; fewer than kMinBrickSlots is raised.
  ASSERT_TRUE(dev->ResizeBrickBuffer(uint64_t{1} << 40).ok());
  EXPECT_EQ(dev->slot_count(), 216u);
  ASSERT_TRUE(dev->ResizeBrickBuffer(1).ok());
  EXPECT_EQ(dev->slot_count(), kMinBrickSlots);
}

}  // namespace
}  // namespace octoscope::render
