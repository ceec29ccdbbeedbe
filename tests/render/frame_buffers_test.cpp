// FrameBuffers (server/render/frame_buffers.h): reserved sizes, reuse from frame to frame,
// shrinking only when much too large, BytesAfterReserve agreeing with what Reserve then holds,
// and the renderers' BufferSizes agreeing with what their frames reserve.
#include "render/frame_buffers.h"

#include <gtest/gtest.h>

#include <cstdint>

#include "cl_test_env.h"
#include "render/slice_renderer.h"
#include "render/volume_renderer.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::SharedClTestEnv;

FrameBufferSizes Sizes(uint64_t image, uint64_t ray_next = 0) {
  FrameBufferSizes sizes{};
  sizes[static_cast<size_t>(FrameBuffer::kImage)] = image;
  sizes[static_cast<size_t>(FrameBuffer::kRayNext)] = ray_next;
  return sizes;
}

TEST(FrameBuffersTest, ReusesBuffersAndShrinksOnlyWhenMuchTooLarge) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  FrameBuffers buffers(SharedClTestEnv().context);
  EXPECT_EQ(buffers.bytes(), 0u);
  EXPECT_EQ(buffers.BytesAfterReserve(Sizes(1000, 200)), 1200u);
  ASSERT_TRUE(buffers.Reserve(Sizes(1000, 200)).ok());
  EXPECT_EQ(buffers.bytes(), 1200u);
  EXPECT_EQ(buffers.allocations(), 2u);
  const cl_mem image = buffers.get(FrameBuffer::kImage);
  ASSERT_NE(image, nullptr);
  // Same or somewhat smaller sizes, and unused buffers (size 0): nothing is reallocated.
  for (uint64_t size : {1000, 900, 250}) {
    EXPECT_EQ(buffers.BytesAfterReserve(Sizes(size)), 1200u);
    ASSERT_TRUE(buffers.Reserve(Sizes(size)).ok());
    EXPECT_EQ(buffers.get(FrameBuffer::kImage), image);
  }
  EXPECT_EQ(buffers.allocations(), 2u);
  // More than kFrameBufferShrink times too large: reallocated at the size asked.
  EXPECT_EQ(buffers.BytesAfterReserve(Sizes(249)), 449u);
  ASSERT_TRUE(buffers.Reserve(Sizes(249)).ok());
  EXPECT_EQ(buffers.bytes(), 449u);
  // Larger: reallocated.
  ASSERT_TRUE(buffers.Reserve(Sizes(5000)).ok());
  EXPECT_EQ(buffers.bytes(), 5200u);
  EXPECT_EQ(buffers.allocations(), 4u);
  buffers.Release();
  EXPECT_EQ(buffers.bytes(), 0u);
  EXPECT_EQ(buffers.get(FrameBuffer::kImage), nullptr);
  // More than the device allows in one buffer: kResourceExhausted, not an exception.
  const uint64_t too_large = SharedClTestEnv().context->device().max_alloc_bytes + 1;
  EXPECT_EQ(buffers.Reserve(Sizes(too_large)).code(), StatusCode::kResourceExhausted);
}

TEST(FrameBuffersTest, RequestSizesFollowTheImageAndTheMode) {
  RenderParams dvr = DefaultRenderParams(3, volume::DataType::kUint16, RenderMode::kDvr);
  RenderParams mip = DefaultRenderParams(3, volume::DataType::kUint16, RenderMode::kMip);
  const auto total = [](const FrameBufferSizes& sizes) { return TotalBytes(sizes); };
  // A full frame: the image (16 bytes per pixel) and small parameter buffers.
  const uint64_t full = total(VolumeRenderer::BufferSizes(FrameMode::kFullFrame, dvr, 100, 50));
  EXPECT_GE(full, 100u * 50 * 16);
  EXPECT_LT(full, 100u * 50 * 16 + 65536);
  // A DVR refinement: image, next sample, accumulated colour (36 bytes per pixel); MIP: image,
  // next sample and one extremum per enabled channel.
  const uint64_t dvr_refine = total(VolumeRenderer::BufferSizes(FrameMode::kRefine, dvr, 100, 50));
  EXPECT_GE(dvr_refine, 100u * 50 * 36);
  EXPECT_LT(dvr_refine, 100u * 50 * 36 + 65536);
  const uint64_t mip_refine = total(VolumeRenderer::BufferSizes(FrameMode::kRefine, mip, 100, 50));
  EXPECT_GE(mip_refine, 100u * 50 * (20 + 3 * 4));
  EXPECT_LT(mip_refine, 100u * 50 * (20 + 3 * 4) + 65536);
  // The service's default limit admits 4096^2 and refuses 16384^2.
  EXPECT_LE(total(VolumeRenderer::BufferSizes(FrameMode::kRefine, dvr, 4096, 4096)),
            uint64_t{1} << 30);
  EXPECT_GT(total(VolumeRenderer::BufferSizes(FrameMode::kRefine, dvr, 16384, 16384)),
            uint64_t{1} << 30);
  EXPECT_GT(total(VolumeRenderer::BufferSizes(FrameMode::kFullFrame, dvr, 16384, 16384)),
            uint64_t{1} << 30);
  SliceView slice;
  slice.width = 64;
  slice.height = 32;
  const uint64_t slice_bytes = total(SliceRenderer::BufferSizes(slice, dvr));
  EXPECT_GE(slice_bytes, 64u * 32 * 16);
  EXPECT_LT(slice_bytes, 64u * 32 * 16 + 65536);
}

}  // namespace
}  // namespace octoscope::render
