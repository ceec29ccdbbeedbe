#include "io/raw_volume.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "io/spacing.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/file_reading.h"

namespace octoscope::io {
namespace {

// De-interleaving reads at most this many bytes of the file at a time.
constexpr uint64_t kInterleavedChunkBytes = uint64_t{4} << 20;

std::string Num(uint64_t v) { return std::to_string(v); }

// The raw data file: an owned read-only descriptor, read with positioned reads.
class RawFile final : public PositionedFile {
 public:
  RawFile(int fd, std::string name) : fd_(fd), name_(std::move(name)) {}
  int get() const { return fd_.get(); }

  // pread keeps no shared offset, so threads don't race.
  Status ReadBytes(uint64_t offset, std::span<std::byte> out) const override {
    return ReadFully(fd_.get(), offset, out, name_);
  }

 private:
  const ScopedFd fd_;
  const std::string name_;
};

class RawVolume final : public VolumeSource {
 public:
  // REQUIRES: `info` validated; the file held header_bytes + info.VoxelBytes() bytes at open.
  RawVolume(volume::VolumeInfo info, std::filesystem::path path, std::shared_ptr<RawFile> file,
            const RawLayout& layout)
      : info_(std::move(info)),
        path_(std::move(path)),
        file_(std::move(file)),
        header_bytes_(layout.header_bytes),
        interleaved_(layout.interleaved && layout.channels > 1),
        swap_(layout.big_endian != (std::endian::native == std::endian::big)) {}

  const volume::VolumeInfo& info() const override { return info_; }

  Status ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) override {
    OCTO_RETURN_IF_ERROR(
        CheckSlabRequest(info_, channel, z0, nz, out.size()).WithContext(path_.string()));
    const size_t bps = volume::BytesPerSample(info_.dtype);
    const uint64_t plane_voxels = info_.PlaneVoxels();
    if (!interleaved_) {
      // Planar: channel c is one whole volume at header + c * (volume bytes); the slab is one
      // contiguous run of the file.
      const uint64_t voxel = (static_cast<uint64_t>(channel) * info_.size[2] + z0) * plane_voxels;
      OCTO_RETURN_IF_ERROR(ReadAt(header_bytes_ + voxel * bps, out));
    } else {
      OCTO_RETURN_IF_ERROR(ReadInterleaved(channel, z0, nz, out));
    }
    if (swap_) SwapBytesInPlace(out, bps);
    return Status::Ok();
  }

  // Planar files in native byte order store each plane as one run of the file.
  std::optional<StoredPlane> FindStoredPlane(int channel, int64_t z) const override {
    if (channel < 0 || channel >= info_.channel_count() || z < 0 || z >= info_.size[2]) {
      return std::nullopt;
    }
    const uint64_t bps = volume::BytesPerSample(info_.dtype);
    if (interleaved_ || (swap_ && bps > 1)) return std::nullopt;
    const uint64_t plane_voxels = info_.PlaneVoxels();
    const uint64_t voxel = (static_cast<uint64_t>(channel) * info_.size[2] + z) * plane_voxels;
    return StoredPlane{file_, header_bytes_ + voxel * bps};  // Inside the file: checked at open.
  }

 private:
  // Interleaved: voxel v of channel c lies at header + (v * C + c) * bps. Reads the slab's span
  // of the file in bounded chunks of whole voxels and picks out this channel's samples.
  Status ReadInterleaved(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) {
    const size_t bps = volume::BytesPerSample(info_.dtype);
    const uint64_t stride = static_cast<uint64_t>(info_.channel_count()) * bps;
    const uint64_t first_voxel = static_cast<uint64_t>(z0) * info_.PlaneVoxels();
    const uint64_t voxels = static_cast<uint64_t>(nz) * info_.PlaneVoxels();
    const uint64_t chunk_voxels = std::max<uint64_t>(1, kInterleavedChunkBytes / stride);
    std::vector<std::byte> chunk(static_cast<size_t>(std::min(chunk_voxels, voxels) * stride));
    for (uint64_t done = 0; done < voxels;) {
      const uint64_t n = std::min(chunk_voxels, voxels - done);
      std::span<std::byte> buf(chunk.data(), static_cast<size_t>(n * stride));
      OCTO_RETURN_IF_ERROR(ReadAt(header_bytes_ + (first_voxel + done) * stride, buf));
      const std::byte* src = buf.data() + static_cast<size_t>(channel) * bps;
      std::byte* dst = out.data() + static_cast<size_t>(done * bps);
      for (uint64_t i = 0; i < n; ++i) {
        std::memcpy(dst + i * bps, src + i * stride, bps);
      }
      done += n;
    }
    return Status::Ok();
  }

  // Fills `out` from file offset `offset`; pread keeps no shared offset, so threads don't race.
  Status ReadAt(uint64_t offset, std::span<std::byte> out) const {
    return file_->ReadBytes(offset, out);
  }

  const volume::VolumeInfo info_;
  const std::filesystem::path path_;
  const std::shared_ptr<RawFile> file_;
  const uint64_t header_bytes_;
  const bool interleaved_;
  const bool swap_;
};

}  // namespace

// Layouts come from a file (a JSON sidecar, a Voreen .vvd), so impossible values in them are
// reported as corruption of that file, not as a caller's invalid argument.
Result<std::unique_ptr<VolumeSource>> OpenRawVolume(const RawLayout& layout,
                                                    const OpenOptions& options) {
  const std::string name = layout.data_file.string();
  for (int axis = 0; axis < 3; ++axis) {
    if (layout.size[axis] < 1) {
      return CorruptError(name + ": raw size along " + std::string(1, "xyz"[axis]) + " is " +
                          std::to_string(layout.size[axis]) + ", must be >= 1");
    }
  }
  if (layout.channels < 1) {
    return CorruptError(name + ": raw channel count is " + std::to_string(layout.channels) +
                        ", must be >= 1");
  }
  if (!layout.channel_names.empty() &&
      layout.channel_names.size() != static_cast<size_t>(layout.channels)) {
    return CorruptError(name + ": " + std::to_string(layout.channel_names.size()) +
                        " channel names for " + std::to_string(layout.channels) + " channels");
  }
  if (options.series != 0 || options.time != 0) {
    return OutOfRangeError(name +
                           ": a raw file holds one series and one time point (asked for "
                           "series " +
                           std::to_string(options.series) + ", time " +
                           std::to_string(options.time) + ")");
  }
  const uint64_t bps = volume::BytesPerSample(layout.dtype);
  std::optional<uint64_t> plane_bytes = CheckedProduct(
      {static_cast<uint64_t>(layout.size[0]), static_cast<uint64_t>(layout.size[1]), bps});
  std::optional<uint64_t> voxel_bytes =
      plane_bytes ? CheckedProduct({*plane_bytes, static_cast<uint64_t>(layout.size[2]),
                                    static_cast<uint64_t>(layout.channels)})
                  : std::nullopt;
  std::optional<uint64_t> need =
      voxel_bytes ? CheckedAdd(*voxel_bytes, layout.header_bytes) : std::nullopt;
  if (!need || *need > static_cast<uint64_t>(INT64_MAX)) {
    return CorruptError(name + ": raw layout " + std::to_string(layout.size[0]) + "x" +
                        std::to_string(layout.size[1]) + "x" + std::to_string(layout.size[2]) +
                        "x" + std::to_string(layout.channels) + " " +
                        std::string(volume::NumpyName(layout.dtype)) +
                        " overflows a 64-bit byte count");
  }
  if (*plane_bytes > options.max_plane_bytes) {
    return ResourceExhaustedError(name + ": one plane is " + Num(*plane_bytes) +
                                  " bytes, more than the limit of " + Num(options.max_plane_bytes));
  }

  Result<int> raw_fd = options.file_gate.OpenForReading(layout.data_file);
  if (!raw_fd.ok()) {
    if (raw_fd.status().code() == StatusCode::kNotFound) {
      return NotFoundError(name + ": raw data file not found");
    }
    return raw_fd.status();
  }
  auto file = std::make_shared<RawFile>(*raw_fd, name);
  struct stat st;
  if (::fstat(file->get(), &st) != 0) {
    return IoError(name + ": cannot stat raw data file: " + std::strerror(errno));
  }
  const uint64_t file_size = static_cast<uint64_t>(st.st_size);
  if (file_size < *need) {
    return CorruptError(name + ": raw file is truncated: it holds " + Num(file_size) +
                        " bytes, the layout needs " + Num(*need) + " (header " +
                        Num(layout.header_bytes) + " + voxels " + Num(*voxel_bytes) + ")");
  }

  volume::VolumeInfo info;
  info.format = "raw";
  info.size = layout.size;
  info.dtype = layout.dtype;
  info.channels.resize(static_cast<size_t>(layout.channels));
  for (size_t c = 0; c < layout.channel_names.size(); ++c) {
    info.channels[c].name = layout.channel_names[c];
  }
  info.spacing_um = layout.spacing_um;
  ApplySpacingOverrides(info, options);
  if (Status s = info.Validate(); !s.ok()) return s.WithContext(name);
  return std::unique_ptr<VolumeSource>(
      new RawVolume(std::move(info), layout.data_file, std::move(file), layout));
}

}  // namespace octoscope::io
