// Chunk codecs: each decoder against its library's own encoder (blosc with every inner compressor
// and shuffle, zstd, zlib, gzip, LZ4), framings built by hand (numcodecs LZ4, HDF5 LZ4), CRC32C's
// published check value; and every malformed input (truncated, wrong size, garbage) refused with
// Corrupt, never a crash. Cross-implementation checks live in the OME-Zarr and Imaris tests.
#include "io/chunk_codecs.h"

#include <blosc.h>
#include <gtest/gtest.h>
#include <lz4.h>
#include <zlib.h>
#include <zstd.h>

#include <cstring>
#include <random>
#include <vector>

namespace octoscope::io {
namespace {

std::vector<std::byte> Sample(size_t n) {
  std::vector<std::byte> v(n);
  std::mt19937 rng(7);
  for (size_t i = 0; i < n; ++i) {
    v[i] = static_cast<std::byte>(i % 300 < 150 ? (i / 7) & 0xff : rng() & 0xff);
  }
  return v;
}

std::vector<std::byte> Blosc(const std::vector<std::byte>& in, const char* cname, int shuffle,
                             size_t typesize) {
  std::vector<std::byte> out(in.size() + BLOSC_MAX_OVERHEAD);
  const int n = blosc_compress_ctx(5, shuffle, typesize, in.size(), in.data(), out.data(),
                                   out.size(), cname, 0, 1);
  EXPECT_GT(n, 0);
  out.resize(static_cast<size_t>(n));
  return out;
}

std::vector<std::byte> Zstd(const std::vector<std::byte>& in) {
  std::vector<std::byte> out(ZSTD_compressBound(in.size()));
  out.resize(ZSTD_compress(out.data(), out.size(), in.data(), in.size(), 3));
  return out;
}

std::vector<std::byte> Deflate(const std::vector<std::byte>& in, bool gzip) {
  z_stream z{};
  EXPECT_EQ(deflateInit2(&z, 6, Z_DEFLATED, gzip ? 31 : 15, 8, Z_DEFAULT_STRATEGY), Z_OK);
  std::vector<std::byte> out(deflateBound(&z, in.size()) + 32);
  z.next_in = reinterpret_cast<Bytef*>(const_cast<std::byte*>(in.data()));
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&z, Z_FINISH), Z_STREAM_END);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

std::vector<std::byte> Lz4Block(const std::vector<std::byte>& in) {
  std::vector<std::byte> out(LZ4_compressBound(static_cast<int>(in.size())));
  out.resize(static_cast<size_t>(LZ4_compress_default(
      reinterpret_cast<const char*>(in.data()), reinterpret_cast<char*>(out.data()),
      static_cast<int>(in.size()), static_cast<int>(out.size()))));
  return out;
}

void PutBig(std::vector<std::byte>& out, uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i) out.push_back(static_cast<std::byte>(v >> (8 * i)));
}

// Decoding `encoded` gives `plain`; truncations and a wrong output size are Corrupt.
void ExpectDecodes(ChunkCodec codec, const std::vector<std::byte>& encoded,
                   const std::vector<std::byte>& plain) {
  SCOPED_TRACE(std::string(ChunkCodecName(codec)));
  std::vector<std::byte> out(plain.size());
  Status s = DecodeChunk(codec, encoded, out);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(out, plain);
  std::vector<std::byte> bigger(plain.size() + 1), smaller(plain.size() - 1);
  EXPECT_EQ(DecodeChunk(codec, encoded, bigger).code(), StatusCode::kCorrupt);
  EXPECT_EQ(DecodeChunk(codec, encoded, smaller).code(), StatusCode::kCorrupt);
  for (size_t cut : {size_t{0}, size_t{3}, encoded.size() / 2, encoded.size() - 1}) {
    std::vector<std::byte> truncated(encoded.begin(), encoded.begin() + cut);
    EXPECT_EQ(DecodeChunk(codec, truncated, out).code(), StatusCode::kCorrupt) << "cut " << cut;
  }
}

TEST(ChunkCodecs, BloscEveryCompressorAndShuffle) {
  const std::vector<std::byte> plain = Sample(100000);
  for (const char* cname : {"lz4", "lz4hc", "blosclz", "zstd", "zlib"}) {
    for (int shuffle : {BLOSC_NOSHUFFLE, BLOSC_SHUFFLE, BLOSC_BITSHUFFLE}) {
      SCOPED_TRACE(std::string(cname) + " shuffle " + std::to_string(shuffle));
      ExpectDecodes(ChunkCodec::kBlosc, Blosc(plain, cname, shuffle, 2), plain);
    }
  }
}

TEST(ChunkCodecs, ZstdZlibGzipLz4) {
  const std::vector<std::byte> plain = Sample(70001);
  ExpectDecodes(ChunkCodec::kZstd, Zstd(plain), plain);
  ExpectDecodes(ChunkCodec::kZlib, Deflate(plain, false), plain);
  ExpectDecodes(ChunkCodec::kGzip, Deflate(plain, true), plain);
  const std::vector<std::byte> block = Lz4Block(plain);
  std::vector<std::byte> numcodecs_lz4(4 + block.size());
  for (int i = 0; i < 4; ++i) numcodecs_lz4[i] = static_cast<std::byte>(plain.size() >> (8 * i));
  std::memcpy(numcodecs_lz4.data() + 4, block.data(), block.size());
  ExpectDecodes(ChunkCodec::kLz4, numcodecs_lz4, plain);
}

TEST(ChunkCodecs, Hdf5Lz4BlocksCompressedAndRaw) {
  const std::vector<std::byte> plain = Sample(10000);
  std::vector<std::byte> framed;
  PutBig(framed, plain.size(), 8);
  PutBig(framed, 4096, 4);
  for (size_t at = 0; at < plain.size(); at += 4096) {
    std::vector<std::byte> piece(plain.begin() + at,
                                 plain.begin() + std::min(plain.size(), at + 4096));
    std::vector<std::byte> c = at == 4096 ? piece : Lz4Block(piece);  // Middle block raw.
    PutBig(framed, c.size(), 4);
    framed.insert(framed.end(), c.begin(), c.end());
  }
  ExpectDecodes(ChunkCodec::kHdf5Lz4, framed, plain);
}

TEST(ChunkCodecs, GarbageIsCorruptForEveryCodec) {
  std::vector<std::byte> garbage = Sample(5000);
  std::vector<std::byte> out(20000);
  for (ChunkCodec codec :
       {ChunkCodec::kBlosc, ChunkCodec::kZstd, ChunkCodec::kZlib, ChunkCodec::kGzip,
        ChunkCodec::kLz4, ChunkCodec::kHdf5Lz4, ChunkCodec::kCrc32c}) {
    EXPECT_EQ(DecodeChunk(codec, garbage, out).code(), StatusCode::kCorrupt)
        << ChunkCodecName(codec);
  }
}

TEST(ChunkCodecs, BloscHeaderClaimingMoreThanTheBufferIsCorrupt) {
  const std::vector<std::byte> plain = Sample(4096);
  std::vector<std::byte> enc = Blosc(plain, "lz4", 1, 2);
  // cbytes (bytes 12..15) larger than the chunk: blosc would read past the buffer.
  enc[12] = std::byte{0xff};
  enc[13] = std::byte{0xff};
  std::vector<std::byte> out(plain.size());
  EXPECT_EQ(DecodeChunk(ChunkCodec::kBlosc, enc, out).code(), StatusCode::kCorrupt);
}

TEST(ChunkCodecs, Crc32cCheckValueAndTrailer) {
  const char* check = "123456789";
  std::vector<std::byte> data(reinterpret_cast<const std::byte*>(check),
                              reinterpret_cast<const std::byte*>(check) + 9);
  EXPECT_EQ(Crc32c(data), 0xE3069283u);  // The published CRC-32C check value.
  EXPECT_EQ(Crc32c({}), 0u);
  std::vector<std::byte> with = data;
  for (int i = 0; i < 4; ++i) with.push_back(static_cast<std::byte>(0xE3069283u >> (8 * i)));
  EXPECT_TRUE(CheckCrc32cTrailer(with).ok());
  std::vector<std::byte> out(9);
  ASSERT_TRUE(DecodeChunk(ChunkCodec::kCrc32c, with, out).ok());
  EXPECT_EQ(out, data);
  with[2] ^= std::byte{1};
  EXPECT_EQ(CheckCrc32cTrailer(with).code(), StatusCode::kCorrupt);
  // Long inputs take the 8-byte path: it must agree with the byte-wise definition.
  std::vector<std::byte> long_data = Sample(1001);
  uint32_t crc = 0xFFFFFFFFu;
  for (std::byte b : long_data) {
    crc ^= static_cast<uint8_t>(b);
    for (int k = 0; k < 8; ++k) crc = (crc & 1) ? (crc >> 1) ^ 0x82F63B78u : crc >> 1;
  }
  EXPECT_EQ(Crc32c(long_data), crc ^ 0xFFFFFFFFu);
}

TEST(ChunkCodecs, UnshuffleInvertsHdf5Shuffle) {
  const std::vector<std::byte> plain = Sample(4 * 1000 + 3);
  std::vector<std::byte> shuffled(plain.size());
  const size_t n = plain.size() / 4;
  for (size_t i = 0; i < n; ++i) {
    for (size_t b = 0; b < 4; ++b) shuffled[b * n + i] = plain[i * 4 + b];
  }
  for (size_t t = n * 4; t < plain.size(); ++t) shuffled[t] = plain[t];
  std::vector<std::byte> out(plain.size());
  Unshuffle(shuffled, 4, out);
  EXPECT_EQ(out, plain);
}

}  // namespace
}  // namespace octoscope::io
