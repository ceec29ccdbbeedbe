// Voreen .vvd: the XML header that the Voreen volume renderer writes beside a raw data file
// (<VoreenData><Volumes><Volume><RawData filename= format= x= y= z=/> plus a <MetaData> block
// whose MetaItem "Spacing" gives the voxel pitch). See docs/formats.md.
//
// Voreen writes spacing without a unit; by Voreen's convention it is millimetres, so
// 0.015625 becomes 15.625 µm. Voreen writes raw data in the machine's (little-endian) byte order,
// channels (vector formats) are not supported.
//
// Thread safety: a pure function of the file.
#ifndef OCTOSCOPE_IO_VOREEN_VVD_H_
#define OCTOSCOPE_IO_VOREEN_VVD_H_

#include <filesystem>

#include "io/file_gate.h"
#include "io/raw_layout.h"
#include "util/result.h"

namespace octoscope::io {

// Reads (through `gate`) the first <Volume> of `vvd`. data_file is RawData@filename resolved
// against the .vvd's directory. Formats: uint8, uint16, int8, int16, uint32, int32, float, double.
// Errors: not XML, no RawData, a missing or non-positive size, an unsupported format, a bad
// spacing.
Result<RawLayout> ReadVoreenVvd(const std::filesystem::path& vvd,
                                const FileGate& gate = FileGate());

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_VOREEN_VVD_H_
