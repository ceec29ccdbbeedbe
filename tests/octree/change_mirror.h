// Test helper: a consumer of the octree's change log written the way docs/octree_format.md
// ("Change log") tells consumers to be: subscribe, walk the tree from the root by child group,
// then apply each poll's events in order reading every node's CURRENT state (GetNode, ReadBrick),
// and walk again on a resync verdict. Whenever the tree is quiet and the mirror has synced, its
// map must hold exactly the live nodes by id, each as the tree has it now (ExpectMirrors checks
// that against a fresh walk of the tree). Not thread-safe: one thread per mirror.
#ifndef OCTOSCOPE_TESTS_OCTREE_CHANGE_MIRROR_H_
#define OCTOSCOPE_TESTS_OCTREE_CHANGE_MIRROR_H_

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "octree/change_log.h"
#include "octree/octree.h"

namespace octoscope::octree::testing {

class ChangeMirror {
 public:
  struct Mirrored {
    NodeSnapshot node;
    std::vector<std::byte> brick;  // Empty when the node has no brick.
  };

  explicit ChangeMirror(const Octree* tree, ChangeSubscription subscription)
      : tree_(tree), subscription_(std::move(subscription)) {
    Walk();
  }

  // Polls once and applies what it got.
  void Sync() {
    ChangeBatch batch = subscription_.Poll();
    if (batch.resync) {
      ++resyncs_;
      Walk();
      return;
    }
    for (const NodeChange& change : batch.events) {
      ++events_;
      if (change.kind == NodeChangeKind::kCreated) ++created_;
      if (change.kind == NodeChangeKind::kDeleted) {
        ++deleted_;
        nodes_.erase(change.node);
        continue;
      }
      Read(change.node);  // Gone already counts as deleted (its event is in a later poll).
    }
  }

  // Rebuilds the map from the root, as after subscribing or a resync verdict.
  void Walk() {
    nodes_.clear();
    std::vector<uint32_t> queue = {0};
    for (size_t i = 0; i < queue.size(); ++i) {
      if (nodes_.count(queue[i]) != 0) continue;  // A group reused while we walk.
      Read(queue[i]);
      const auto it = nodes_.find(queue[i]);
      if (it == nodes_.end() || !it->second.node.has_children()) continue;
      for (uint32_t o = 0; o < 8; ++o) queue.push_back(it->second.node.child_group * 8 + o);
    }
  }

  const std::map<uint32_t, Mirrored>& nodes() const { return nodes_; }
  int resyncs() const { return resyncs_; }
  uint64_t events() const { return events_; }
  uint64_t created() const { return created_; }
  uint64_t deleted() const { return deleted_; }
  ChangeSubscription& subscription() { return subscription_; }

 private:
  void Read(uint32_t id) {
    std::optional<NodeSnapshot> node = tree_->GetNode(id);
    if (!node.has_value()) {
      nodes_.erase(id);
      return;
    }
    Mirrored m{std::move(*node), {}};
    if (m.node.has_brick()) {
      m.brick.resize(tree_->geometry().brick_bytes());
      const Status read = tree_->ReadBrick(id, m.brick);
      // kNotFound: the brick was dropped after the snapshot; that change's event follows.
      if (!read.ok()) m.brick.clear();
      if (!read.ok() && read.code() != StatusCode::kNotFound) {
        ADD_FAILURE() << "ReadBrick(" << id << "): " << read.ToString();
      }
    }
    nodes_[id] = std::move(m);
  }

  const Octree* tree_;
  ChangeSubscription subscription_;
  std::map<uint32_t, Mirrored> nodes_;
  int resyncs_ = 0;
  uint64_t events_ = 0, created_ = 0, deleted_ = 0;
};

// The mirror holds exactly the tree's live nodes, each as it is now. The tree is walked by KEY
// here (GetNode(NodeKey)), not by child-group ids as the mirror does.
inline void ExpectMirrors(const Octree& tree, const ChangeMirror& mirror, const std::string& what) {
  size_t live = 0;
  std::vector<NodeKey> stack{tree.geometry().RootKey()};
  while (!stack.empty()) {
    const NodeKey key = stack.back();
    stack.pop_back();
    const std::optional<NodeSnapshot> want = tree.GetNode(key);
    ASSERT_TRUE(want.has_value()) << what << ": " << key.ToString() << " listed but missing";
    ++live;
    if (want->has_children()) {
      for (int o = 0; o < 8; ++o) stack.push_back(ChildKey(key, o));
    }
    const uint32_t id = want->id;
    const auto it = mirror.nodes().find(id);
    ASSERT_NE(it, mirror.nodes().end()) << what << ": node " << id << " never reported";
    const NodeSnapshot& got = it->second.node;
    EXPECT_EQ(got.key, want->key) << what << ": node " << id;
    EXPECT_EQ(got.child_group, want->child_group) << what << ": node " << id;
    EXPECT_EQ(got.brick, want->brick) << what << ": node " << id;
    EXPECT_EQ(got.is_virtual, want->is_virtual) << what << ": node " << id;
    EXPECT_EQ(got.complete, want->complete) << what << ": node " << id;
    EXPECT_EQ(got.channels, want->channels) << what << ": node " << id;
    std::vector<std::byte> brick;
    if (want->has_brick()) {
      brick.resize(tree.geometry().brick_bytes());
      ASSERT_TRUE(tree.ReadBrick(id, brick).ok()) << what << ": node " << id;
    }
    EXPECT_EQ(it->second.brick, brick) << what << ": stale brick bytes for node " << id;
  }
  EXPECT_EQ(live, tree.stats().nodes) << what;
  EXPECT_EQ(mirror.nodes().size(), live) << what << ": the mirror holds nodes that are gone";
}

}  // namespace octoscope::octree::testing

#endif  // OCTOSCOPE_TESTS_OCTREE_CHANGE_MIRROR_H_
