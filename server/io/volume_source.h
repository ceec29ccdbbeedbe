// VolumeSource: a multi-channel 3-D scan that can be read one z-slab of one channel at a time.
// Files (OME-TIFF, TIFF stacks, slice folders, raw) and live acquisitions implement it, so the
// octree builder consumes all of them the same way. Memory use of a read is bounded by the slab
// the caller asks for (plus at most one decoded plane or tile row of the file), never by the file.
//
// Thread safety: implementations are thread-safe: ReadSlab may be called from several threads at
// once (e.g. one builder thread per channel); info() never changes after construction.
#ifndef OCTOSCOPE_IO_VOLUME_SOURCE_H_
#define OCTOSCOPE_IO_VOLUME_SOURCE_H_

#include <cstddef>
#include <cstdint>
#include <span>

#include "util/status.h"
#include "volume/volume_info.h"

namespace octoscope::io {

class VolumeSource {
 public:
  virtual ~VolumeSource() = default;

  virtual const volume::VolumeInfo& info() const = 0;

  // Reads planes z0 .. z0+nz-1 of `channel` into `out`: x fastest, then y, then z; samples in
  // info().dtype, native byte order. On error `out` holds unspecified data.
  // REQUIRES: CheckSlabRequest(info(), channel, z0, nz, out.size()).ok()
  virtual Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) = 0;

  // Bytes of a slab of `nz` planes of one channel.
  uint64_t SlabBytes(int64_t nz) const;
};

// Validates a ReadSlab request; implementations call it first and return its error.
Status CheckSlabRequest(const volume::VolumeInfo& info, int channel, int64_t z0, int64_t nz,
                        size_t out_size);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_VOLUME_SOURCE_H_
