// OME-TIFF reader: a VolumeSource for one series (OME Image) and one time point of an OME-TIFF
// data set — a single file, a multi-file set whose master file holds the full OME-XML, or a set
// described by a `.companion.ome` XML file.
//
// Opening resolves every plane (z, c) of the selected series and time point to (file, IFD,
// sample) following the OME-TIFF specification (TiffData IFD/FirstZ/FirstC/FirstT/PlaneCount and
// UUID@FileName; plane order given by DimensionOrder; Channel@SamplesPerPixel > 1 stores several
// consecutive channels as the samples of one page) and verifies each referenced page exists and
// matches Pixels (width, height, sample type), so ReadSlab never meets a structural surprise.
// Referenced TIFF files are opened lazily and at most kMaxOpenOmeTiffFiles stay open at once, so
// a series spread over thousands of files does not exhaust file descriptors.
// FindStoredPlane locates planes of uncompressed, native-order pages (TiffFile::StoredPlaneOffset);
// the StoredPlane it returns holds its file open while the caller reads it.
//
// Thread safety: the returned source is thread-safe (see volume_source.h); decoding goes through
// TiffFile, which serializes access per file.
#ifndef OCTOSCOPE_IO_OME_TIFF_VOLUME_H_
#define OCTOSCOPE_IO_OME_TIFF_VOLUME_H_

#include <cstddef>
#include <filesystem>
#include <memory>

#include "io/open_options.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// Most TIFF files one OME-TIFF source keeps open at once.
inline constexpr size_t kMaxOpenOmeTiffFiles = 32;

// Opens `path`: an OME-TIFF file (any member of a multi-file set: a BinaryOnly reference is
// followed to the file holding the metadata) or a `.companion.ome` XML file.
// Errors: NotFound (missing file), Unsupported (a TIFF without OME-XML, BinData pixels),
// OutOfRange (options.series / options.time outside the data), Corrupt (inconsistent metadata or
// missing pages), ResourceExhausted (a plane larger than options.max_plane_bytes). Every message
// names the file concerned.
Result<std::unique_ptr<VolumeSource>> OpenOmeTiff(const std::filesystem::path& path,
                                                  const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OME_TIFF_VOLUME_H_
