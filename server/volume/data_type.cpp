#include "volume/data_type.h"

#include <limits>

#include "util/strings.h"

namespace octoscope::volume {

size_t BytesPerSample(DataType type) {
  switch (type) {
    case DataType::kUint8:
    case DataType::kInt8:
      return 1;
    case DataType::kUint16:
    case DataType::kInt16:
      return 2;
    case DataType::kUint32:
    case DataType::kInt32:
    case DataType::kFloat32:
      return 4;
    case DataType::kFloat64:
      return 8;
  }
  return 1;
}

std::string_view NumpyName(DataType type) {
  switch (type) {
    case DataType::kUint8:
      return "uint8";
    case DataType::kInt8:
      return "int8";
    case DataType::kUint16:
      return "uint16";
    case DataType::kInt16:
      return "int16";
    case DataType::kUint32:
      return "uint32";
    case DataType::kInt32:
      return "int32";
    case DataType::kFloat32:
      return "float32";
    case DataType::kFloat64:
      return "float64";
  }
  return "unknown";
}

std::optional<DataType> DataTypeFromNumpyName(std::string_view name) {
  for (DataType t : {DataType::kUint8, DataType::kInt8, DataType::kUint16, DataType::kInt16,
                     DataType::kUint32, DataType::kInt32, DataType::kFloat32, DataType::kFloat64}) {
    if (EqualsIgnoreCase(name, NumpyName(t))) return t;
  }
  return std::nullopt;
}

std::optional<DataType> DataTypeFromOmeName(std::string_view name) {
  if (EqualsIgnoreCase(name, "float")) return DataType::kFloat32;
  if (EqualsIgnoreCase(name, "double")) return DataType::kFloat64;
  if (EqualsIgnoreCase(name, "bit")) return std::nullopt;  // 1-bit masks: unsupported.
  return DataTypeFromNumpyName(name);
}

bool IsSigned(DataType type) {
  return type == DataType::kInt8 || type == DataType::kInt16 || type == DataType::kInt32 ||
         IsFloat(type);
}

bool IsFloat(DataType type) { return type == DataType::kFloat32 || type == DataType::kFloat64; }

double TypeMin(DataType type) {
  switch (type) {
    case DataType::kUint8:
    case DataType::kUint16:
    case DataType::kUint32:
      return 0;
    case DataType::kInt8:
      return std::numeric_limits<int8_t>::min();
    case DataType::kInt16:
      return std::numeric_limits<int16_t>::min();
    case DataType::kInt32:
      return std::numeric_limits<int32_t>::min();
    case DataType::kFloat32:
      return std::numeric_limits<float>::lowest();
    case DataType::kFloat64:
      return std::numeric_limits<double>::lowest();
  }
  return 0;
}

double TypeMax(DataType type) {
  switch (type) {
    case DataType::kUint8:
      return std::numeric_limits<uint8_t>::max();
    case DataType::kUint16:
      return std::numeric_limits<uint16_t>::max();
    case DataType::kUint32:
      return std::numeric_limits<uint32_t>::max();
    case DataType::kInt8:
      return std::numeric_limits<int8_t>::max();
    case DataType::kInt16:
      return std::numeric_limits<int16_t>::max();
    case DataType::kInt32:
      return std::numeric_limits<int32_t>::max();
    case DataType::kFloat32:
      return std::numeric_limits<float>::max();
    case DataType::kFloat64:
      return std::numeric_limits<double>::max();
  }
  return 0;
}

}  // namespace octoscope::volume
