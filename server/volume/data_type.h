// DataType: the sample types Octoscope reads from files, and the two it stores internally.
//
// Thread safety: pure functions on an enum.
#ifndef OCTOSCOPE_VOLUME_DATA_TYPE_H_
#define OCTOSCOPE_VOLUME_DATA_TYPE_H_

#include <cstddef>
#include <optional>
#include <string_view>

namespace octoscope::volume {

enum class DataType {
  kUint8,
  kInt8,
  kUint16,
  kInt16,
  kUint32,
  kInt32,
  kFloat32,
  kFloat64,
};

// Bytes per sample: 1, 2, 4 or 8.
size_t BytesPerSample(DataType type);

// The name numpy uses ("uint16", "float32").
std::string_view NumpyName(DataType type);
std::optional<DataType> DataTypeFromNumpyName(std::string_view name);

// The OME-XML Pixels@Type spelling ("uint16", "float", "double").
std::optional<DataType> DataTypeFromOmeName(std::string_view name);

bool IsSigned(DataType type);
bool IsFloat(DataType type);

// The type's representable range (for floats, the finite range).
double TypeMin(DataType type);
double TypeMax(DataType type);

}  // namespace octoscope::volume

#endif  // OCTOSCOPE_VOLUME_DATA_TYPE_H_
