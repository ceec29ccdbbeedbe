// TIFF stacks as volume sources: a plain (multi-page) TIFF, an ImageJ hyperstack, or a ScanImage
// recording, read through TiffFile.
//
//  - Plain TIFF: every full-resolution page is one z plane (all pages must agree in size, sample
//    type and samples per pixel); samples per pixel (chunky or planar) become channels. Spacing
//    x/y comes from X/YResolution when the unit is centimetres; an inch unit is almost always a
//    meaningless 72 dpi default and is ignored. format "tiff".
//  - ImageJ (ImageDescription "ImageJ=…"): images/channels/slices/frames give the C, Z, T extents,
//    pages are ordered C fastest, then Z, then T; spacing from 1/XResolution and "spacing=" in
//    "unit=". ImageJ files > 4 GB hold a single IFD and the other images contiguously after the
//    first one's data; those are read with positioned reads. format "imagej-tiff".
//  - ScanImage (SI.* metadata in the Software tag or description): channels from
//    SI.hChannels.channelSave, slices from the stack manager, remaining frames are time points.
//    format "tiff".
//
// Thread safety: OpenTiffStack is thread-safe; the returned source is (see volume_source.h).
// Memory: a ReadSlab needs only the caller's slab plus TiffFile's one strip/tile of scratch.
// Stored planes: FindStoredPlane locates planes of uncompressed, native-order pages
// (TiffFile::StoredPlaneOffset) and the contiguous images of > 4 GB ImageJ files.
#ifndef OCTOSCOPE_IO_TIFF_STACK_VOLUME_H_
#define OCTOSCOPE_IO_TIFF_STACK_VOLUME_H_

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "io/open_options.h"
#include "io/spacing.h"  // MicrometresPerUnit and the spacing rules.
#include "io/tiff_file.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// The fields of an ImageJ ImageDescription that Octoscope uses. Counts are as written (0 when
// absent); lengths are in `unit`.
struct ImageJDescription {
  int64_t images = 0;
  int64_t channels = 0;
  int64_t slices = 0;
  int64_t frames = 0;
  bool hyperstack = false;
  std::optional<double> spacing;    // z step, in `unit`.
  std::optional<double> finterval;  // Seconds between frames.
  std::string unit;                 // As written, with "\u00B5" escapes decoded.
};

// Parses a description starting with "ImageJ="; nullopt for anything else.
std::optional<ImageJDescription> ParseImageJDescription(std::string_view text);

// Opens `path` as a TIFF stack (see above). options.series must be 0 (a stack has one series);
// options.time selects the time point; options.spacing_um overrides the file's spacing per axis.
Result<std::unique_ptr<VolumeSource>> OpenTiffStack(const std::filesystem::path& path,
                                                    const OpenOptions& options);

// The same for a TiffFile the caller has already opened (e.g. after sniffing its description);
// the file's own Limits apply, options.max_plane_bytes is not consulted again.
Result<std::unique_ptr<VolumeSource>> OpenTiffStack(std::unique_ptr<TiffFile> file,
                                                    const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_TIFF_STACK_VOLUME_H_
