// FrameBuffers: the device buffers of one image stream (a view of the render service, or the
// frames of one renderer used on its own), kept from frame to frame. A frame first states what it
// needs — FrameBufferSizes, computed from its image size and parameters before anything is
// allocated (VolumeRenderer::BufferSizes, SliceRenderer::BufferSizes), so that a caller can admit
// or refuse it (RenderService) — then Reserve makes each buffer large enough, reallocating one only
// when it is too small or more than kFrameBufferShrink times too large. A view that renders frame
// after frame at about one size therefore allocates nothing after its first frame.
//
// Invariant: bytes() is the sum of the capacities of the buffers held; a buffer's capacity is the
// size it was last allocated with.
//
// Thread safety: NOT thread-safe; used by the render thread that owns the device queue. At most one
// frame or refinement uses a FrameBuffers at a time: starting a frame on it invalidates the device
// state of a refinement started earlier on the same buffers.
#ifndef OCTOSCOPE_RENDER_FRAME_BUFFERS_H_
#define OCTOSCOPE_RENDER_FRAME_BUFFERS_H_

#include <CL/cl.h>

#include <array>
#include <cstdint>

#include "render/cl_handles.h"
#include "render/device.h"
#include "util/status.h"

namespace octoscope::render {

enum class FrameBuffer {
  kImage,           // float4 per pixel.
  kRayNext,         // Refinement: uint per pixel (next sample index).
  kRayAccumulator,  // DVR refinement: float4 per pixel.
  kRayExtreme,      // MIP/MinIP refinement: float per pixel and enabled channel.
  kChannels,        // Per-channel parameters of the kernels.
  kLut,             // Transfer-function tables.
  kCounter,         // Counters written by the kernels.
  // Refinement: the 8x8 pixel tiles with unfinished rays, as two uint lists of at most one entry
  // per tile (a pass reads one and writes the other), and a uint stamp per tile.
  kRayTilesA,
  kRayTilesB,
  kRayTileStamp,
};
inline constexpr int kFrameBufferCount = 10;

// Bytes per FrameBuffer (indexed by its value); 0 = the frame does not use it.
using FrameBufferSizes = std::array<uint64_t, kFrameBufferCount>;
uint64_t TotalBytes(const FrameBufferSizes& sizes);

// A buffer more than this many times larger than a frame needs is reallocated smaller.
inline constexpr uint64_t kFrameBufferShrink = 4;

class FrameBuffers {
 public:
  // `context` must outlive the buffers.
  explicit FrameBuffers(const ComputeContext* context) : context_(context) {}
  FrameBuffers(const FrameBuffers&) = delete;
  FrameBuffers& operator=(const FrameBuffers&) = delete;

  // Makes every buffer with a non-zero size at least that large (contents undefined after a
  // reallocation); buffers of size 0 are kept as they are. A buffer to be replaced is released
  // before its successor is allocated. Errors: kResourceExhausted when the device cannot hold it
  // (the buffers already reserved stay).
  Status Reserve(const FrameBufferSizes& sizes);
  // What bytes() would be after Reserve(sizes), without allocating anything.
  uint64_t BytesAfterReserve(const FrameBufferSizes& sizes) const;

  // The buffer (nullptr when never reserved).
  cl_mem get(FrameBuffer which) const { return buffers_[Index(which)].get(); }
  const ClMem& handle(FrameBuffer which) const { return buffers_[Index(which)]; }

  // Device bytes held now, and buffers allocated since construction.
  uint64_t bytes() const { return TotalBytes(capacity_); }
  uint64_t allocations() const { return allocations_; }
  // Frees every buffer (bytes() == 0).
  void Release();

 private:
  static size_t Index(FrameBuffer which) { return static_cast<size_t>(which); }
  // The capacity a buffer of `capacity` bytes has after a reservation of `wanted` bytes.
  static uint64_t CapacityAfter(uint64_t capacity, uint64_t wanted);

  const ComputeContext* context_;
  std::array<ClMem, kFrameBufferCount> buffers_;
  FrameBufferSizes capacity_{};
  uint64_t allocations_ = 0;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_FRAME_BUFFERS_H_
