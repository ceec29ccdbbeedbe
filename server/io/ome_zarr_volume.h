// OME-Zarr (OME-NGFF 0.1 – 0.5 on Zarr v2 or v3 directory stores) as a VolumeSource.
//
// Accepted inputs: an image group (its `multiscales` attributes choose the levels, axes and
// scales; `omero` gives channel names, colours and display windows); a bioformats2raw.layout
// group (series 0, 1, … are its image sub-groups); one level's array inside an image (that
// level is read); a bare Zarr array without NGFF metadata (axes by the NGFF 0.1 convention: the
// last dims are z, y, x, preceded by c and t); or any of their metadata files. `--level N`
// (OpenOptions::level) picks a coarser level, `--series`, `--time` as usual. docs/formats.md
// specifies the mapping, what is refused, and why.
//
// Reading goes through ChunkedVolume (chunk-aligned slabs, several decoding threads, a bounded
// chunk cache); every size the metadata declares is checked before it sizes anything.
//
// Thread safety: OpenOmeZarr is thread-safe; the source is (see volume_source.h).
#ifndef OCTOSCOPE_IO_OME_ZARR_VOLUME_H_
#define OCTOSCOPE_IO_OME_ZARR_VOLUME_H_

#include <filesystem>
#include <memory>
#include <optional>

#include "io/open_options.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// True when `path` is (or is a metadata file of) a Zarr group or array: a folder holding
// `.zgroup`, `.zattrs`, `.zarray` or `zarr.json`, or one of those files. Looks through `gate`
// (and fails with its refusal).
Result<bool> LooksLikeZarr(const std::filesystem::path& path, const FileGate& gate);

// Opens the OME-Zarr image, level or array at `path`. Format "ome-zarr" (NGFF metadata) or "zarr"
// (a bare array).
Result<std::unique_ptr<VolumeSource>> OpenOmeZarr(const std::filesystem::path& path,
                                                  const OpenOptions& options);

// Micrometres per NGFF axis unit (the UDUNITS-2 length names of the NGFF specification, such as
// "micrometer" or "nanometer", and the usual symbols "um", "nm" …); nullopt for other units.
std::optional<double> MicrometresPerNgffUnit(std::string_view unit);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OME_ZARR_VOLUME_H_
