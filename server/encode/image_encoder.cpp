#include "encode/image_encoder.h"

#include <turbojpeg.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>

namespace octoscope::encode {
namespace {

constexpr std::array<uint8_t, 8> kPngSignature = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
constexpr size_t kMaxIdatBytes = size_t{1} << 20;

uint8_t ToByte(float v) {
  // NaN fails both comparisons and ends up 0.
  if (!(v > 0)) return 0;
  if (v >= 1) return 255;
  return static_cast<uint8_t>(std::lround(v * 255.0f));
}

void PutBigEndian32(std::vector<uint8_t>& out, uint32_t v) {
  out.push_back(static_cast<uint8_t>(v >> 24));
  out.push_back(static_cast<uint8_t>(v >> 16));
  out.push_back(static_cast<uint8_t>(v >> 8));
  out.push_back(static_cast<uint8_t>(v));
}

// A chunk: length, type, data, CRC-32 over type and data (PNG spec 5.3).
void PutChunk(std::vector<uint8_t>& out, const char type[4], const uint8_t* data, size_t size) {
  PutBigEndian32(out, static_cast<uint32_t>(size));
  const size_t type_at = out.size();
  out.insert(out.end(), type, type + 4);
  if (size > 0) out.insert(out.end(), data, data + size);
  const uLong crc = crc32(0L, out.data() + type_at, static_cast<uInt>(4 + size));
  PutBigEndian32(out, static_cast<uint32_t>(crc));
}

uint8_t Paeth(int a, int b, int c) {
  const int p = a + b - c;
  const int pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
  if (pa <= pb && pa <= pc) return static_cast<uint8_t>(a);
  if (pb <= pc) return static_cast<uint8_t>(b);
  return static_cast<uint8_t>(c);
}

// Filters one row with filter `type` (0 none, 1 sub, 2 up, 3 average, 4 Paeth) into `out`.
// `prior` is the previous unfiltered row (zeros for the first row).
void FilterRow(int type, const uint8_t* row, const uint8_t* prior, size_t bytes, uint8_t* out) {
  constexpr size_t kBpp = 4;
  for (size_t i = 0; i < bytes; ++i) {
    const int a = i >= kBpp ? row[i - kBpp] : 0;
    const int b = prior[i];
    const int c = i >= kBpp ? prior[i - kBpp] : 0;
    int predictor = 0;
    switch (type) {
      case 1:
        predictor = a;
        break;
      case 2:
        predictor = b;
        break;
      case 3:
        predictor = (a + b) / 2;
        break;
      case 4:
        predictor = Paeth(a, b, c);
        break;
      default:
        break;
    }
    out[i] = static_cast<uint8_t>(row[i] - predictor);
  }
}

// The usual heuristic (PNG spec 12.8): residuals read as signed bytes; smaller sums compress
// better.
uint64_t ResidualCost(const uint8_t* filtered, size_t bytes) {
  uint64_t sum = 0;
  for (size_t i = 0; i < bytes; ++i) sum += static_cast<uint64_t>(std::abs(int8_t(filtered[i])));
  return sum;
}

// Frees a libturbojpeg handle on every path.
struct TjHandle {
  tjhandle handle = nullptr;
  ~TjHandle() {
    if (handle) tjDestroy(handle);
  }
};

}  // namespace

Status ValidateImage(const Rgba8Image& image) {
  if (image.width < 1 || image.height < 1 || image.width > kMaxEncodeSize ||
      image.height > kMaxEncodeSize) {
    return InvalidArgumentError("image size " + std::to_string(image.width) + "x" +
                                std::to_string(image.height) + " is not in 1.." +
                                std::to_string(kMaxEncodeSize) + " per axis");
  }
  const size_t expected = static_cast<size_t>(image.width) * image.height * 4;
  if (image.pixels.size() != expected) {
    return InvalidArgumentError("image has " + std::to_string(image.pixels.size()) +
                                " bytes, expected " + std::to_string(expected) + " (RGBA)");
  }
  return Status::Ok();
}

Rgba8Image ToRgba8(const float* rgba_premultiplied, int width, int height, AlphaMode mode) {
  Rgba8Image image;
  ToRgba8Into(rgba_premultiplied, width, height, mode, &image);
  return image;
}

void ToRgba8Into(const float* rgba_premultiplied, int width, int height, AlphaMode mode,
                 Rgba8Image* out) {
  Rgba8Image& image = *out;
  image.width = width;
  image.height = height;
  const size_t count = static_cast<size_t>(std::max(width, 0)) * std::max(height, 0) * 4;
  image.pixels.resize(count);
  for (size_t i = 0; i < count; i += 4) {
    const float* p = rgba_premultiplied + i;
    // Premultiplied colour is already the colour over black; straight colour divides by alpha.
    const float alpha = p[3];
    const float scale =
        mode == AlphaMode::kOverBlack ? 1.0f : (alpha > 0 && alpha < 1 ? 1.0f / alpha : 1.0f);
    for (int k = 0; k < 3; ++k) image.pixels[i + k] = ToByte(p[k] * scale);
    image.pixels[i + 3] = ToByte(alpha);
  }
}

Result<std::vector<uint8_t>> EncodePng(const Rgba8Image& image) {
  OCTO_RETURN_IF_ERROR(ValidateImage(image));
  const size_t row_bytes = static_cast<size_t>(image.width) * 4;
  // Step 1: filter every row with the cheapest filter, each row prefixed by its filter byte.
  std::vector<uint8_t> raw((row_bytes + 1) * image.height);
  std::vector<uint8_t> zeros(row_bytes, 0), candidate(row_bytes);
  for (int y = 0; y < image.height; ++y) {
    const uint8_t* row = image.pixels.data() + row_bytes * y;
    const uint8_t* prior = y > 0 ? row - row_bytes : zeros.data();
    uint8_t* out = raw.data() + (row_bytes + 1) * y;
    uint64_t best_cost = UINT64_MAX;
    for (int type = 0; type <= 4; ++type) {
      FilterRow(type, row, prior, row_bytes, candidate.data());
      const uint64_t cost = ResidualCost(candidate.data(), row_bytes);
      if (cost < best_cost) {
        best_cost = cost;
        out[0] = static_cast<uint8_t>(type);
        std::memcpy(out + 1, candidate.data(), row_bytes);
      }
    }
  }
  // Step 2: one zlib stream over all filtered rows.
  uLongf compressed_size = compressBound(static_cast<uLong>(raw.size()));
  std::vector<uint8_t> compressed(compressed_size);
  const int z =
      compress2(compressed.data(), &compressed_size, raw.data(), static_cast<uLong>(raw.size()), 6);
  if (z != Z_OK) return InternalError("PNG: zlib compress2 failed (" + std::to_string(z) + ")");
  compressed.resize(compressed_size);
  // Step 3: signature, IHDR, the stream split over IDAT chunks, IEND.
  std::vector<uint8_t> png(kPngSignature.begin(), kPngSignature.end());
  png.reserve(compressed.size() + compressed.size() / kMaxIdatBytes * 12 + 64);
  std::vector<uint8_t> ihdr;
  PutBigEndian32(ihdr, static_cast<uint32_t>(image.width));
  PutBigEndian32(ihdr, static_cast<uint32_t>(image.height));
  ihdr.insert(ihdr.end(), {8, 6, 0, 0, 0});  // 8 bits, RGBA, deflate, adaptive, no interlace.
  PutChunk(png, "IHDR", ihdr.data(), ihdr.size());
  for (size_t at = 0; at < compressed.size(); at += kMaxIdatBytes) {
    PutChunk(png, "IDAT", compressed.data() + at, std::min(kMaxIdatBytes, compressed.size() - at));
  }
  PutChunk(png, "IEND", nullptr, 0);
  return png;
}

Result<std::vector<uint8_t>> EncodeJpeg(const Rgba8Image& image, int quality) {
  OCTO_RETURN_IF_ERROR(ValidateImage(image));
  if (quality < 1 || quality > 100) {
    return InvalidArgumentError("JPEG quality " + std::to_string(quality) + " is not in 1..100");
  }
  TjHandle tj;
  tj.handle = tjInitCompress();
  if (!tj.handle) return InternalError(std::string("JPEG: tjInitCompress: ") + tjGetErrorStr());
  unsigned char* jpeg = nullptr;
  unsigned long jpeg_size = 0;
  // RGBX: the alpha byte is skipped, i.e. the premultiplied colour over black is encoded.
  const int rc =
      tjCompress2(tj.handle, image.pixels.data(), image.width, image.width * 4, image.height,
                  TJPF_RGBX, &jpeg, &jpeg_size, TJSAMP_444, quality, TJFLAG_ACCURATEDCT);
  if (rc != 0) {
    const std::string message = tjGetErrorStr2(tj.handle);
    tjFree(jpeg);
    return InternalError("JPEG: tjCompress2: " + message);
  }
  std::vector<uint8_t> out(jpeg, jpeg + jpeg_size);
  tjFree(jpeg);
  return out;
}

Result<ImageFormat> ImageFormatFromPath(std::string_view path) {
  const size_t dot = path.rfind('.');
  const size_t slash = path.find_last_of('/');
  std::string ext;
  if (dot != std::string_view::npos && (slash == std::string_view::npos || dot > slash)) {
    for (char c : path.substr(dot + 1)) ext.push_back(static_cast<char>(std::tolower(c)));
  }
  if (ext == "png") return ImageFormat::kPng;
  if (ext == "jpg" || ext == "jpeg") return ImageFormat::kJpeg;
  return InvalidArgumentError("output file '" + std::string(path) +
                              "' must end in .png, .jpg or .jpeg");
}

}  // namespace octoscope::encode
