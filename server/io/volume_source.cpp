#include "io/volume_source.h"

#include <cstdint>
#include <string>
#include <utility>

namespace octoscope::io {
namespace {

// Forwards everything to the wrapped source; only its info (with the warnings added) is its own.
class WarnedSource final : public VolumeSource {
 public:
  WarnedSource(std::unique_ptr<VolumeSource> source, std::vector<std::string> warnings)
      : source_(std::move(source)), info_(source_->info()) {
    for (std::string& w : warnings) info_.warnings.push_back(std::move(w));
  }
  const volume::VolumeInfo& info() const override { return info_; }
  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    return source_->ReadSlab(channel, z0, nz, out);
  }
  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    return source_->FindStoredPlane(channel, z);
  }
  int64_t PreferredSlabPlanes() const override { return source_->PreferredSlabPlanes(); }

 private:
  const std::unique_ptr<VolumeSource> source_;
  volume::VolumeInfo info_;
};

}  // namespace

std::unique_ptr<VolumeSource> WithWarnings(std::unique_ptr<VolumeSource> source,
                                           std::vector<std::string> warnings) {
  if (warnings.empty()) return source;
  return std::make_unique<WarnedSource>(std::move(source), std::move(warnings));
}

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
  uint64_t want =
      info.PlaneVoxels() * static_cast<uint64_t>(nz) * volume::BytesPerSample(info.dtype);
  if (out_size != want) {
    return InvalidArgumentError("slab buffer holds " + std::to_string(out_size) +
                                " bytes, the slab needs " + std::to_string(want));
  }
  return Status::Ok();
}

}  // namespace octoscope::io
