#include "render/bilinear_upsample.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

namespace octoscope::render {
namespace {

// Per output index: the two input indices and the weight of the second.
struct Tap {
  int i0 = 0;
  int i1 = 0;
  float w1 = 0;
};

std::vector<Tap> Taps(int in, int out) {
  std::vector<Tap> taps(out);
  const double ratio = static_cast<double>(in) / out;
  for (int i = 0; i < out; ++i) {
    // The input coordinate of the output pixel's centre, clamped to the outer pixel centres.
    const double s = std::clamp((i + 0.5) * ratio - 0.5, 0.0, static_cast<double>(in - 1));
    const int i0 = static_cast<int>(std::floor(s));
    taps[i] = {i0, std::min(i0 + 1, in - 1), static_cast<float>(s - i0)};
  }
  return taps;
}

}  // namespace

RenderImage BilinearUpsample(const RenderImage& image, int width, int height) {
  if (width == image.width && height == image.height) return image;
  const std::vector<Tap> xs = Taps(image.width, width);
  const std::vector<Tap> ys = Taps(image.height, height);
  RenderImage out;
  out.width = width;
  out.height = height;
  out.rgba.resize(static_cast<size_t>(width) * height * 4);
  const auto at = [&](int x, int y) {
    return image.rgba.data() + (static_cast<size_t>(y) * image.width + x) * 4;
  };
  for (int y = 0; y < height; ++y) {
    const Tap& ty = ys[y];
    float* row = out.rgba.data() + static_cast<size_t>(y) * width * 4;
    for (int x = 0; x < width; ++x) {
      const Tap& tx = xs[x];
      const float* a = at(tx.i0, ty.i0);
      const float* b = at(tx.i1, ty.i0);
      const float* c = at(tx.i0, ty.i1);
      const float* d = at(tx.i1, ty.i1);
      for (int k = 0; k < 4; ++k) {
        const float top = a[k] + tx.w1 * (b[k] - a[k]);
        const float bottom = c[k] + tx.w1 * (d[k] - c[k]);
        row[x * 4 + k] = top + ty.w1 * (bottom - top);
      }
    }
  }
  return out;
}

}  // namespace octoscope::render
