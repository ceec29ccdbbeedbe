// TiffPlanes: decodes a TIFF held in memory — the body of a slab upload, a plane file a folder
// watcher read — into whole planes of an EXPECTED width, height and sample type, for streaming
// ingest. Strict: every full-resolution page (reduced-resolution copies such as thumbnails are
// skipped) must be exactly width x height with one sample per pixel of exactly the expected
// type, and the page count must be allowed; anything else is an error naming `name` and the page.
// Memory: the expectation bounds everything — the decoded planes are allocated only after the
// page count and sizes were checked against PlaneExpectation::max_bytes, and libtiff's own
// allocations are bounded by one plane (TiffFile::Limits). A compressed page that decodes to
// more or less than a plane is corrupt, never an overflow.
//
// Thread safety: a pure function of its inputs.
#ifndef OCTOSCOPE_IO_TIFF_PLANES_H_
#define OCTOSCOPE_IO_TIFF_PLANES_H_

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::io {

struct PlaneExpectation {
  int64_t width = 1;
  int64_t height = 1;
  volume::DataType dtype = volume::DataType::kUint16;
  // The exact number of planes the TIFF must hold; 0 = any number in 1..max_planes.
  int64_t planes = 0;
  int64_t max_planes = 1;
  // The most bytes the decoded planes may take (planes x width x height x sample bytes).
  uint64_t max_bytes = uint64_t{1} << 30;
};

struct DecodedPlanes {
  int64_t count = 0;
  // count planes, x fastest, in the expected type and the machine's byte order.
  std::vector<std::byte> samples;
};

// Decodes `tiff` (a whole TIFF or BigTIFF file, either byte order, any compression libtiff
// decodes). Errors: not a TIFF / corrupt (kCorrupt, kUnsupported), pages of another size or type
// (kInvalidArgument), a page count outside the expectation (kInvalidArgument), planes beyond
// max_bytes (kResourceExhausted). Messages start with `name`.
Result<DecodedPlanes> DecodeTiffPlanes(std::span<const std::byte> tiff, const std::string& name,
                                       const PlaneExpectation& expect);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_TIFF_PLANES_H_
