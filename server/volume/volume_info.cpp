#include "volume/volume_info.h"

#include <cmath>
#include <sstream>

#include "util/checked_math.h"

namespace octoscope::volume {

uint64_t VolumeInfo::VoxelBytes() const {
  return CheckedProduct({static_cast<uint64_t>(size[0]), static_cast<uint64_t>(size[1]),
                         static_cast<uint64_t>(size[2]), channels.size(), BytesPerSample(dtype)})
      .value_or(UINT64_MAX);
}

Status CheckChannelCount(int64_t channels) {
  if (channels >= 1 && channels <= kMaxChannels) return Status::Ok();
  if (channels < 1) return CorruptError(std::to_string(channels) + " channels");
  return ResourceExhaustedError(std::to_string(channels) + " channels, more than the " +
                                std::to_string(kMaxChannels) + " Octoscope supports");
}

Status VolumeInfo::Validate() const {
  for (int a = 0; a < 3; ++a) {
    if (size[a] < 1)
      return CorruptError("size along " + std::string(1, "xyz"[a]) + " is " +
                          std::to_string(size[a]));
    if (spacing_um[a] && !(std::isfinite(*spacing_um[a]) && *spacing_um[a] > 0)) {
      return CorruptError("spacing along " + std::string(1, "xyz"[a]) + " is not positive");
    }
  }
  if (channels.empty()) return CorruptError("no channels");
  OCTO_RETURN_IF_ERROR(CheckChannelCount(static_cast<int64_t>(channels.size())));
  if (series_count < 1 || series < 0 || series >= series_count) {
    return OutOfRangeError("series " + std::to_string(series) + " of " +
                           std::to_string(series_count));
  }
  if (time_points < 1 || time < 0 || time >= time_points) {
    return OutOfRangeError("time point " + std::to_string(time) + " of " +
                           std::to_string(time_points));
  }
  if (level_count < 1 || level < 0 || level >= level_count) {
    return OutOfRangeError("resolution level " + std::to_string(level) + " of " +
                           std::to_string(level_count));
  }
  for (const ChannelInfo& c : channels) {
    if (c.window &&
        !(std::isfinite(c.window->start) && std::isfinite(c.window->end) &&
          std::isfinite(c.window->min.value_or(0)) && std::isfinite(c.window->max.value_or(0)))) {
      return CorruptError("display window of channel \"" + c.name + "\" is not finite");
    }
  }
  if (VoxelBytes() == UINT64_MAX) return CorruptError("volume size overflows 64 bits");
  return Status::Ok();
}

std::string VolumeInfo::ToString() const {
  std::ostringstream out;
  out << format << " " << size[0] << "x" << size[1] << "x" << size[2] << " x" << channels.size()
      << "ch " << NumpyName(dtype);
  return out.str();
}

}  // namespace octoscope::volume
