#include "render/frame_buffers.h"

namespace octoscope::render {

uint64_t TotalBytes(const FrameBufferSizes& sizes) {
  uint64_t total = 0;
  for (uint64_t bytes : sizes) total += bytes;
  return total;
}

uint64_t FrameBuffers::CapacityAfter(uint64_t capacity, uint64_t wanted) {
  if (wanted == 0) return capacity;
  // Kept while large enough and not wastefully large.
  if (capacity >= wanted && capacity / kFrameBufferShrink <= wanted) return capacity;
  return wanted;
}

Status FrameBuffers::Reserve(const FrameBufferSizes& sizes) {
  for (size_t i = 0; i < sizes.size(); ++i) {
    const uint64_t after = CapacityAfter(capacity_[i], sizes[i]);
    if (after == capacity_[i] && buffers_[i]) continue;
    if (after == 0) continue;
    // The old buffer goes first: the device never holds both.
    buffers_[i].reset();
    capacity_[i] = 0;
    OCTO_ASSIGN_OR_RETURN(buffers_[i],
                          context_->CreateBuffer(CL_MEM_READ_WRITE, static_cast<size_t>(after)));
    capacity_[i] = after;
    ++allocations_;
  }
  return Status::Ok();
}

uint64_t FrameBuffers::BytesAfterReserve(const FrameBufferSizes& sizes) const {
  uint64_t total = 0;
  for (size_t i = 0; i < sizes.size(); ++i) total += CapacityAfter(capacity_[i], sizes[i]);
  return total;
}

void FrameBuffers::Release() {
  for (size_t i = 0; i < buffers_.size(); ++i) {
    buffers_[i].reset();
    capacity_[i] = 0;
  }
}

}  // namespace octoscope::render
