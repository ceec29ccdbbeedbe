#include "io/buffer_pool.h"

#include <utility>

namespace octoscope::io {

std::shared_ptr<BufferPool> BufferPool::Create(size_t max_free) {
  return std::shared_ptr<BufferPool>(new BufferPool(max_free));
}

std::shared_ptr<UninitializedBytes> BufferPool::Take(size_t size) {
  std::unique_ptr<UninitializedBytes> buffer;
  {
    std::lock_guard lock(mutex_);
    // The largest idle buffer: most likely to hold `size` without growing.
    size_t best = free_.size();
    for (size_t i = 0; i < free_.size(); ++i) {
      if (best == free_.size() || free_[i]->capacity() > free_[best]->capacity()) best = i;
    }
    if (best < free_.size()) {
      buffer = std::move(free_[best]);
      free_.erase(free_.begin() + static_cast<std::ptrdiff_t>(best));
    }
  }
  if (!buffer) buffer = std::make_unique<UninitializedBytes>();
  buffer->resize(size);
  std::weak_ptr<BufferPool> pool = weak_from_this();
  return std::shared_ptr<UninitializedBytes>(buffer.release(), [pool](UninitializedBytes* b) {
    if (std::shared_ptr<BufferPool> p = pool.lock()) {
      p->Give(b);
    } else {
      delete b;
    }
  });
}

void BufferPool::Give(UninitializedBytes* buffer) {
  std::unique_ptr<UninitializedBytes> owned(buffer);
  std::lock_guard lock(mutex_);
  if (free_.size() < max_free_) free_.push_back(std::move(owned));
}

}  // namespace octoscope::io
