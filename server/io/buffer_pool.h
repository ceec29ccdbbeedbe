// BufferPool: recycles the byte buffers of a hot decoding loop, so that chunk after chunk reuses
// memory whose pages are already mapped instead of paying the kernel for fresh ones (a fresh 8 MB
// buffer costs 2048 page faults, each zeroing a page). Keeps at most `max_free` idle buffers.
//
// Thread safety: thread-safe. Buffers may outlive the pool (they are then simply freed).
#ifndef OCTOSCOPE_IO_BUFFER_POOL_H_
#define OCTOSCOPE_IO_BUFFER_POOL_H_

#include <cstddef>
#include <memory>
#include <mutex>
#include <vector>

#include "util/uninitialized_bytes.h"

namespace octoscope::io {

class BufferPool : public std::enable_shared_from_this<BufferPool> {
 public:
  // Use Create: buffers hold a weak reference back to the pool.
  static std::shared_ptr<BufferPool> Create(size_t max_free);

  // A buffer of `size` bytes with unspecified contents; it goes back to the pool when its last
  // reference is dropped.
  std::shared_ptr<UninitializedBytes> Take(size_t size);

 private:
  explicit BufferPool(size_t max_free) : max_free_(max_free) {}
  void Give(UninitializedBytes* buffer);

  const size_t max_free_;
  std::mutex mutex_;
  std::vector<std::unique_ptr<UninitializedBytes>> free_;  // GUARDED_BY(mutex_)
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_BUFFER_POOL_H_
