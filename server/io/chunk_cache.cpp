#include "io/chunk_cache.h"

#include <exception>
#include <new>
#include <string>
#include <utility>

namespace octoscope::io {

Result<ChunkCache::Data> ChunkCache::Get(uint64_t key, bool keep, const Decoder& decode) {
  std::promise<Result<Data>> promise;
  {
    std::unique_lock lock(mutex_);
    auto it = entries_.find(key);
    if (it != entries_.end()) {
      Entry& e = it->second;
      if (e.ready) lru_.splice(lru_.begin(), lru_, e.lru);  // Most recently used.
      std::shared_future<Result<Data>> future = e.future;
      lock.unlock();
      return future.get();  // Waits when another thread is still decoding it.
    }
    Entry e;
    e.future = promise.get_future().share();
    entries_.emplace(key, std::move(e));
  }

  // Decode outside the lock; nothing may escape without fulfilling the promise (waiters).
  Result<Data> result = InternalError("chunk decode did not run");
  try {
    result = decode();
  } catch (const std::bad_alloc&) {
    result = ResourceExhaustedError("out of memory decoding a chunk");
  } catch (const std::exception& e) {
    result = InternalError(std::string("decoding a chunk: ") + e.what());
  }
  promise.set_value(result);

  std::lock_guard lock(mutex_);
  ++decodes_;
  auto it = entries_.find(key);
  if (it == entries_.end()) return result;
  if (!result.ok() || !keep) {
    // Waiters hold the shared future; the entry itself is not worth keeping.
    entries_.erase(it);
    return result;
  }
  Entry& e = it->second;
  e.ready = true;
  e.bytes = *result ? (*result)->size() : 0;
  lru_.push_front(key);
  e.lru = lru_.begin();
  bytes_ += e.bytes;
  EvictLocked();
  return result;
}

void ChunkCache::MarkRead(uint64_t key, uint64_t first, uint64_t count, uint64_t total) {
  std::lock_guard lock(mutex_);
  auto it = entries_.find(key);
  if (it == entries_.end() || !it->second.ready) return;
  Entry& e = it->second;
  if (e.read.size() != total) {
    e.read.assign(total, false);
    e.read_count = 0;
  }
  for (uint64_t u = first; u < first + count && u < total; ++u) {
    if (!e.read[u]) {
      e.read[u] = true;
      ++e.read_count;
    }
  }
  if (e.read_count == total) EraseLocked(it);
}

void ChunkCache::EraseLocked(std::unordered_map<uint64_t, Entry>::iterator it) {
  if (it->second.ready) {
    bytes_ -= it->second.bytes;
    lru_.erase(it->second.lru);
  }
  entries_.erase(it);
}

void ChunkCache::EvictLocked() {
  // The least recently used go first; a chunk that alone exceeds the budget goes too (its reader
  // holds its own reference until it is done).
  while (bytes_ > budget_ && !lru_.empty()) EraseLocked(entries_.find(lru_.back()));
}

uint64_t ChunkCache::bytes() const {
  std::lock_guard lock(mutex_);
  return bytes_;
}

size_t ChunkCache::entries() const {
  std::lock_guard lock(mutex_);
  return entries_.size();
}

uint64_t ChunkCache::decodes() const {
  std::lock_guard lock(mutex_);
  return decodes_;
}

}  // namespace octoscope::io
