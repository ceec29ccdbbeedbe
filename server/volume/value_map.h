// ValueMap: the voxel-type policy. Octoscope stores every volume as uint8 or uint16 (bricks are
// small and GPU-friendly); a ValueMap is the affine map between those stored values and the
// file's own values, so users always see numbers in the file's units:
//
//   file_value = offset + scale * stored_value
//
//   file type        stored   map
//   uint8, uint16    same     identity (offset 0, scale 1)
//   int8             uint8    offset -128,   scale 1   (exact)
//   int16            uint16   offset -32768, scale 1   (exact)
//   uint32, int32,   uint16   the data range [lo, hi] onto [0, 65535]:
//   float32, float64          offset lo, scale (hi - lo) / 65535; NaN stores as 0,
//                             values outside [lo, hi] clamp (lossy; 65536 levels)
//
// The range for the wide types comes from a full pass over the data (`octoscope info --stats`
// computes it) or, for a live acquisition, from the caller.
//
// Thread safety: a plain value type; conversions are pure functions.
#ifndef OCTOSCOPE_VOLUME_VALUE_MAP_H_
#define OCTOSCOPE_VOLUME_VALUE_MAP_H_

#include <cstddef>
#include <span>
#include <string>

#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::volume {

struct ValueMap {
  DataType file_type = DataType::kUint16;
  DataType stored_type = DataType::kUint16;
  double offset = 0;
  double scale = 1;

  double ToFile(double stored) const { return offset + scale * stored; }
  // Rounds to the nearest stored value, clamped to the stored type; NaN gives 0.
  double ToStored(double file_value) const;
  bool exact() const;  // True when every file value survives the round trip.
  std::string ToString() const;
};

// The stored type the policy picks for `file_type`.
DataType StoredTypeFor(DataType file_type);

// The map for types whose map needs no data range (8/16-bit types).
// REQUIRES: BytesPerSample(file_type) <= 2.
ValueMap FixedValueMap(DataType file_type);

// The map for any type given the data range [lo, hi] in file units (ignored for 8/16-bit types).
// Errors when lo/hi are not finite or lo > hi.
Result<ValueMap> ValueMapForRange(DataType file_type, double lo, double hi);

// Converts `count` samples from `in` (file_type, native byte order) to `out` (stored_type).
// REQUIRES: in.size() == count * BytesPerSample(file_type),
//           out.size() == count * BytesPerSample(stored_type).
void ConvertToStored(const ValueMap& map, std::span<const std::byte> in, std::span<std::byte> out);

}  // namespace octoscope::volume

#endif  // OCTOSCOPE_VOLUME_VALUE_MAP_H_
