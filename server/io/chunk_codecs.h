// Chunk codecs: the lossless byte codecs that chunked formats (OME-Zarr, Imaris/HDF5) compress
// their chunks with — blosc (every inner compressor, byte and bit shuffle), zstd, zlib, gzip,
// LZ4 (numcodecs' framing and HDF5's filter 32004 framing), HDF5's byte shuffle, and the CRC32C
// checksum of Zarr v3.
//
// Every decoder writes into a caller buffer of exactly the size the chunk must decode to, and
// fails (Corrupt, naming the codec and the problem) when the input is malformed, truncated, or
// decodes to any other size. Sizes that an encoded stream declares are compared with the caller's
// size, never used to allocate.
//
// Thread safety: pure functions; any number of threads may decode at once.
#ifndef OCTOSCOPE_IO_CHUNK_CODECS_H_
#define OCTOSCOPE_IO_CHUNK_CODECS_H_

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

#include "util/status.h"

namespace octoscope::io {

// The compressors a chunk's bytes may pass through (decoded in the reverse order of encoding).
enum class ChunkCodec {
  kBlosc,    // c-blosc 1.x frame (lz4, lz4hc, blosclz, zstd, zlib; no/byte/bit shuffle).
  kZstd,     // One or more zstd frames.
  kZlib,     // zlib-wrapped deflate (numcodecs "zlib", HDF5's deflate filter).
  kGzip,     // gzip member(s) (numcodecs "gzip", Zarr v3 "gzip").
  kLz4,      // numcodecs LZ4: little-endian uint32 decoded size, then one LZ4 block.
  kHdf5Lz4,  // HDF5 filter 32004: big-endian uint64 size, uint32 block size, sized blocks.
  kCrc32c,   // Zarr v3 crc32c: the payload followed by its little-endian CRC32C.
};

std::string_view ChunkCodecName(ChunkCodec codec);

// Decodes `in` with `codec` into `out`, which must be filled exactly.
// kCrc32c: `in` minus its 4-byte trailer is copied to `out` after the checksum is verified.
Status DecodeChunk(ChunkCodec codec, std::span<const std::byte> in, std::span<std::byte> out);

// Reverses HDF5's shuffle filter: `in` holds byte 0 of every element, then byte 1, ...; `out`
// gets the elements back. A tail of in.size() % element_size bytes is copied unchanged.
// REQUIRES: in.size() == out.size(); element_size >= 1.
void Unshuffle(std::span<const std::byte> in, size_t element_size, std::span<std::byte> out);

// CRC-32C (Castagnoli), as iSCSI, ext4 and Zarr v3 compute it.
uint32_t Crc32c(std::span<const std::byte> data);

// Checks that the last 4 bytes of `in` are the little-endian CRC32C of the rest (Zarr v3
// "crc32c" codec).
Status CheckCrc32cTrailer(std::span<const std::byte> in);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_CHUNK_CODECS_H_
