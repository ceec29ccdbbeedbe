#include "io/voreen_vvd.h"

#include <cmath>
#include <cstdint>
#include <pugixml.hpp>
#include <string>
#include <utility>

#include "util/strings.h"

namespace octoscope::io {
namespace {

// A .vvd is a small XML header (with a preview image, some tens of KiB); anything bigger is
// not one.
constexpr uint64_t kMaxVvdBytes = uint64_t{16} << 20;

// Voreen's spacing is in millimetres.
constexpr double kMicrometresPerVoreenUnit = 1000.0;

Result<int64_t> SizeAttribute(const std::string& name, const pugi::xml_node& raw, const char* key) {
  pugi::xml_attribute attr = raw.attribute(key);
  if (!attr) return CorruptError(name + ": RawData has no " + key + " attribute");
  std::optional<int64_t> v = ParseInt64(attr.value());
  if (!v || *v < 1) {
    return CorruptError(name + ": RawData@" + key + " is \"" + Printable(attr.value()) +
                        "\", not a positive integer");
  }
  return *v;
}

// Voreen's scalar format names: the OME-XML spellings ("uint16", "float", "double"; numpy's
// "float32" is accepted too). Vector formats such as "Vector3(uint8)" are not supported.
std::optional<volume::DataType> VoreenFormat(std::string_view format) {
  return volume::DataTypeFromOmeName(format);
}

}  // namespace

Result<RawLayout> ReadVoreenVvd(const std::filesystem::path& vvd, const FileGate& gate) {
  const std::string name = vvd.string();
  OCTO_ASSIGN_OR_RETURN(const std::string text, gate.ReadSmallFile(vvd, kMaxVvdBytes));

  pugi::xml_document doc;
  pugi::xml_parse_result parsed = doc.load_buffer(text.data(), text.size());
  if (!parsed) {
    return CorruptError(name + ": not valid XML (" + parsed.description() + " at byte " +
                        std::to_string(parsed.offset) + ")");
  }
  pugi::xml_node volume = doc.child("VoreenData").child("Volumes").child("Volume");
  if (!volume) return CorruptError(name + ": no VoreenData/Volumes/Volume element");
  pugi::xml_node raw = volume.child("RawData");
  if (!raw) return CorruptError(name + ": the Volume has no RawData element");

  RawLayout layout;
  const std::string file_name = raw.attribute("filename").value();
  if (file_name.empty()) return CorruptError(name + ": RawData has no filename");
  layout.data_file = vvd.parent_path() / std::filesystem::path(file_name);
  const char* keys[3] = {"x", "y", "z"};
  for (int axis = 0; axis < 3; ++axis) {
    OCTO_ASSIGN_OR_RETURN(layout.size[axis], SizeAttribute(name, raw, keys[axis]));
  }
  const std::string format = raw.attribute("format").value();
  std::optional<volume::DataType> dtype = VoreenFormat(format);
  if (!dtype) {
    return UnsupportedError(name + ": RawData format \"" + Printable(format) +
                            "\" is not supported (uint8, uint16, int8, int16, uint32, int32, "
                            "float, double)");
  }
  layout.dtype = *dtype;
  layout.channels = 1;
  layout.big_endian = false;
  layout.header_bytes = 0;

  for (pugi::xml_node item : volume.child("MetaData").children("MetaItem")) {
    if (std::string_view(item.attribute("name").value()) != "Spacing") continue;
    pugi::xml_node value = item.child("value");
    for (int axis = 0; axis < 3; ++axis) {
      std::optional<double> v = ParseDouble(value.attribute(keys[axis]).value());
      if (!v || !std::isfinite(*v) || *v <= 0) {
        return CorruptError(name + ": Spacing " + keys[axis] + " is \"" +
                            Printable(value.attribute(keys[axis]).value()) +
                            "\", not a positive number");
      }
      layout.spacing_um[axis] = *v * kMicrometresPerVoreenUnit;
    }
    break;
  }
  return layout;
}

}  // namespace octoscope::io
