// Imaris `.ims` (HDF5) as a VolumeSource.
//
// Layout read: `/DataSet/ResolutionLevel L/TimePoint T/Channel C/Data`, one 3-D (z, y, x) dataset
// per channel; metadata from `/DataSetInfo/Image` (X, Y, Z, ExtMin0..2, ExtMax0..2, Unit) and
// `/DataSetInfo/Channel C` (Name, Color "r g b", ColorRange "lo hi"), attributes stored as arrays
// of single characters (as Imaris writes them) or as ordinary strings or numbers. Data arrays
// padded beyond the image size (Imaris pads to its block size) are cropped to the image; each
// level's size comes from its `ImageSizeX/Y/Z` channel attributes. `--level N` picks resolution
// level N, `--time T` a time point. docs/formats.md has the details.
//
// Reading goes through ChunkedVolume. Chunks whose filters are deflate, shuffle and/or LZ4
// (filter 32004; the filters Imaris writes) are fetched raw (H5Dread_chunk) and decoded by our
// codecs on several threads; other filters (Fletcher32, szip, scale-offset, …) and contiguous
// datasets are read through HDF5 itself (H5Dread of one chunk at a time, serialised by HDF5's
// lock). HDF5 never prints to the terminal: its errors come back as Status (io/hdf5_call.h).
//
// Thread safety: OpenImaris is thread-safe; the source is (see volume_source.h).
#ifndef OCTOSCOPE_IO_IMS_VOLUME_H_
#define OCTOSCOPE_IO_IMS_VOLUME_H_

#include <filesystem>
#include <memory>

#include "io/file_gate.h"
#include "io/open_options.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// True when the file starts with the HDF5 signature (at byte 0, or after a user block at 512,
// 1024, 2048, … bytes); false also when `gate` refuses it.
bool HasHdf5Signature(const std::filesystem::path& path, const FileGate& gate = FileGate());

// Opens an Imaris file. Format "imaris". Under a confined options.file_gate, external links and
// data stored in other files (external storage, virtual datasets) are refused as the gate refuses
// a path.
Result<std::unique_ptr<VolumeSource>> OpenImaris(const std::filesystem::path& path,
                                                 const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_IMS_VOLUME_H_
