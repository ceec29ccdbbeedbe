// Image encoding: turns a rendered RGBA float image into 8-bit pixels and those into PNG or JPEG
// files (bytes in memory), for `octoscope render` and the browser server.
//
// Pixel convention: the renderer's pixels are premultiplied RGBA floats in [0, 1]. ToRgba8 makes
// either kind of 8-bit pixel, each component round(clamp(v, 0, 1) * 255) (NaN counts as 0):
//  * AlphaMode::kStraight: colour divided by alpha (0 where alpha is 0) — what PNG requires
//    (colour type 6 stores straight, "unassociated" alpha), so any viewer composites it right;
//  * AlphaMode::kOverBlack: the colour kept premultiplied, i.e. composited over black (the usual
//    microscopy display) — what JPEG, which has no alpha, stores.
// EncodePng stores all four components as given (8 bits); EncodeJpeg stores R, G, B.
//
// Invariant of a valid Rgba8Image: 1 <= width, height <= kMaxEncodeSize and
// pixels.size() == width * height * 4 (row 0 at the top, x fastest, R G B A per pixel).
//
// Thread safety: pure functions (libturbojpeg handles are created per call); reentrant.
#ifndef OCTOSCOPE_ENCODE_IMAGE_ENCODER_H_
#define OCTOSCOPE_ENCODE_IMAGE_ENCODER_H_

#include <cstdint>
#include <string_view>
#include <vector>

#include "util/result.h"
#include "util/status.h"

namespace octoscope::encode {

// Largest width or height an encoder accepts (the renderer's limit, render/camera.h).
inline constexpr int kMaxEncodeSize = 16384;

struct Rgba8Image {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> pixels;  // width * height * 4 bytes.
};

// Checks the invariant above; kInvalidArgument naming what is wrong.
Status ValidateImage(const Rgba8Image& image);

enum class AlphaMode { kStraight, kOverBlack };

// Converts `width` x `height` premultiplied RGBA float pixels (4 floats each) as described above.
// REQUIRES: width, height >= 0; rgba_premultiplied points at width * height * 4 floats.
Rgba8Image ToRgba8(const float* rgba_premultiplied, int width, int height, AlphaMode mode);
// The same into `out`, reusing its pixel buffer (no allocation once it is large enough).
void ToRgba8Into(const float* rgba_premultiplied, int width, int height, AlphaMode mode,
                 Rgba8Image* out);

// A PNG file (RGBA, 8 bits per sample, non-interlaced; per row the filter among the five PNG
// filters with the smallest sum of absolute residuals; zlib-compressed IDAT chunks of at most
// 1 MiB each). Errors when the image is invalid.
Result<std::vector<uint8_t>> EncodePng(const Rgba8Image& image);

// A baseline JPEG file of the RGB components (4:4:4, so thin bright structures keep their
// colour). `quality` in [1, 100]. Errors when the image or the quality is invalid or libturbojpeg
// fails.
Result<std::vector<uint8_t>> EncodeJpeg(const Rgba8Image& image, int quality);

enum class ImageFormat { kPng, kJpeg };
// The format a file name asks for by its extension (".png"; ".jpg" or ".jpeg"; any case);
// kInvalidArgument otherwise.
Result<ImageFormat> ImageFormatFromPath(std::string_view path);

}  // namespace octoscope::encode

#endif  // OCTOSCOPE_ENCODE_IMAGE_ENCODER_H_
