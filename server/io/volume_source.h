// VolumeSource: a multi-channel 3-D scan that can be read one z-slab of one channel at a time.
// Files (OME-TIFF, TIFF stacks, slice folders, raw) and live acquisitions implement it, so the
// octree builder consumes all of them the same way. Memory use of a read is bounded by the slab
// the caller asks for (plus at most one decoded plane or tile row of the file), never by the file.
//
// Sources whose file stores a plane exactly as ReadSlab would return it may also hand out a
// zero-copy view of it (MappedPlane), backed by a read-only memory mapping of the file.
//
// Thread safety: implementations are thread-safe: ReadSlab and MappedPlane may be called from
// several threads at once (e.g. one builder thread per channel); info() never changes after
// construction.
#ifndef OCTOSCOPE_IO_VOLUME_SOURCE_H_
#define OCTOSCOPE_IO_VOLUME_SOURCE_H_

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>
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

  // A zero-copy view of plane `z` of `channel`: exactly the SlabBytes(1) bytes ReadSlab(channel,
  // z, 1, ...) would produce (info().dtype, native byte order, aligned for the sample type), when
  // the file stores the plane that way; nullopt otherwise (and for out-of-range requests), in
  // which case callers use ReadSlab. The view stays valid while the source lives.
  // Caveat of every mapping: if another process truncates the file while it is mapped, touching
  // the lost pages raises SIGBUS. Sources map only files whose size they validated at open.
  virtual std::optional<std::span<const std::byte>> MappedPlane(int channel, int64_t z) const {
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

// A read-only, shared memory mapping of a whole file, created on first use, for sources that
// implement MappedPlane. Unmapped on destruction.
// Invariant: once mapped, the mapping covers exactly the `size` bytes given at construction.
// Thread safety: thread-safe; the first View maps the file (once, whatever the thread count).
class LazyFileMapping {
 public:
  // `fd`: a descriptor of the file, open at least until the first View returns; `size`: the file
  // size the caller validated (mapping past the file's end would give SIGBUS on access).
  LazyFileMapping(int fd, uint64_t size) : fd_(fd), size_(size) {}
  ~LazyFileMapping();
  LazyFileMapping(const LazyFileMapping&) = delete;
  LazyFileMapping& operator=(const LazyFileMapping&) = delete;

  // Bytes [offset, offset + length) of the file; nullopt when the range is not inside the file
  // or the file cannot be mapped. Advises the kernel to read the range ahead (MADV_WILLNEED), so
  // a file not yet in the page cache streams in while the caller works on an earlier view.
  std::optional<std::span<const std::byte>> View(uint64_t offset, uint64_t length) const;

 private:
  const int fd_;
  const uint64_t size_;
  mutable std::once_flag once_;
  mutable const std::byte* base_ = nullptr;  // Written once under once_; nullptr: not mappable.
};

// Validates a ReadSlab request; implementations call it first and return its error.
Status CheckSlabRequest(const volume::VolumeInfo& info, int channel, int64_t z0, int64_t nz,
                        size_t out_size);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_VOLUME_SOURCE_H_
