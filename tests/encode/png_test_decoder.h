// A small, independent PNG reader for tests: checks the signature, every chunk's CRC-32
// (computed here with its own table, not zlib's crc32), the IHDR fields, and decodes 8-bit RGBA
// or RGB non-interlaced images (zlib `uncompress` + the five PNG filters). Used by the encoder
// tests and by the end-to-end `octoscope render` tests to read the images they produce.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_TESTS_ENCODE_PNG_TEST_DECODER_H_
#define OCTOSCOPE_TESTS_ENCODE_PNG_TEST_DECODER_H_

#include <zlib.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

namespace octoscope::testing {

struct DecodedPng {
  bool ok = false;
  std::string error;
  int width = 0;
  int height = 0;
  int channels = 0;                      // 4 (RGBA) or 3 (RGB).
  std::vector<uint8_t> pixels;           // width * height * channels.
  std::vector<std::string> chunk_types;  // In file order.

  // Component c of pixel (x, y). REQUIRES: ok, in range.
  int At(int x, int y, int c) const {
    return pixels[(static_cast<size_t>(y) * width + x) * channels + c];
  }
};

// CRC-32 (ISO 3309, polynomial 0xEDB88320), bitwise table built on first use.
inline uint32_t TestCrc32(const uint8_t* data, size_t size) {
  static const std::array<uint32_t, 256> table = [] {
    std::array<uint32_t, 256> t{};
    for (uint32_t n = 0; n < 256; ++n) {
      uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[n] = c;
    }
    return t;
  }();
  uint32_t c = 0xFFFFFFFFu;
  for (size_t i = 0; i < size; ++i) c = table[(c ^ data[i]) & 0xFF] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

inline uint32_t ReadBe32(const uint8_t* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | p[3];
}

inline DecodedPng DecodeTestPng(const std::vector<uint8_t>& file) {
  DecodedPng png;
  auto fail = [&png](std::string why) {
    png.ok = false;
    png.error = std::move(why);
    return png;
  };
  static constexpr uint8_t kSig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (file.size() < 8 || !std::equal(kSig, kSig + 8, file.begin())) return fail("bad signature");
  size_t at = 8;
  std::vector<uint8_t> idat;
  int bit_depth = 0, colour_type = -1, interlace = -1;
  bool seen_iend = false;
  while (at < file.size()) {
    if (file.size() - at < 12) return fail("truncated chunk header");
    const uint32_t length = ReadBe32(&file[at]);
    if (length > file.size() - at - 12) return fail("chunk longer than the file");
    const std::string type(reinterpret_cast<const char*>(&file[at + 4]), 4);
    const uint8_t* data = &file[at + 8];
    const uint32_t crc = ReadBe32(&file[at + 8 + length]);
    if (crc != TestCrc32(&file[at + 4], length + 4)) return fail("bad CRC in " + type);
    png.chunk_types.push_back(type);
    if (png.chunk_types.size() == 1 && type != "IHDR") return fail("first chunk is not IHDR");
    if (type == "IHDR") {
      if (length != 13) return fail("IHDR length");
      png.width = static_cast<int>(ReadBe32(data));
      png.height = static_cast<int>(ReadBe32(data + 4));
      bit_depth = data[8];
      colour_type = data[9];
      if (data[10] != 0 || data[11] != 0) return fail("compression/filter method not 0");
      interlace = data[12];
    } else if (type == "IDAT") {
      idat.insert(idat.end(), data, data + length);
    } else if (type == "IEND") {
      seen_iend = true;
      at += 12 + length;
      break;
    }
    at += 12 + length;
  }
  if (!seen_iend) return fail("no IEND");
  if (at != file.size()) return fail("bytes after IEND");
  if (bit_depth != 8 || (colour_type != 6 && colour_type != 2) || interlace != 0) {
    return fail("unsupported IHDR (depth/colour/interlace)");
  }
  if (png.width < 1 || png.height < 1) return fail("zero size");
  png.channels = colour_type == 6 ? 4 : 3;
  const size_t row_bytes = static_cast<size_t>(png.width) * png.channels;
  std::vector<uint8_t> raw((row_bytes + 1) * png.height);
  uLongf raw_size = static_cast<uLongf>(raw.size());
  if (uncompress(raw.data(), &raw_size, idat.data(), static_cast<uLong>(idat.size())) != Z_OK ||
      raw_size != raw.size()) {
    return fail("zlib stream does not hold exactly the rows");
  }
  png.pixels.resize(row_bytes * png.height);
  const size_t bpp = static_cast<size_t>(png.channels);
  for (int y = 0; y < png.height; ++y) {
    const uint8_t filter = raw[(row_bytes + 1) * y];
    const uint8_t* in = &raw[(row_bytes + 1) * y + 1];
    uint8_t* out = &png.pixels[row_bytes * y];
    const uint8_t* prior = y > 0 ? out - row_bytes : nullptr;
    for (size_t i = 0; i < row_bytes; ++i) {
      const int a = i >= bpp ? out[i - bpp] : 0;
      const int b = prior ? prior[i] : 0;
      const int c = (prior && i >= bpp) ? prior[i - bpp] : 0;
      int predictor = 0;
      switch (filter) {
        case 0:
          break;
        case 1:
          predictor = a;
          break;
        case 2:
          predictor = b;
          break;
        case 3:
          predictor = (a + b) / 2;
          break;
        case 4: {
          const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
          predictor = (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
          break;
        }
        default:
          return fail("bad filter type " + std::to_string(filter));
      }
      out[i] = static_cast<uint8_t>(in[i] + predictor);
    }
  }
  png.ok = true;
  return png;
}

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_ENCODE_PNG_TEST_DECODER_H_
