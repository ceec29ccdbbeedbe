// MemoryVolume: a VolumeSource whose voxels live in RAM. The seam for tests of everything that
// consumes sources (stats, the octree builder), and a container for small generated volumes.
//
// Thread safety: thread-safe; ReadSlab and WritePlane may run concurrently (internal mutex).
#ifndef OCTOSCOPE_IO_MEMORY_VOLUME_H_
#define OCTOSCOPE_IO_MEMORY_VOLUME_H_

#include <cstddef>
#include <cstring>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

class MemoryVolume : public VolumeSource {
 public:
  // A zero-filled volume. Errors when `info` is invalid or larger than `max_bytes`.
  static Result<std::unique_ptr<MemoryVolume>> Create(const volume::VolumeInfo& info,
                                                      uint64_t max_bytes = uint64_t{1} << 32);

  const volume::VolumeInfo& info() const override { return info_; }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override;

  // Replaces plane z of `channel` (PlaneVoxels() samples of dtype, native order).
  Status WritePlane(int channel, int64_t z, std::span<const std::byte> plane);

  // Typed access for tests. REQUIRES: T matches info().dtype in size.
  template <typename T>
  void Set(int channel, int64_t x, int64_t y, int64_t z, T value) {
    std::lock_guard lock(mutex_);
    std::memcpy(&data_[Offset(channel, x, y, z)], &value, sizeof(T));
  }

 private:
  explicit MemoryVolume(const volume::VolumeInfo& info);
  size_t Offset(int channel, int64_t x, int64_t y, int64_t z) const;

  const volume::VolumeInfo info_;
  std::mutex mutex_;
  std::vector<std::byte> data_;  // GUARDED_BY(mutex_): channel-major, then z, y, x.
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_MEMORY_VOLUME_H_
