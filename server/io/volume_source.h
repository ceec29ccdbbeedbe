// VolumeSource: a multi-channel 3-D scan that can be read one z-slab of one channel at a time.
// Files (OME-TIFF, TIFF stacks, slice folders, raw, OME-Zarr, Imaris) and live acquisitions
// implement it, so the octree builder consumes all of them the same way. Memory use of a read is
// bounded by the slab the caller asks for (plus at most one decoded plane or tile row of the file,
// or the bounded chunk cache of a chunked format), never by the file.
//
// Sources whose file stores a plane exactly as ReadSlab would return it may also say where
// (FindStoredPlane), so a caller can stream it through a small buffer of its own with positioned
// reads. Files are never memory-mapped: an input may still be written (an acquisition in
// progress), and a mapped file that shrinks turns the next access into SIGBUS for the whole
// process, where a read returns an error ("the file is truncated").
//
// Thread safety: implementations are thread-safe: ReadSlab and FindStoredPlane may be called from
// several threads at once (e.g. one builder thread per channel); info() never changes after
// construction. PositionedFile reads are thread-safe.
#ifndef OCTOSCOPE_IO_VOLUME_SOURCE_H_
#define OCTOSCOPE_IO_VOLUME_SOURCE_H_

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "util/status.h"
#include "volume/volume_info.h"

namespace octoscope::io {

// An open file read with positioned reads (pread keeps no shared offset, so any number of threads
// may read at once). A file that shrinks after it was opened gives a Corrupt error naming it
// ("the file is truncated"), never a signal.
class PositionedFile {
 public:
  virtual ~PositionedFile() = default;
  // Reads out.size() bytes at `offset`. Errors name the file.
  virtual Status ReadBytes(uint64_t offset, std::span<std::byte> out) const = 0;
};

// A plane stored as is: bytes [offset, offset + SlabBytes(1)) of `file` are exactly what
// ReadSlab returns for it.
struct StoredPlane {
  std::shared_ptr<const PositionedFile> file;  // Keeps the file open while the caller reads.
  uint64_t offset = 0;
};

class VolumeSource {
 public:
  virtual ~VolumeSource() = default;

  virtual const volume::VolumeInfo& info() const = 0;

  // Reads planes z0 .. z0+nz-1 of `channel` into `out`: x fastest, then y, then z; samples in
  // info().dtype, native byte order. On error `out` holds unspecified data.
  // REQUIRES: CheckSlabRequest(info(), channel, z0, nz, out.size()).ok()
  virtual Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) = 0;

  // Where plane `z` of `channel` lies in a file when the file stores exactly the SlabBytes(1) bytes
  // ReadSlab(channel, z, 1, ...) would produce (info().dtype, native byte order) as one run;
  // nullopt otherwise (and for out-of-range requests), in which case callers use ReadSlab.
  virtual std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const {
    (void)channel;
    (void)z;
    return std::nullopt;
  }

  // Planes per slab at which reading is cheapest: formats stored in chunks along z (OME-Zarr,
  // Imaris) decode whole chunks, so slabs whose z0 and nz are multiples of this decode each chunk
  // once. 1 for formats stored plane by plane.
  virtual int64_t PreferredSlabPlanes() const { return 1; }

  // Bytes of a slab of `nz` planes of one channel.
  uint64_t SlabBytes(int64_t nz) const;
};

// `source` with `warnings` appended to its info().warnings; reads are forwarded unchanged. For
// readers that fall back to another reader and must say so.
std::unique_ptr<VolumeSource> WithWarnings(std::unique_ptr<VolumeSource> source,
                                           std::vector<std::string> warnings);

// Validates a ReadSlab request; implementations call it first and return its error.
Status CheckSlabRequest(const volume::VolumeInfo& info, int channel, int64_t z0, int64_t nz,
                        size_t out_size);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_VOLUME_SOURCE_H_
