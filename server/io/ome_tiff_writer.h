// OME-TIFF writer: streams a VolumeSource into one OME-TIFF file, slab by slab, so memory stays
// bounded by OmeTiffWriteOptions::slab_bytes (at least one plane, two slabs in flight: the next
// slab is read on a helper thread while the current one is compressed and written).
//
// Layout: one IFD per (z, c) plane, single sample, in DimensionOrder XYZCT (z fastest, then c;
// IFD index = z + SizeZ * c). The first IFD's ImageDescription holds a complete OME-XML document
// (2016-06 schema) with the file's UUID, one Image/Pixels (SizeX/Y/Z/C, SizeT=1, Type, physical
// sizes in µm, channel names and colours) and a single TiffData covering all planes. Integer
// data uses the horizontal-differencing predictor with deflate/zstd/LZW.
//
// The file is written to "<path>.tmp" and renamed to `path` only after the last byte is written,
// so a crash or error never leaves a partial file under the final name (the .tmp is removed on
// error).
//
// Thread safety: WriteOmeTiff may run concurrently for different output paths; the source must be
// thread-safe (all VolumeSources are).
#ifndef OCTOSCOPE_IO_OME_TIFF_WRITER_H_
#define OCTOSCOPE_IO_OME_TIFF_WRITER_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include "io/volume_source.h"
#include "util/status.h"

namespace octoscope::io {

enum class TiffCompression { kNone, kDeflate, kZstd, kLzw };

// "none", "deflate", "zstd", "lzw" (case-insensitive); nullopt otherwise.
std::optional<TiffCompression> TiffCompressionFromName(std::string_view name);
std::string_view TiffCompressionName(TiffCompression compression);

enum class BigTiffMode {
  kAuto,  // BigTIFF when the uncompressed data would exceed ~3.9 GB.
  kAlways,
  kNever,  // Classic TIFF; writing fails if the file outgrows 4 GB.
};

struct OmeTiffWriteOptions {
  TiffCompression compression = TiffCompression::kDeflate;
  // 0: strips of about 256 KiB; else square tiles of this edge (a multiple of 16).
  uint32_t tile_size = 0;
  BigTiffMode big_tiff = BigTiffMode::kAuto;
  // Image@Name in the OME-XML; "" means the file name without ".ome.tif(f)".
  std::string image_name;
  // Target bytes per slab read from the source (rounded down to whole planes, at least one).
  uint64_t slab_bytes = uint64_t{32} << 20;
  // Called after each plane is written with (planes done, planes total).
  std::function<void(uint64_t, uint64_t)> progress;
};

// Writes `source` (its selected series and time point, all channels) to `path`. Errors name the
// path and the problem: kInvalidArgument for bad options, kUnsupported for a compression this
// libtiff lacks, kIoError when the file cannot be written, or the source's own read errors.
Status WriteOmeTiff(VolumeSource& source, const std::filesystem::path& path,
                    const OmeTiffWriteOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OME_TIFF_WRITER_H_
