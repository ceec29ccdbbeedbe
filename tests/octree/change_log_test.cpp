// ChangeLog and ChangeSubscription (server/octree/change_log.h) on hand-written event sequences
// with the expected polls written out, and against a plain model (every event each subscription
// would see without coalescing or bounds) in a randomised run. Consumers mirroring a real octree:
// octree_test.cpp (several speeds) and octree_concurrency_test.cpp (threads).
#include "octree/change_log.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <map>
#include <new>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace {

// Allocations made by this thread while counting (operator new is replaced for the whole test
// binary; it only counts while a test asks it to).
thread_local bool count_allocations = false;
thread_local size_t allocations = 0;

}  // namespace

void* operator new(std::size_t bytes) {
  if (count_allocations) ++allocations;
  if (void* p = std::malloc(bytes == 0 ? 1 : bytes)) return p;
  throw std::bad_alloc();
}
// GCC sees free() of what (its idea of) operator new returned; both are replaced here, so they
// match.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace octoscope::octree {
namespace {

constexpr NodeChangeKind kC = NodeChangeKind::kCreated;
constexpr NodeChangeKind kU = NodeChangeKind::kUpdated;
constexpr NodeChangeKind kD = NodeChangeKind::kDeleted;
using Events = std::vector<NodeChange>;

// Counts this thread's allocations from construction to allocations().
class AllocationCounter {
 public:
  AllocationCounter() {
    allocations = 0;
    count_allocations = true;
  }
  ~AllocationCounter() { count_allocations = false; }
  size_t count() const { return allocations; }
};

Events Poll(ChangeSubscription& s) {
  ChangeBatch batch = s.Poll();
  EXPECT_FALSE(batch.resync);
  return batch.events;
}

TEST(ChangeLogTest, OneSubscriptionGetsUpdatesCoalescedAndCreationsAndDeletionsInOrder) {
  ChangeLog log;
  ChangeSubscription sub = log.Subscribe();
  log.Append(8, kC);
  log.Append(8, kU);
  log.Append(0, kU);
  log.Append(8, kU);
  log.Append(8, kD);
  log.Append(8, kC);
  EXPECT_EQ(log.retained(), 5u);
  EXPECT_EQ(sub.backlog(), 5u);
  EXPECT_EQ(Poll(sub), (Events{{8, kC}, {8, kU}, {0, kU}, {8, kD}, {8, kC}}));
  EXPECT_EQ(log.retained(), 0u);
  EXPECT_EQ(sub.backlog(), 0u);
  log.Append(0, kU);  // A new window: reported again.
  EXPECT_EQ(Poll(sub), (Events{{0, kU}}));
  EXPECT_TRUE(Poll(sub).empty());
}

TEST(ChangeLogTest, EachSubscriptionReadsFromItsOwnCursor) {
  ChangeLog log;
  log.Append(1, kC);  // Before anyone subscribed: not recorded.
  ChangeSubscription a = log.Subscribe();
  log.Append(8, kC);
  ChangeSubscription b = log.Subscribe();
  log.Append(16, kC);
  EXPECT_EQ(log.subscribers(), 2u);
  EXPECT_EQ(Poll(b), (Events{{16, kC}}));
  EXPECT_EQ(log.retained(), 2u);  // a has read nothing yet.
  EXPECT_EQ(Poll(a), (Events{{8, kC}, {16, kC}}));
  EXPECT_EQ(log.retained(), 0u);
  log.Append(16, kD);
  EXPECT_EQ(Poll(a), (Events{{16, kD}}));
  EXPECT_EQ(log.retained(), 1u);  // Until b has read it too.
  EXPECT_EQ(Poll(b), (Events{{16, kD}}));
  EXPECT_EQ(log.retained(), 0u);
}

// An update is dropped only while every subscription will still read the retained one; once one
// has read it, the retained one is dropped instead and the new one appended.
TEST(ChangeLogTest, CoalescingWithCursorsAtDifferentPositions) {
  ChangeLog log;
  ChangeSubscription a = log.Subscribe();
  ChangeSubscription b = log.Subscribe();
  log.Append(5, kU);
  log.Append(5, kU);  // Both will read the first: dropped.
  log.Append(8, kC);
  log.Append(5, kU);  // Likewise.
  EXPECT_EQ(log.retained(), 2u);
  EXPECT_EQ(Poll(a), (Events{{5, kU}, {8, kC}}));
  log.Append(5, kU);  // a read the retained one: appended; b reads this one instead.
  log.Append(5, kU);  // Neither has read the new one: dropped.
  log.Append(8, kD);
  log.Append(5, kU);  // Dropped.
  EXPECT_EQ(Poll(b), (Events{{8, kC}, {5, kU}, {8, kD}}));
  EXPECT_EQ(Poll(a), (Events{{5, kU}, {8, kD}}));
  EXPECT_EQ(log.retained(), 0u);
}

// A node updated a million times while a fast subscription polls 10,000 times between two polls
// of a slow one costs the slow one one event, and the log never holds more than a compaction's
// worth of entries.
TEST(ChangeLogTest, ManyUpdatesBetweenTwoPollsOfASlowSubscriptionCostOneEntry) {
  ChangeLog log;
  ChangeSubscription fast = log.Subscribe();
  ChangeSubscription slow = log.Subscribe();
  log.Append(3, kC);
  size_t most = 0;
  uint64_t fast_updates = 0;
  for (int i = 0; i < 1000000; ++i) {
    log.Append(7, kU);
    if (i % 100 == 99) {
      for (const NodeChange& c : Poll(fast)) fast_updates += c.node == 7 ? 1 : 0;
    }
    most = std::max(most, log.retained());
  }
  EXPECT_EQ(fast_updates, 10000u);  // One per window of the fast one.
  EXPECT_LE(most, 1100u);           // Dropped entries are compacted away.
  EXPECT_EQ(Poll(slow), (Events{{3, kC}, {7, kU}}));
  EXPECT_TRUE(Poll(fast).empty());
  EXPECT_EQ(log.retained(), 0u);
}

TEST(ChangeLogTest, ASubscriptionThatFallsBehindIsToldToResynchroniseAndRecovers) {
  ChangeLog log;
  ChangeSubscription fast = log.Subscribe();
  ChangeSubscription slow = log.Subscribe(10);
  for (uint32_t i = 0; i < 10; ++i) log.Append(8 * i, kC);
  EXPECT_EQ(slow.backlog(), 10u);  // Exactly at its bound: still fine.
  log.Append(80, kC);
  EXPECT_EQ(slow.backlog(), 0u);  // Over it: its events are dropped for it.
  EXPECT_EQ(Poll(fast).size(), 11u);
  EXPECT_EQ(log.retained(), 0u);  // The slow one pins nothing any more.
  log.Append(88, kC);
  EXPECT_EQ(log.retained(), 1u);
  const ChangeBatch verdict = slow.Poll();
  EXPECT_TRUE(verdict.resync);
  EXPECT_TRUE(verdict.events.empty());
  // It now stands at the head: what comes after the verdict (after its walk starts) is delivered.
  log.Append(88, kU);
  EXPECT_EQ(Poll(slow), (Events{{88, kU}}));
  EXPECT_EQ(Poll(fast), (Events{{88, kC}, {88, kU}}));
  EXPECT_EQ(log.retained(), 0u);
}

// However long a subscription sleeps, the log holds at most its bound.
TEST(ChangeLogTest, MemoryIsBoundedWhileASubscriptionSleeps) {
  ChangeLog log;
  ChangeSubscription fast = log.Subscribe();
  ChangeSubscription sleeper = log.Subscribe(1000);
  size_t most = 0;
  for (uint32_t i = 0; i < 200000; ++i) {
    log.Append(i, i % 3 == 0 ? kU : kC);
    most = std::max(most, log.retained());
    if (i % 500 == 0) (void)fast.Poll();
  }
  EXPECT_LE(most, 1000u);
  EXPECT_TRUE(sleeper.Poll().resync);
  // Alone and asleep it pins nothing at all: with only a resync pending nothing is stored.
  fast = ChangeSubscription();
  ChangeSubscription alone = log.Subscribe(1000);
  for (uint32_t i = 0; i < 5000; ++i) log.Append(i, kC);
  EXPECT_EQ(log.retained(), 0u);
  EXPECT_TRUE(alone.Poll().resync);
}

TEST(ChangeLogTest, WithoutSubscriptionsAppendStoresAndAllocatesNothing) {
  ChangeLog log;
  {
    const AllocationCounter counter;
    for (uint32_t i = 0; i < 100000; ++i) log.Append(i % 977, i % 2 == 0 ? kU : kC);
    EXPECT_EQ(counter.count(), 0u);
  }
  EXPECT_EQ(log.retained(), 0u);
  {
    ChangeSubscription sub = log.Subscribe();
    log.Append(1, kC);
    log.Append(1, kU);
    EXPECT_EQ(log.retained(), 2u);
  }
  EXPECT_EQ(log.subscribers(), 0u);
  EXPECT_EQ(log.retained(), 0u);
  {
    const AllocationCounter counter;
    for (uint32_t i = 0; i < 100000; ++i) log.Append(i % 977, kU);
    EXPECT_EQ(counter.count(), 0u);
  }
  EXPECT_EQ(log.retained(), 0u);
  // Only a subscription waiting for its resync: nothing is stored for it either.
  ChangeSubscription behind = log.Subscribe(2);
  for (uint32_t i = 0; i < 3; ++i) log.Append(i, kC);
  {
    const AllocationCounter counter;
    for (uint32_t i = 0; i < 100000; ++i) log.Append(i % 977, kU);
    EXPECT_EQ(counter.count(), 0u);
  }
  EXPECT_EQ(log.retained(), 0u);
  EXPECT_TRUE(behind.Poll().resync);
}

TEST(ChangeLogTest, UnsubscribingReleasesWhatOnlyThatSubscriptionNeeded) {
  ChangeLog log;
  ChangeSubscription reader = log.Subscribe();
  auto idle = std::make_optional(log.Subscribe());
  for (uint32_t i = 0; i < 5000; ++i) log.Append(i, kC);
  EXPECT_EQ(Poll(reader).size(), 5000u);
  EXPECT_EQ(log.retained(), 5000u);  // idle has read none of them.
  idle.reset();
  EXPECT_EQ(log.subscribers(), 1u);
  EXPECT_EQ(log.retained(), 0u);
  log.Append(1, kU);
  EXPECT_EQ(Poll(reader), (Events{{1, kU}}));
}

TEST(ChangeLogTest, SubscriptionsMoveWithTheirCursor) {
  ChangeLog log;
  ChangeSubscription a = log.Subscribe();
  log.Append(8, kC);
  ChangeSubscription b = std::move(a);
  EXPECT_FALSE(a.attached());  // NOLINT(bugprone-use-after-move): moved-from is detached.
  EXPECT_TRUE(a.Poll().events.empty());
  EXPECT_EQ(log.subscribers(), 1u);
  log.Append(16, kC);
  ChangeSubscription c = log.Subscribe();
  log.Append(24, kC);
  c = std::move(b);  // c's own cursor is unsubscribed; it continues b's.
  EXPECT_EQ(log.subscribers(), 1u);
  EXPECT_EQ(Poll(c), (Events{{8, kC}, {16, kC}, {24, kC}}));
  c = ChangeSubscription();
  EXPECT_EQ(log.subscribers(), 0u);
  EXPECT_EQ(log.retained(), 0u);
}

TEST(ChangeLogTest, ASubscriptionMayOutliveItsLog) {
  ChangeSubscription sub;
  {
    ChangeLog log;
    sub = log.Subscribe();
    log.Append(8, kC);
  }
  EXPECT_EQ(Poll(sub), (Events{{8, kC}}));
  EXPECT_TRUE(Poll(sub).empty());
}

// Random appends and polls against a model: every event appended since each subscription's last
// poll, uncoalesced. A poll must return the model's creations and deletions in order, each id
// the model updated exactly once as kUpdated, placed where one of those updates was (between the
// same creations and deletions), and resync only when the model's window exceeds the bound.
TEST(ChangeLogTest, RandomAppendsAndPollsMatchAPlainModel) {
  struct Consumer {
    size_t max_backlog = 0;
    double poll_chance = 0;
    std::optional<ChangeSubscription> sub;
    Events window;
    int resyncs = 0;
    uint64_t polls = 0;
  };
  ChangeLog log;
  std::vector<Consumer> consumers(4);
  // A fast one, a slow one with the default bound, and two that fall behind their small bounds.
  const std::pair<size_t, double> kinds[] = {
      {kDefaultChangeBacklog, 0.3}, {kDefaultChangeBacklog, 0.002}, {40, 0.02}, {3000, 0.0005}};
  for (size_t i = 0; i < consumers.size(); ++i) {
    consumers[i].max_backlog = kinds[i].first;
    consumers[i].poll_chance = kinds[i].second;
  }
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (Consumer& c : consumers) c.sub = log.Subscribe(c.max_backlog);

  const auto check = [](Consumer& c, const ChangeBatch& got) {
    ++c.polls;
    if (got.resync) {
      ++c.resyncs;
      EXPECT_GT(c.window.size(), c.max_backlog) << "resync without falling behind";
      EXPECT_TRUE(got.events.empty());
      c.window.clear();
      return;
    }
    // Creations and deletions: exactly the model's, in order.
    Events want_cd, got_cd;
    for (const NodeChange& e : c.window) {
      if (e.kind != kU) want_cd.push_back(e);
    }
    // Per updated id: the range of "creations/deletions before it" its updates had.
    std::map<uint32_t, std::pair<size_t, size_t>> update_range;
    for (size_t i = 0, cd = 0; i < c.window.size(); ++i) {
      if (c.window[i].kind != kU) {
        ++cd;
        continue;
      }
      auto [it, fresh] = update_range.try_emplace(c.window[i].node, cd, cd);
      if (!fresh) it->second.second = cd;
    }
    std::set<uint32_t> seen;
    for (size_t i = 0, cd = 0; i < got.events.size(); ++i) {
      const NodeChange& e = got.events[i];
      if (e.kind != kU) {
        got_cd.push_back(e);
        ++cd;
        continue;
      }
      EXPECT_TRUE(seen.insert(e.node).second) << "two updates of " << e.node << " in one poll";
      const auto it = update_range.find(e.node);
      ASSERT_NE(it, update_range.end()) << "update of " << e.node << " never happened";
      EXPECT_GE(cd, it->second.first) << e.node;
      EXPECT_LE(cd, it->second.second) << e.node;
    }
    EXPECT_EQ(got_cd, want_cd);
    EXPECT_EQ(seen.size(), update_range.size()) << "an update was lost";
    c.window.clear();
  };

  for (int step = 0; step < 300000; ++step) {
    const uint32_t id = static_cast<uint32_t>(rng() % 48);
    const double r = unit(rng);
    const NodeChangeKind kind = r < 0.8 ? kU : (r < 0.9 ? kC : kD);
    log.Append(id, kind);
    for (Consumer& c : consumers) {
      if (c.sub.has_value()) c.window.push_back({id, kind});
    }
    // The log holds no more than the longest window still within its bound.
    size_t bound = 0;
    for (const Consumer& c : consumers)
      bound = std::max(bound, std::min(c.window.size(), c.max_backlog));
    ASSERT_LE(log.retained(), bound);
    for (Consumer& c : consumers) {
      if (!c.sub.has_value() || unit(rng) >= c.poll_chance) continue;
      ASSERT_NO_FATAL_FAILURE(check(c, c.sub->Poll()));
      if (::testing::Test::HasFailure()) return;
    }
    if (step % 50000 == 49999) {  // Unsubscribe and resubscribe one.
      Consumer& c = consumers[static_cast<size_t>(step / 50000) % consumers.size()];
      c.sub.reset();
      c.window.clear();
      c.sub = log.Subscribe(c.max_backlog);
    }
  }
  for (Consumer& c : consumers) ASSERT_NO_FATAL_FAILURE(check(c, c.sub->Poll()));
  EXPECT_EQ(log.retained(), 0u);
  EXPECT_EQ(consumers[0].resyncs, 0);
  EXPECT_GT(consumers[2].resyncs, 0);
  EXPECT_GT(consumers[3].resyncs, 0);
}

}  // namespace
}  // namespace octoscope::octree
