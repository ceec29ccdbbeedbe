// RawVolume: a VolumeSource over a headerless binary file ("raw") whose layout a sidecar describes
// (Octoscope's JSON sidecar or a Voreen .vvd; see io/raw_layout.h and docs/formats.md). Samples
// of any volume::DataType, either byte order, channels planar (one whole volume per channel) or
// interleaved (channel fastest), after an optional fixed-size header.
//
// Reads use pread on one file descriptor (no shared file offset), so ReadSlab is safe from many
// threads at once; interleaved files are de-interleaved through a bounded chunk buffer, never by
// reading the whole file. Planar files in native byte order say where each plane is stored
// (FindStoredPlane).
//
// Thread safety: the returned source is thread-safe (see volume_source.h).
#ifndef OCTOSCOPE_IO_RAW_VOLUME_H_
#define OCTOSCOPE_IO_RAW_VOLUME_H_

#include <memory>

#include "io/open_options.h"
#include "io/raw_layout.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// Opens `layout.data_file` (used as given: callers resolve sidecar-relative names) as a volume of
// format "raw". Errors: sizes or channels < 1, channel_names neither empty nor one per channel,
// byte counts that overflow, a plane above options.max_plane_bytes, a file shorter than
// header_bytes + voxel bytes (Corrupt, naming both numbers and the file), options.series or
// options.time other than 0. options.spacing_um overrides layout.spacing_um per axis.
Result<std::unique_ptr<VolumeSource>> OpenRawVolume(const RawLayout& layout,
                                                    const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_RAW_VOLUME_H_
