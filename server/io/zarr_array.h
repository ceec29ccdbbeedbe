// ZarrArray: one array of a Zarr directory store (v2 `.zarray`, v3 `zarr.json`): loading and
// checking its metadata, and a ChunkReader over its chunk files — chunk keys (`0.1.2`, `0/1/2`,
// `c/0/1/2`), absent chunk files (the fill value), the codec chain (compressor, crc32c, byte
// order, C/F order or transpose), and v3 sharding (the shard index read and checked, inner
// chunks read by their byte ranges).
//
// Thread safety: the ChunkReader is thread-safe (positioned reads, a locked shard-index cache).
#ifndef OCTOSCOPE_IO_ZARR_ARRAY_H_
#define OCTOSCOPE_IO_ZARR_ARRAY_H_

#include <filesystem>
#include <memory>
#include <string>

#include "io/chunked_volume.h"
#include "io/file_gate.h"
#include "io/open_options.h"
#include "io/zarr_metadata.h"
#include "util/result.h"

namespace octoscope::io {

// Zarr JSON documents larger than this are refused unread.
inline constexpr uint64_t kMaxZarrJsonBytes = uint64_t{16} << 20;
// Shard indexes larger than this (16 bytes per inner chunk) are refused.
inline constexpr uint64_t kMaxShardIndexBytes = uint64_t{64} << 20;

// Reads `dir/.zarray` (v2) or `dir/zarr.json` (v3) with `parsers.array` and checks what the
// values mean: dims 1 .. 32, chunk extents >= 1, shapes >= 0, the decoded chunk (inner chunk when
// sharded) at most `max_chunk_bytes`, codec chains and orders valid, shards divisible into inner
// chunks. Errors name the metadata file. Reads through `gate`.
Result<ZarrArrayMetadata> LoadZarrArray(const std::filesystem::path& dir,
                                        const ZarrJsonParsers& parsers, uint64_t max_chunk_bytes,
                                        const FileGate& gate = FileGate());

// The chunk grid the reader serves: the inner chunks when sharded, else the chunks.
const std::vector<int64_t>& ReadChunkShape(const ZarrArrayMetadata& meta);
// Element strides of a decoded chunk of that grid.
std::vector<int64_t> ReadChunkStrides(const ZarrArrayMetadata& meta);

// Chunk files are opened through `gate` (a chunk that leads out of it fails with its refusal).
// REQUIRES: `meta` came from LoadZarrArray.
std::unique_ptr<ChunkReader> MakeZarrChunkReader(const std::filesystem::path& dir,
                                                 ZarrArrayMetadata meta,
                                                 FileGate gate = FileGate());

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_ZARR_ARRAY_H_
