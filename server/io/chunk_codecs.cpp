#include "io/chunk_codecs.h"

#include <blosc.h>
#include <libdeflate.h>
#include <lz4.h>
#include <zstd.h>
#include <zstd_errors.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <limits>
#include <memory>
#include <string>

namespace octoscope::io {
namespace {

std::string Num(uint64_t v) { return std::to_string(v); }

Status SizeMismatch(ChunkCodec codec, uint64_t got, uint64_t want) {
  return CorruptError(std::string(ChunkCodecName(codec)) + " chunk decodes to " + Num(got) +
                      " bytes, the chunk holds " + Num(want));
}

uint64_t LoadBigEndian(const std::byte* p, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | static_cast<uint8_t>(p[i]);
  return v;
}

uint32_t LoadLittle32(const std::byte* p) {
  return static_cast<uint32_t>(p[0]) | static_cast<uint32_t>(p[1]) << 8 |
         static_cast<uint32_t>(p[2]) << 16 | static_cast<uint32_t>(p[3]) << 24;
}

Status DecodeBlosc(std::span<const std::byte> in, std::span<std::byte> out) {
  if (in.size() < BLOSC_MIN_HEADER_LENGTH) {
    return CorruptError("blosc chunk is " + Num(in.size()) + " bytes, shorter than its header");
  }
  // The header's compressed size must lie inside the buffer (blosc reads up to it).
  size_t nbytes = 0;
  if (blosc_cbuffer_validate(in.data(), in.size(), &nbytes) != 0) {
    return CorruptError("blosc chunk header is invalid or claims more bytes than the chunk's " +
                        Num(in.size()));
  }
  if (nbytes != out.size()) return SizeMismatch(ChunkCodec::kBlosc, nbytes, out.size());
  if (out.empty()) return Status::Ok();
  const int n = blosc_decompress_ctx(in.data(), out.data(), out.size(), 1);
  if (n < 0 || static_cast<size_t>(n) != out.size()) {
    return CorruptError("blosc chunk does not decode (blosc error " + std::to_string(n) + ")");
  }
  return Status::Ok();
}

Status DecodeZstd(std::span<const std::byte> in, std::span<std::byte> out) {
  std::unique_ptr<ZSTD_DCtx, size_t (*)(ZSTD_DCtx*)> ctx(ZSTD_createDCtx(), ZSTD_freeDCtx);
  if (!ctx) return ResourceExhaustedError("zstd: cannot create a decoder");
  const size_t n = ZSTD_decompressDCtx(ctx.get(), out.data(), out.size(), in.data(), in.size());
  if (ZSTD_isError(n)) {
    if (ZSTD_getErrorCode(n) == ZSTD_error_dstSize_tooSmall) {
      return CorruptError("zstd chunk decodes to more than the chunk's " + Num(out.size()) +
                          " bytes");
    }
    return CorruptError(std::string("zstd chunk does not decode: ") + ZSTD_getErrorName(n));
  }
  if (n != out.size()) return SizeMismatch(ChunkCodec::kZstd, n, out.size());
  return Status::Ok();
}

// zlib and gzip through libdeflate (whole-buffer decoding, faster than zlib's inflate).
Status DecodeDeflate(ChunkCodec codec, std::span<const std::byte> in, std::span<std::byte> out) {
  std::unique_ptr<libdeflate_decompressor, void (*)(libdeflate_decompressor*)> d(
      libdeflate_alloc_decompressor(), libdeflate_free_decompressor);
  if (!d) return ResourceExhaustedError("deflate: cannot create a decoder");
  size_t actual = 0;
  size_t consumed = 0;
  libdeflate_result r;
  if (codec == ChunkCodec::kZlib) {
    r = libdeflate_zlib_decompress_ex(d.get(), in.data(), in.size(), out.data(), out.size(),
                                      &consumed, &actual);
  } else {
    r = libdeflate_gzip_decompress_ex(d.get(), in.data(), in.size(), out.data(), out.size(),
                                      &consumed, &actual);
  }
  const std::string name(ChunkCodecName(codec));
  if (r == LIBDEFLATE_INSUFFICIENT_SPACE) {
    return CorruptError(name + " chunk decodes to more than the chunk's " + Num(out.size()) +
                        " bytes");
  }
  if (r != LIBDEFLATE_SUCCESS) return CorruptError(name + " chunk does not decode (bad data)");
  if (actual != out.size()) return SizeMismatch(codec, actual, out.size());
  return Status::Ok();
}

Status DecodeNumcodecsLz4(std::span<const std::byte> in, std::span<std::byte> out) {
  if (in.size() < 4) return CorruptError("lz4 chunk is shorter than its 4-byte size header");
  const uint32_t declared = LoadLittle32(in.data());
  if (declared != out.size()) return SizeMismatch(ChunkCodec::kLz4, declared, out.size());
  if (out.size() > static_cast<size_t>(LZ4_MAX_INPUT_SIZE) ||
      in.size() - 4 > static_cast<size_t>(std::numeric_limits<int>::max())) {
    return UnsupportedError("lz4 chunk larger than LZ4's 2 GB limit");
  }
  const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(in.data() + 4),
                                    reinterpret_cast<char*>(out.data()),
                                    static_cast<int>(in.size() - 4), static_cast<int>(out.size()));
  if (n < 0) return CorruptError("lz4 chunk does not decode");
  if (static_cast<size_t>(n) != out.size()) return SizeMismatch(ChunkCodec::kLz4, n, out.size());
  return Status::Ok();
}

// HDF5 LZ4 filter (id 32004): header (uint64 BE decoded size, uint32 BE block size), then each
// block as uint32 BE compressed size + bytes; a block whose compressed size equals its decoded
// size is stored raw.
Status DecodeHdf5Lz4(std::span<const std::byte> in, std::span<std::byte> out) {
  if (in.size() < 12) return CorruptError("hdf5-lz4 chunk is shorter than its 12-byte header");
  const uint64_t declared = LoadBigEndian(in.data(), 8);
  uint64_t block = LoadBigEndian(in.data() + 8, 4);
  if (declared != out.size()) return SizeMismatch(ChunkCodec::kHdf5Lz4, declared, out.size());
  if (block == 0 && !out.empty()) return CorruptError("hdf5-lz4 chunk has block size 0");
  if (block > out.size()) block = out.size();
  size_t pos = 12;
  size_t done = 0;
  while (done < out.size()) {
    const size_t want = static_cast<size_t>(std::min<uint64_t>(block, out.size() - done));
    if (in.size() - pos < 4) return CorruptError("hdf5-lz4 chunk is truncated");
    const uint64_t csize = LoadBigEndian(in.data() + pos, 4);
    pos += 4;
    if (csize > in.size() - pos) return CorruptError("hdf5-lz4 chunk is truncated");
    if (csize == want) {
      std::memcpy(out.data() + done, in.data() + pos, want);
    } else {
      if (want > static_cast<size_t>(LZ4_MAX_INPUT_SIZE)) {
        return UnsupportedError("hdf5-lz4 block larger than LZ4's 2 GB limit");
      }
      const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(in.data() + pos),
                                        reinterpret_cast<char*>(out.data() + done),
                                        static_cast<int>(csize), static_cast<int>(want));
      if (n < 0 || static_cast<size_t>(n) != want) {
        return CorruptError("hdf5-lz4 block does not decode to its " + Num(want) + " bytes");
      }
    }
    pos += static_cast<size_t>(csize);
    done += want;
  }
  return Status::Ok();
}

// Slice-by-8 tables for the reflected Castagnoli polynomial, built at compile time.
constexpr std::array<std::array<uint32_t, 256>, 8> MakeCrc32cTables() {
  std::array<std::array<uint32_t, 256>, 8> t{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? (c >> 1) ^ 0x82F63B78u : c >> 1;
    t[0][i] = c;
  }
  for (uint32_t i = 0; i < 256; ++i) {
    for (int s = 1; s < 8; ++s) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xff];
  }
  return t;
}
constexpr auto kCrc32cTables = MakeCrc32cTables();

}  // namespace

std::string_view ChunkCodecName(ChunkCodec codec) {
  switch (codec) {
    case ChunkCodec::kBlosc:
      return "blosc";
    case ChunkCodec::kZstd:
      return "zstd";
    case ChunkCodec::kZlib:
      return "zlib";
    case ChunkCodec::kGzip:
      return "gzip";
    case ChunkCodec::kLz4:
      return "lz4";
    case ChunkCodec::kHdf5Lz4:
      return "hdf5-lz4";
    case ChunkCodec::kCrc32c:
      return "crc32c";
  }
  return "?";
}

Status DecodeChunk(ChunkCodec codec, std::span<const std::byte> in, std::span<std::byte> out) {
  switch (codec) {
    case ChunkCodec::kBlosc:
      return DecodeBlosc(in, out);
    case ChunkCodec::kZstd:
      return DecodeZstd(in, out);
    case ChunkCodec::kZlib:
    case ChunkCodec::kGzip:
      return DecodeDeflate(codec, in, out);
    case ChunkCodec::kLz4:
      return DecodeNumcodecsLz4(in, out);
    case ChunkCodec::kHdf5Lz4:
      return DecodeHdf5Lz4(in, out);
    case ChunkCodec::kCrc32c: {
      OCTO_RETURN_IF_ERROR(CheckCrc32cTrailer(in));
      if (in.size() - 4 != out.size()) return SizeMismatch(codec, in.size() - 4, out.size());
      if (!out.empty()) std::memcpy(out.data(), in.data(), out.size());
      return Status::Ok();
    }
  }
  return InternalError("unknown chunk codec");
}

Status CheckCrc32cTrailer(std::span<const std::byte> in) {
  if (in.size() < 4) return CorruptError("crc32c data is shorter than its checksum");
  if (Crc32c(in.first(in.size() - 4)) != LoadLittle32(in.data() + in.size() - 4)) {
    return CorruptError("crc32c checksum does not match the data");
  }
  return Status::Ok();
}

void Unshuffle(std::span<const std::byte> in, size_t element_size, std::span<std::byte> out) {
  if (in.empty()) return;  // memcpy of nothing may still not take the null data() of empties.
  const size_t n = in.size() / element_size;
  if (element_size <= 1 || n <= 1) {
    std::memcpy(out.data(), in.data(), in.size());
    return;
  }
  for (size_t b = 0; b < element_size; ++b) {
    const std::byte* src = in.data() + b * n;
    std::byte* dst = out.data() + b;
    for (size_t i = 0; i < n; ++i) dst[i * element_size] = src[i];
  }
  const size_t tail = in.size() - n * element_size;
  if (tail) std::memcpy(out.data() + n * element_size, in.data() + n * element_size, tail);
}

uint32_t Crc32c(std::span<const std::byte> data) {
  const auto& t = kCrc32cTables;
  uint32_t crc = 0xFFFFFFFFu;
  const std::byte* p = data.data();
  size_t n = data.size();
  while (n >= 8) {
    uint64_t word;
    std::memcpy(&word, p, 8);
    if constexpr (std::endian::native == std::endian::big) word = __builtin_bswap64(word);
    word ^= crc;
    crc = t[7][word & 0xff] ^ t[6][(word >> 8) & 0xff] ^ t[5][(word >> 16) & 0xff] ^
          t[4][(word >> 24) & 0xff] ^ t[3][(word >> 32) & 0xff] ^ t[2][(word >> 40) & 0xff] ^
          t[1][(word >> 48) & 0xff] ^ t[0][word >> 56];
    p += 8;
    n -= 8;
  }
  while (n--) crc = (crc >> 8) ^ t[0][(crc ^ static_cast<uint8_t>(*p++)) & 0xff];
  return crc ^ 0xFFFFFFFFu;
}

}  // namespace octoscope::io
