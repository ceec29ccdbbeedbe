// OpenOptions: what a user may say about how to open a volume (series, time point, resolution
// level, spacing overrides), the safety limits every reader enforces against lying headers, and
// the gate every reader passes for each file it touches.
//
// Thread safety: a plain value type.
#ifndef OCTOSCOPE_IO_OPEN_OPTIONS_H_
#define OCTOSCOPE_IO_OPEN_OPTIONS_H_

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "io/file_gate.h"
#include "io/raw_layout.h"
#include "io/zarr_metadata.h"
#include "util/result.h"

namespace octoscope::io {

struct OpenOptions {
  int series = 0;  // Which image/series of a multi-series file.
  int time = 0;    // Which time point.
  int level = 0;   // Which resolution level of a multiscale file (0 = finest).
  // Overrides the file's spacing per axis where set (micrometres).
  std::array<std::optional<double>, 3> spacing_um;
  // Refuses files whose single xy plane of one channel would exceed this (a lying header must not
  // size an allocation).
  uint64_t max_plane_bytes = uint64_t{4} << 30;
  // Parses the text of the Octoscope JSON raw sidecar `sidecar` (read through file_gate). Set by
  // app/ (protocol/ owns JSON); when unset, JSON sidecars are reported as unsupported.
  std::function<Result<RawLayout>(std::string_view text, const std::filesystem::path& sidecar)>
      parse_raw_sidecar;
  // Parse Zarr's JSON documents. Set by app/ (protocol/ owns JSON); when unset, OME-Zarr is
  // reported as unsupported.
  ZarrJsonParsers zarr_json;

  // Chunked formats (OME-Zarr, Imaris): refuses chunks whose decoded size exceeds this (each
  // decoding thread holds one), and keeps at most `chunk_cache_bytes` of decoded chunks for
  // slabs thinner than a chunk and channels sharing one.
  uint64_t max_chunk_bytes = uint64_t{1} << 30;
  uint64_t chunk_cache_bytes = uint64_t{512} << 20;
  // Threads decoding the chunks of one slab read, the reading thread included; 0: the hardware
  // concurrency (at most 16).
  int decode_threads = 0;
  // Called by OpenVolume once per warning of the volume it opened (VolumeInfo::warnings: what
  // the reader had to guess or ignore), right after opening, so a command can show it before a
  // long read. Unset: the warnings are only in info().
  std::function<void(const std::string& warning)> on_warning;
  // Every file a reader opens, stats or lists passes this gate: the server confines a dataset to
  // its own folder (FileGate::ForDataset); the default admits every path (the command-line tools).
  FileGate file_gate;
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OPEN_OPTIONS_H_
