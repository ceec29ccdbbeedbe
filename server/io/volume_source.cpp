#include "io/volume_source.h"

#include <string>

namespace octoscope::io {

uint64_t VolumeSource::SlabBytes(int64_t nz) const {
  const volume::VolumeInfo& i = info();
  return i.PlaneVoxels() * static_cast<uint64_t>(nz) * volume::BytesPerSample(i.dtype);
}

Status CheckSlabRequest(const volume::VolumeInfo& info, int channel, int64_t z0, int64_t nz,
                        size_t out_size) {
  if (channel < 0 || channel >= info.channel_count()) {
    return OutOfRangeError("channel " + std::to_string(channel) + " of " +
                           std::to_string(info.channel_count()));
  }
  if (z0 < 0 || nz < 1 || z0 > info.size[2] - nz) {
    return OutOfRangeError("slab z " + std::to_string(z0) + "+" + std::to_string(nz) +
                           " outside 0.." + std::to_string(info.size[2]));
  }
  uint64_t want = info.PlaneVoxels() * static_cast<uint64_t>(nz) *
                  volume::BytesPerSample(info.dtype);
  if (out_size != want) {
    return InvalidArgumentError("slab buffer holds " + std::to_string(out_size) +
                                " bytes, the slab needs " + std::to_string(want));
  }
  return Status::Ok();
}

}  // namespace octoscope::io
