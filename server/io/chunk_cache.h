// ChunkCache: decoded chunks of one chunked array (an OME-Zarr level, an Imaris resolution level),
// shared by the threads reading it, within a byte budget.
//
// - In flight: a chunk being decoded is entered at once, so a second reader that wants it waits
//   for that one decode instead of decoding it again (channels stored in one chunk, concurrent
//   builder threads).
// - Read tracking: a reader says which parts ("units": one channel-plane of the chunk each) it has
//   copied out; a chunk whose units have all been read is dropped at once, so a sequential pass
//   with slabs thinner than the chunks keeps only the partly read chunks (one chunk row), and a
//   chunk a read uses completely is never kept.
// - Budget: beyond `budget_bytes` of decoded chunks the least recently used are dropped (readers
//   holding one keep it alive until they are done, so memory can exceed the budget by the chunks
//   being copied at that moment).
//
// Invariant: bytes() == the sum of the sizes of the finished entries held.
// Thread safety: thread-safe. Decoding runs on the calling thread, outside the cache's lock.
#ifndef OCTOSCOPE_IO_CHUNK_CACHE_H_
#define OCTOSCOPE_IO_CHUNK_CACHE_H_

#include <cstdint>
#include <functional>
#include <future>
#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

#include "util/result.h"
#include "util/uninitialized_bytes.h"

namespace octoscope::io {

class ChunkCache {
 public:
  // A decoded chunk; nullptr stands for a chunk absent from the file (it reads as the fill value).
  using Data = std::shared_ptr<const UninitializedBytes>;
  using Decoder = std::function<Result<Data>()>;

  explicit ChunkCache(uint64_t budget_bytes) : budget_(budget_bytes) {}
  ChunkCache(const ChunkCache&) = delete;
  ChunkCache& operator=(const ChunkCache&) = delete;

  // The chunk `key`: from the cache, from a decode in flight on another thread, or decoded here
  // by `decode`. `keep`: whether it is worth keeping after this read (false when this read
  // uses all of it). Errors are not cached: the next Get decodes again.
  Result<Data> Get(uint64_t key, bool keep, const Decoder& decode);

  // Records that units [first, first + count) of the chunk's `total` units have been read;
  // drops the chunk once all have. Unknown keys are ignored.
  // REQUIRES: first + count <= total, the same `total` for every call with this key.
  void MarkRead(uint64_t key, uint64_t first, uint64_t count, uint64_t total);

  uint64_t bytes() const;    // Decoded bytes held.
  size_t entries() const;    // Chunks held (finished or in flight).
  uint64_t decodes() const;  // Chunks decoded so far (for tests and benchmarks).

 private:
  struct Entry {
    std::shared_future<Result<Data>> future;
    bool ready = false;
    uint64_t bytes = 0;
    std::list<uint64_t>::iterator lru;  // Valid when ready.
    std::vector<bool> read;             // Units read so far (sized on first MarkRead).
    uint64_t read_count = 0;
  };

  void EraseLocked(std::unordered_map<uint64_t, Entry>::iterator it);
  void EvictLocked();

  const uint64_t budget_;
  mutable std::mutex mutex_;
  std::unordered_map<uint64_t, Entry> entries_;  // GUARDED_BY(mutex_)
  std::list<uint64_t> lru_;                      // GUARDED_BY(mutex_): front = most recent.
  uint64_t bytes_ = 0;                           // GUARDED_BY(mutex_)
  uint64_t decodes_ = 0;                         // GUARDED_BY(mutex_)
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_CHUNK_CACHE_H_
