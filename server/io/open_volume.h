// OpenVolume: the one entry point that turns a user's path (a file, a master/companion file, a
// folder of slices, a raw file with sidecar) into a VolumeSource, choosing the reader by content
// and name. Bad input yields a Status naming the file and the problem, never a crash; input read
// other than as it describes itself (malformed OME-XML read as a plain TIFF) carries a warning.
//
// Thread safety: OpenVolume is thread-safe; the returned source is (see volume_source.h).
#ifndef OCTOSCOPE_IO_OPEN_VOLUME_H_
#define OCTOSCOPE_IO_OPEN_VOLUME_H_

#include <filesystem>
#include <memory>

#include "io/open_options.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

// Opens `path` with the reader its name or content calls for (docs/formats.md, "Choosing a
// reader"); OutOfRange when the file has no resolution level options.level. Reports the opened
// volume's warnings through options.on_warning.
Result<std::unique_ptr<VolumeSource>> OpenVolume(const std::filesystem::path& path,
                                                 const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OPEN_VOLUME_H_
