#include "volume/value_map.h"

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>

namespace octoscope::volume {
namespace {

static_assert(std::endian::native == std::endian::little,
              "ConvertToStored's sign-bit flip assumes a little-endian host");

template <typename In, typename Out>
void ConvertTyped(const ValueMap& map, const std::byte* in, std::byte* out, size_t count) {
  const double inv_scale = 1.0 / map.scale;
  const double max_out = TypeMax(map.stored_type);
  for (size_t i = 0; i < count; ++i) {
    In v;
    std::memcpy(&v, in + i * sizeof(In), sizeof(In));
    double s = (static_cast<double>(v) - map.offset) * inv_scale;
    // NaN fails both comparisons and lands on 0; everything else clamps then rounds.
    s = s > 0 ? (s < max_out ? std::nearbyint(s) : max_out) : 0.0;
    Out o = static_cast<Out>(s);
    std::memcpy(out + i * sizeof(Out), &o, sizeof(Out));
  }
}

template <typename Out>
void ConvertFrom(const ValueMap& map, const std::byte* in, std::byte* out, size_t count) {
  switch (map.file_type) {
    case DataType::kUint8:
      return ConvertTyped<uint8_t, Out>(map, in, out, count);
    case DataType::kInt8:
      return ConvertTyped<int8_t, Out>(map, in, out, count);
    case DataType::kUint16:
      return ConvertTyped<uint16_t, Out>(map, in, out, count);
    case DataType::kInt16:
      return ConvertTyped<int16_t, Out>(map, in, out, count);
    case DataType::kUint32:
      return ConvertTyped<uint32_t, Out>(map, in, out, count);
    case DataType::kInt32:
      return ConvertTyped<int32_t, Out>(map, in, out, count);
    case DataType::kFloat32:
      return ConvertTyped<float, Out>(map, in, out, count);
    case DataType::kFloat64:
      return ConvertTyped<double, Out>(map, in, out, count);
  }
}

}  // namespace

DataType StoredTypeFor(DataType file_type) {
  return (file_type == DataType::kUint8 || file_type == DataType::kInt8) ? DataType::kUint8
                                                                         : DataType::kUint16;
}

ValueMap FixedValueMap(DataType file_type) {
  ValueMap map;
  map.file_type = file_type;
  map.stored_type = StoredTypeFor(file_type);
  map.offset = file_type == DataType::kInt8    ? -128.0
               : file_type == DataType::kInt16 ? -32768.0
                                               : 0.0;
  map.scale = 1.0;
  return map;
}

Result<ValueMap> ValueMapForRange(DataType file_type, double lo, double hi) {
  if (BytesPerSample(file_type) <= 2) return FixedValueMap(file_type);
  if (!std::isfinite(lo) || !std::isfinite(hi) || lo > hi) {
    return InvalidArgumentError("value range [" + std::to_string(lo) + ", " + std::to_string(hi) +
                                "] is not a finite interval");
  }
  ValueMap map;
  map.file_type = file_type;
  map.stored_type = DataType::kUint16;
  map.offset = lo;
  // A constant volume maps everything to 0 with a harmless unit scale.
  map.scale = hi > lo ? (hi - lo) / 65535.0 : 1.0;
  return map;
}

double ValueMap::ToStored(double file_value) const {
  double s = (file_value - offset) / scale;
  double max_out = TypeMax(stored_type);
  return s > 0 ? (s < max_out ? std::nearbyint(s) : max_out) : 0.0;
}

bool ValueMap::exact() const { return BytesPerSample(file_type) <= 2; }

std::string ValueMap::ToString() const {
  std::ostringstream out;
  out << NumpyName(file_type) << " = " << offset << " + " << scale << " * "
      << NumpyName(stored_type);
  return out.str();
}

void ConvertToStored(const ValueMap& map, std::span<const std::byte> in, std::span<std::byte> out) {
  // The common case (uint8/uint16 files) is the identity: a copy.
  if (map.file_type == map.stored_type && map.offset == 0 && map.scale == 1) {
    std::memcpy(out.data(), in.data(), in.size());
    return;
  }
  // Signed 8/16-bit: flipping the sign bit is exactly "+128" / "+32768".
  if (map.exact() && map.file_type != map.stored_type) {
    const size_t bytes = BytesPerSample(map.file_type);
    std::memcpy(out.data(), in.data(), in.size());
    for (size_t i = bytes - 1; i < out.size(); i += bytes) {
      out[i] ^= std::byte{0x80};  // The most significant byte in little-endian order.
    }
    return;
  }
  size_t count = in.size() / BytesPerSample(map.file_type);
  if (map.stored_type == DataType::kUint8) {
    ConvertFrom<uint8_t>(map, in.data(), out.data(), count);
  } else {
    ConvertFrom<uint16_t>(map, in.data(), out.data(), count);
  }
}

}  // namespace octoscope::volume
