// ChunkedVolume: the VolumeSource of the chunked formats (OME-Zarr, Imaris). The file stores an
// N-dimensional array cut into a regular grid of chunks; one dimension each is x, y and
// (optionally) z, channel and time, any others have size 1. A ChunkReader (one per format) reads
// and decodes one chunk; ChunkedVolume turns slab requests into chunk reads:
//
// - Chunk-aligned: a slab (channel c, planes z0 .. z0+nz-1 of the selected time point) reads only
//   the chunks it touches: c's chunk along the channel axis, the time point's chunk, the chunks
//   of the z range, all chunks along y and x.
// - Parallel: the slab's chunks are decoded by several threads at once (decoding, not reading,
//   is the bottleneck of compressed data); each copies its part straight into the caller's
//   buffer (disjoint parts, no locking).
// - Cached: chunks a later read will need again (slabs thinner than the chunk depth, channels
//   stored in one chunk) stay in a bounded ChunkCache; absent chunks read as the fill value.
//
// Memory of a read: the slab, one decoded chunk per decoding thread, and the cache's budget.
// PreferredSlabPlanes() is the chunk depth along z.
//
// Thread safety: the source is thread-safe (see volume_source.h); ChunkReader::ReadChunk is
// called from several threads at once.
#ifndef OCTOSCOPE_IO_CHUNKED_VOLUME_H_
#define OCTOSCOPE_IO_CHUNKED_VOLUME_H_

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "io/volume_source.h"
#include "util/result.h"
#include "volume/volume_info.h"

namespace octoscope::io {

// Where the volume's axes lie in the stored array and how a decoded chunk is laid out.
// Invariants (checked by MakeChunkedVolume): shape, chunk and strides have one entry per
// dimension; chunk entries >= 1; strides address every element of a chunk inside
// ChunkElements(); x and y dims exist; the dims named are distinct.
struct ChunkLayout {
  std::vector<int64_t> shape;    // Array extent per dimension (chunks may reach beyond it).
  std::vector<int64_t> chunk;    // Chunk extent per dimension.
  std::vector<int64_t> strides;  // Element strides of a decoded chunk per dimension.
  int x_dim = -1, y_dim = -1, z_dim = -1, channel_dim = -1, time_dim = -1;  // -1: absent.

  uint64_t ChunkElements() const;
  // Strides of a chunk stored in C order over its dims permuted by `order` (stored dim k is
  // chunk dim order[k]); empty `order`: C order.
  static std::vector<int64_t> StridesFor(const std::vector<int64_t>& chunk,
                                         const std::vector<int>& order);
};

class ChunkReader {
 public:
  virtual ~ChunkReader() = default;
  // Decodes chunk `index` (one grid index per dimension) into `out` (ChunkElements() samples of
  // the volume's dtype, native byte order, laid out per ChunkLayout::strides). Returns false,
  // leaving `out` alone, when the file holds no such chunk (it reads as the fill value). Errors
  // name the file and the chunk. Thread-safe.
  virtual Result<bool> ReadChunk(std::span<const int64_t> index, std::span<std::byte> out) = 0;
};

struct ChunkedVolumeOptions {
  std::string name;          // The file or store, for messages.
  double fill_value = 0;     // Converted to the dtype (NaN stays NaN for floats).
  uint64_t cache_bytes = 0;  // ChunkCache budget.
  int threads = 0;           // Decoding threads per read; 0: hardware concurrency (<= 16).
};

// REQUIRES: `info` validated, its size/channels/time_points equal to the layout's extents (a
// dim absent counts 1), ChunkElements() * BytesPerSample(info.dtype) checked against the limit.
Result<std::unique_ptr<VolumeSource>> MakeChunkedVolume(volume::VolumeInfo info, ChunkLayout layout,
                                                        std::unique_ptr<ChunkReader> reader,
                                                        const ChunkedVolumeOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_CHUNKED_VOLUME_H_
