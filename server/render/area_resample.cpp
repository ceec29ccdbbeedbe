#include "render/area_resample.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace octoscope::render {
namespace {

// The input pixels [first, last] an output cell [i * ratio, (i + 1) * ratio) covers, with the
// covered length of each.
struct Span {
  int first = 0;
  std::vector<double> weights;
};

std::vector<Span> Spans(int in, int out) {
  const double ratio = static_cast<double>(in) / out;
  std::vector<Span> spans(out);
  for (int i = 0; i < out; ++i) {
    const double lo = i * ratio, hi = std::min<double>(in, (i + 1) * ratio);
    const int first = static_cast<int>(std::floor(lo));
    const int last = std::min(in - 1, static_cast<int>(std::ceil(hi)) - 1);
    spans[i].first = first;
    for (int p = first; p <= last; ++p) {
      // Overlap of input pixel [p, p + 1) with [lo, hi).
      const double w = std::min<double>(p + 1, hi) - std::max<double>(p, lo);
      spans[i].weights.push_back(std::max(0.0, w));
    }
  }
  return spans;
}

}  // namespace

RenderImage AreaResample(const RenderImage& image, int width, int height) {
  if (width == image.width && height == image.height) return image;
  const std::vector<Span> xs = Spans(image.width, width);
  const std::vector<Span> ys = Spans(image.height, height);
  // Columns first (one row of sums per output column), then rows.
  std::vector<double> columns(static_cast<size_t>(image.height) * width * 4);
  for (int y = 0; y < image.height; ++y) {
    const float* row = image.rgba.data() + static_cast<size_t>(y) * image.width * 4;
    for (int x = 0; x < width; ++x) {
      double sum[4] = {0, 0, 0, 0};
      const Span& span = xs[x];
      for (size_t k = 0; k < span.weights.size(); ++k) {
        const float* p = row + static_cast<size_t>(span.first + k) * 4;
        for (int c = 0; c < 4; ++c) sum[c] += span.weights[k] * p[c];
      }
      double* out = columns.data() + (static_cast<size_t>(y) * width + x) * 4;
      for (int c = 0; c < 4; ++c) out[c] = sum[c];
    }
  }
  RenderImage result;
  result.width = width;
  result.height = height;
  result.rgba.resize(static_cast<size_t>(width) * height * 4);
  const double area = (static_cast<double>(image.width) / width) * image.height / height;
  for (int y = 0; y < height; ++y) {
    const Span& span = ys[y];
    for (int x = 0; x < width; ++x) {
      double sum[4] = {0, 0, 0, 0};
      for (size_t k = 0; k < span.weights.size(); ++k) {
        const double* p = columns.data() + (static_cast<size_t>(span.first + k) * width + x) * 4;
        for (int c = 0; c < 4; ++c) sum[c] += span.weights[k] * p[c];
      }
      float* out = result.rgba.data() + (static_cast<size_t>(y) * width + x) * 4;
      for (int c = 0; c < 4; ++c) out[c] = static_cast<float>(sum[c] / area);
    }
  }
  return result;
}

}  // namespace octoscope::render
