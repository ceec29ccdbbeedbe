#include "session/outbox.h"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>
#include <vector>

namespace octoscope::session {
namespace {

// Frames carry (view, sequence, final) in bytes 16.. so the test can read back what was sent.
OutgoingFrame Frame(int view, uint64_t sequence, bool final = false) {
  OutgoingFrame f;
  f.view = view;
  f.sequence = sequence;
  f.final = final;
  f.bytes.assign(32, 0);
  f.bytes[16] = static_cast<uint8_t>(view);
  f.bytes[17] = static_cast<uint8_t>(sequence);
  f.bytes[18] = final ? 1 : 0;
  return f;
}

struct Sent {
  uint64_t id;
  int view;
  int sequence;
  bool final;
};

class OutboxTest : public ::testing::Test {
 protected:
  Outbox box_{[this](std::vector<uint8_t> b) {
    uint64_t id = 0;
    for (int i = 0; i < 8; ++i) id |= uint64_t{b[8 + i]} << (8 * i);
    sent_.push_back({id, b[16], b[17], b[18] != 0});
  }};
  std::vector<Sent> sent_;
};

TEST_F(OutboxTest, AtMostTwoUnacknowledgedAndTheNewestWaitingFrameWins) {
  box_.Offer(Frame(0, 1));
  box_.Offer(Frame(0, 2));
  ASSERT_EQ(sent_.size(), 2u);
  EXPECT_EQ(sent_[0].id, 1u);
  EXPECT_EQ(sent_[1].id, 2u);
  for (uint64_t s = 3; s <= 10; ++s) box_.Offer(Frame(0, s));  // Window full: they replace.
  EXPECT_EQ(sent_.size(), 2u);
  EXPECT_EQ(box_.stats().waiting, 1u);
  EXPECT_EQ(box_.stats().dropped, 7u);
  box_.OnAck(1);
  ASSERT_EQ(sent_.size(), 3u);
  EXPECT_EQ(sent_[2].sequence, 10);  // The newest, never 3..9.
  EXPECT_EQ(sent_[2].id, 3u);
}

TEST_F(OutboxTest, NeverAStaleFrameAfterANewerOne) {
  box_.Offer(Frame(0, 5));
  box_.Offer(Frame(0, 3));  // Older than what was sent: dropped.
  box_.Offer(Frame(0, 5, true));
  box_.Offer(Frame(0, 5));  // A progress frame after the final of the same order: dropped.
  box_.OnAck(2);
  box_.Offer(Frame(0, 4));
  ASSERT_EQ(sent_.size(), 2u);
  EXPECT_TRUE(sent_[1].final);
  for (size_t i = 1; i < sent_.size(); ++i) EXPECT_GE(sent_[i].sequence, sent_[i - 1].sequence);
}

TEST_F(OutboxTest, ViewsShareTheWindowRoundRobin) {
  box_.Offer(Frame(0, 1));
  box_.Offer(Frame(1, 1));
  box_.Offer(Frame(2, 1));
  box_.Offer(Frame(3, 1));
  box_.Offer(Frame(0, 2));
  ASSERT_EQ(sent_.size(), 2u);
  box_.OnAck(2);  // Cumulative.
  ASSERT_EQ(sent_.size(), 4u);
  EXPECT_EQ(sent_[2].view, 2);
  EXPECT_EQ(sent_[3].view, 3);
  box_.OnAck(100);  // Beyond what was sent: counts as the last sent.
  ASSERT_EQ(sent_.size(), 5u);
  EXPECT_EQ(sent_[4].view, 0);
  EXPECT_EQ(sent_[4].sequence, 2);
  EXPECT_EQ(box_.stats().unacked, 1u);
}

TEST_F(OutboxTest, AStalledClientHoldsAtMostOneFramePerView) {
  for (uint64_t s = 1; s <= 1000; ++s) {
    for (int v = 0; v < 4; ++v) box_.Offer(Frame(v, s));
  }
  EXPECT_EQ(sent_.size(), 2u);
  EXPECT_EQ(box_.stats().waiting, 4u);
  box_.Close();
  box_.Offer(Frame(0, 2000));
  EXPECT_EQ(box_.stats().waiting, 0u);
}

TEST(OutboxConcurrencyTest, IdsAreSentInOrderFromManyThreads) {
  std::mutex mu;
  std::vector<uint64_t> ids;
  Outbox box([&](std::vector<uint8_t> b) {
    uint64_t id = 0;
    for (int i = 0; i < 8; ++i) id |= uint64_t{b[8 + i]} << (8 * i);
    std::lock_guard lock(mu);
    ids.push_back(id);
  });
  std::atomic<bool> done{false};
  std::vector<std::thread> threads;
  for (int v = 0; v < 4; ++v) {
    threads.emplace_back([&, v] {
      for (uint64_t s = 1; s <= 2000; ++s) box.Offer(Frame(v, s));
    });
  }
  std::thread acker([&] {
    while (!done) {
      box.OnAck(box.next_id() - 1);
      std::this_thread::yield();
    }
  });
  for (auto& t : threads) t.join();
  done = true;
  acker.join();
  while (box.stats().waiting > 0) box.OnAck(box.next_id() - 1);  // Drain what is left.
  for (size_t i = 0; i < ids.size(); ++i) EXPECT_EQ(ids[i], i + 1);
  EXPECT_GT(ids.size(), 2u);
}

}  // namespace
}  // namespace octoscope::session
