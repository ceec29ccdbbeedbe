// VolumeInfo: what a volume source knows about its scan before any voxel is read — extent,
// channels, sample type, physical spacing, and which series/time point of the file it shows.
//
// Invariants (checked by Validate()): every size >= 1; 1 <= channels <= kMaxChannels; spacing,
// where known, finite and > 0; 0 <= series < series_count; 0 <= time < time_points;
// 0 <= level < level_count; display windows, where given, finite.
//
// Thread safety: a plain value type.
#ifndef OCTOSCOPE_VOLUME_VOLUME_INFO_H_
#define OCTOSCOPE_VOLUME_VOLUME_INFO_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "util/status.h"
#include "volume/data_type.h"

namespace octoscope::volume {

// The most channels a volume may have: the octree tracks which channels of a leaf are complete in
// a 64-bit mask and stores up to 64 channels per brick (octree::kMaxChannels), and the renderer
// activates at most 64. Readers refuse files declaring more before sizing anything by the count.
inline constexpr int kMaxChannels = 64;

// OK for 1..kMaxChannels; otherwise ResourceExhausted "<n> channels, more than the 64 Octoscope
// supports" (readers add the file and where the count comes from).
Status CheckChannelCount(int64_t channels);

// An sRGB display colour with alpha, 8 bits each.
struct Rgba {
  uint8_t r = 255, g = 255, b = 255, a = 255;
  bool operator==(const Rgba&) const = default;
};

// The display window a file recommends for a channel, in the file's own units (OME-Zarr
// `omero.channels[].window`, Imaris `ColorRange`): values <= start show black, >= end full
// colour. `min`/`max`: the range a window slider should span, where the file says.
struct DisplayWindow {
  double start = 0;
  double end = 0;
  std::optional<double> min, max;
  bool operator==(const DisplayWindow&) const = default;
};

struct ChannelInfo {
  std::string name;                                    // As the file names it; "" when unnamed.
  std::optional<Rgba> color;                           // As the file gives it; nullopt when none.
  std::optional<DisplayWindow> window = std::nullopt;  // As the file gives it, else none.
};

struct VolumeInfo {
  // "ome-tiff", "imagej-tiff", "tiff", "slice-folder", "raw", "ome-zarr", "zarr", "imaris".
  std::string format;
  std::array<int64_t, 3> size{1, 1, 1};  // Voxels along x, y, z.
  std::vector<ChannelInfo> channels;
  DataType dtype = DataType::kUint16;               // The file's sample type.
  std::array<std::optional<double>, 3> spacing_um;  // Voxel pitch in micrometres, x, y, z.
  int series_count = 1;
  int series = 0;
  int time_points = 1;
  int time = 0;
  int level_count = 1;  // Resolution levels the file stores (multiscale formats); 0 = finest.
  int level = 0;
  // What the reader had to guess or ignore, one sentence each naming the file (e.g. malformed
  // OME-XML read as a plain TIFF). Empty when the file was read as it describes itself. Shown to
  // the user (stderr, `info --json` "warnings") and kept for a server to show later.
  std::vector<std::string> warnings;

  int channel_count() const { return static_cast<int>(channels.size()); }
  // Voxels in one xy plane of one channel.
  uint64_t PlaneVoxels() const { return static_cast<uint64_t>(size[0]) * size[1]; }
  // Bytes of voxel data of the selected series and time point, all channels, in dtype.
  uint64_t VoxelBytes() const;

  // Checks the invariants above (plus overflow-free byte counts).
  Status Validate() const;
  std::string ToString() const;
};

}  // namespace octoscope::volume

#endif  // OCTOSCOPE_VOLUME_VOLUME_INFO_H_
