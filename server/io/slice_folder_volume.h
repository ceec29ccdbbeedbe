// SliceFolderVolume: a z-stack stored as a folder of 2-D TIFF files, one file per z plane
// (what light-sheet and whole-brain pipelines write). Files are .tif/.tiff (any case); hidden
// files and other files are ignored. Channels come either
//   - from sub-folders: when the folder itself holds no TIFF, each non-hidden sub-folder holding
//     TIFFs is one channel, named after the sub-folder, in natural order (ch0, ch1, ch2, ch10); or
//   - from a channel token in flat file names: a run of digits right after a marker "c", "ch",
//     "channel" or "w" (any case) that starts the name or follows a non-letter ("img_c0_z12",
//     "ch1-0005", "C01Z005", "scan_w2_z3"). A marked token is the channel token when it takes
//     at least two values and some value names more than one file (a marked number that alone
//     varies numbers the slices: "slice_c1", "slice_c2" is one channel). Every channel must then
//     hold the same names once the token is blanked out (else an error names a file without
//     counterpart); two such tokens are ambiguous (an error). Channels are ordered by the token's
//     value and named by it ("c0", "ch1", "C01", "w2"). Without one the folder is one unnamed
//     channel.
// z order is natural order of the file names (z2 < z10). Every channel must have the same number
// of slices and every file one full-resolution IFD (thumbnails are ignored) of the same width,
// height, samples per pixel and sample type; a file with several samples per pixel gives that
// many channels per folder channel.
// Spacing x/y comes from the first file (ImageJ unit= with the resolution tags, spacing= for z;
// else a centimetre ResolutionUnit; inch and unitless resolutions count as unknown).
// See docs/formats.md.
//
// Files are opened lazily through TiffFile and kept in a small LRU cache (at most
// kMaxOpenSliceFiles handles); reading a slab of nz planes decodes nz files.
//
// Thread safety: the returned source is thread-safe (see volume_source.h); the handle cache is
// guarded by a mutex and each TiffFile serializes its own decoding.
#ifndef OCTOSCOPE_IO_SLICE_FOLDER_VOLUME_H_
#define OCTOSCOPE_IO_SLICE_FOLDER_VOLUME_H_

#include <filesystem>
#include <memory>

#include "io/open_options.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// Open TIFF handles a slice-folder source keeps at most.
inline constexpr int kMaxOpenSliceFiles = 32;

// Opens the folder `dir` as a volume of format "slice-folder". Opens every file once to check
// that all slices agree. options.spacing_um overrides the files' spacing per axis. Errors: not a
// folder, no TIFF slices, channels with different slice counts, a file that differs from the
// first (naming it), a file with several pages, options.series or options.time other than 0.
Result<std::unique_ptr<VolumeSource>> OpenSliceFolder(const std::filesystem::path& dir,
                                                      const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_SLICE_FOLDER_VOLUME_H_
