#include "io/memory_volume.h"

#include <cstring>

namespace octoscope::io {

Result<std::unique_ptr<MemoryVolume>> MemoryVolume::Create(const volume::VolumeInfo& info,
                                                           uint64_t max_bytes) {
  OCTO_RETURN_IF_ERROR(info.Validate());
  if (info.VoxelBytes() > max_bytes) {
    return ResourceExhaustedError("in-memory volume of " + std::to_string(info.VoxelBytes()) +
                                  " bytes exceeds the " + std::to_string(max_bytes) + " byte cap");
  }
  return std::unique_ptr<MemoryVolume>(new MemoryVolume(info));
}

MemoryVolume::MemoryVolume(const volume::VolumeInfo& info)
    : info_(info), data_(info.VoxelBytes()) {}

size_t MemoryVolume::Offset(int channel, int64_t x, int64_t y, int64_t z) const {
  size_t voxel =
      ((static_cast<size_t>(channel) * info_.size[2] + z) * info_.size[1] + y) * info_.size[0] + x;
  return voxel * volume::BytesPerSample(info_.dtype);
}

Status MemoryVolume::ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) {
  OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()));
  std::lock_guard lock(mutex_);
  std::memcpy(out.data(), &data_[Offset(channel, 0, 0, z0)], out.size());
  return Status::Ok();
}

Status MemoryVolume::WritePlane(int channel, int64_t z, std::span<const std::byte> plane) {
  OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z, 1, plane.size()));
  std::lock_guard lock(mutex_);
  std::memcpy(&data_[Offset(channel, 0, 0, z)], plane.data(), plane.size());
  return Status::Ok();
}

}  // namespace octoscope::io
