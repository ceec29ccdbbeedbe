// ChunkCache: one decode per chunk however many threads want it at once, read tracking drops
// fully read chunks, the byte budget evicts the least recently used, errors are not cached.
#include "io/chunk_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

namespace octoscope::io {
namespace {

ChunkCache::Decoder Bytes(size_t n, std::atomic<int>* calls = nullptr) {
  return [n, calls]() -> Result<ChunkCache::Data> {
    if (calls) ++*calls;
    return ChunkCache::Data(std::make_shared<UninitializedBytes>(n, std::byte{1}));
  };
}

TEST(ChunkCache, ConcurrentRequestsShareOneDecode) {
  ChunkCache cache(1 << 20);
  std::atomic<int> calls{0};
  auto slow = [&]() -> Result<ChunkCache::Data> {
    ++calls;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    return ChunkCache::Data(std::make_shared<UninitializedBytes>(10));
  };
  std::vector<std::thread> threads;
  std::atomic<int> ok{0};
  for (int i = 0; i < 8; ++i) {
    threads.emplace_back([&] {
      auto r = cache.Get(42, true, slow);
      if (r.ok() && *r && (*r)->size() == 10) ++ok;
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(ok, 8);
  EXPECT_EQ(cache.decodes(), 1u);
}

TEST(ChunkCache, FullyReadChunksAreDropped) {
  ChunkCache cache(1 << 20);
  std::atomic<int> calls{0};
  ASSERT_TRUE(cache.Get(1, true, Bytes(100, &calls)).ok());
  EXPECT_EQ(cache.bytes(), 100u);
  cache.MarkRead(1, 0, 2, 4);
  EXPECT_EQ(cache.entries(), 1u);
  ASSERT_TRUE(cache.Get(1, true, Bytes(100, &calls)).ok());
  EXPECT_EQ(calls, 1);  // Served from the cache.
  cache.MarkRead(1, 1, 3, 4);
  EXPECT_EQ(cache.entries(), 0u);
  EXPECT_EQ(cache.bytes(), 0u);
  // A read that uses the whole chunk does not keep it.
  ASSERT_TRUE(cache.Get(2, false, Bytes(100, &calls)).ok());
  EXPECT_EQ(cache.entries(), 0u);
}

TEST(ChunkCache, BudgetEvictsLeastRecentlyUsed) {
  ChunkCache cache(250);
  std::atomic<int> calls{0};
  ASSERT_TRUE(cache.Get(1, true, Bytes(100, &calls)).ok());
  ASSERT_TRUE(cache.Get(2, true, Bytes(100, &calls)).ok());
  ASSERT_TRUE(cache.Get(1, true, Bytes(100, &calls)).ok());  // 1 is now the most recent.
  ASSERT_TRUE(cache.Get(3, true, Bytes(100, &calls)).ok());  // Evicts 2.
  EXPECT_LE(cache.bytes(), 250u);
  EXPECT_EQ(calls, 3);
  ASSERT_TRUE(cache.Get(1, true, Bytes(100, &calls)).ok());
  EXPECT_EQ(calls, 3);
  ASSERT_TRUE(cache.Get(2, true, Bytes(100, &calls)).ok());
  EXPECT_EQ(calls, 4);
  // A chunk larger than the budget is returned but not kept.
  auto big = cache.Get(9, true, Bytes(1000, &calls));
  ASSERT_TRUE(big.ok());
  EXPECT_EQ((*big)->size(), 1000u);
  EXPECT_LE(cache.bytes(), 250u);
}

TEST(ChunkCache, ErrorsAndExceptionsAreNotCached) {
  ChunkCache cache(1 << 20);
  auto bad = cache.Get(5, true, []() -> Result<ChunkCache::Data> { return CorruptError("x"); });
  EXPECT_EQ(bad.status().code(), StatusCode::kCorrupt);
  auto thrown =
      cache.Get(5, true, []() -> Result<ChunkCache::Data> { throw std::runtime_error("boom"); });
  EXPECT_EQ(thrown.status().code(), StatusCode::kInternal);
  std::atomic<int> calls{0};
  ASSERT_TRUE(cache.Get(5, true, Bytes(10, &calls)).ok());
  EXPECT_EQ(calls, 1);
  // Absent chunks (nullptr) are cached like any other.
  auto absent = cache.Get(6, true, [] { return Result<ChunkCache::Data>(ChunkCache::Data()); });
  ASSERT_TRUE(absent.ok());
  EXPECT_EQ(*absent, nullptr);
}

}  // namespace
}  // namespace octoscope::io
