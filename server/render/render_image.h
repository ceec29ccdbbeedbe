// RenderImage and RenderStats: what a renderer produces (an RGBA float image) and what a CPU
// render did (counters), shared by the OpenCL renderers (volume_renderer.h, slice_renderer.h),
// the render service, the CPU reference renderer (reference_renderer.h) and the benchmarks.
//
// Thread safety: plain values; one object must not be modified by two threads at once.
#ifndef OCTOSCOPE_RENDER_RENDER_IMAGE_H_
#define OCTOSCOPE_RENDER_RENDER_IMAGE_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace octoscope::render {

// A rendered image: width * height RGBA pixels, row 0 at the top, 4 floats per pixel.
// Invariant (of every image a renderer returns): rgba.size() == width * height * 4.
struct RenderImage {
  int width = 0;
  int height = 0;
  std::vector<float> rgba;

  // REQUIRES: 0 <= x < width, 0 <= y < height.
  std::array<float, 4> Pixel(int x, int y) const {
    const size_t i = (static_cast<size_t>(y) * width + x) * 4;
    return {rgba[i], rgba[i + 1], rgba[i + 2], rgba[i + 3]};
  }
};

// What a CPU render did, for tests and benchmarks.
struct RenderStats {
  uint64_t rays = 0;              // Pixels.
  uint64_t rays_hit = 0;          // Rays whose clipped interval through the box is not empty.
  uint64_t steps = 0;             // Sample positions visited (none when no channel is enabled).
  uint64_t early_terminated = 0;  // DVR rays stopped by kEarlyTerminationAlpha.
  std::vector<uint64_t> channel_samples;  // Volume reads per channel (trilinear lookups).
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_RENDER_IMAGE_H_
