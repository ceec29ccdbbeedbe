#include "io/ome_xml.h"

#include <cctype>
#include <cmath>
#include <cstring>
#include <limits>
#include <pugixml.hpp>
#include <utility>

#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

constexpr int64_t kMaxDimension = int64_t{1} << 31;

// The element name without its namespace prefix ("OME:Pixels" -> "Pixels").
std::string_view LocalName(const pugi::xml_node& node) {
  std::string_view name = node.name();
  size_t colon = name.rfind(':');
  return colon == std::string_view::npos ? name : name.substr(colon + 1);
}

bool IsElement(const pugi::xml_node& node, std::string_view local_name) {
  return node.type() == pugi::node_element && LocalName(node) == local_name;
}

pugi::xml_node FirstChild(const pugi::xml_node& parent, std::string_view local_name) {
  for (pugi::xml_node child : parent.children()) {
    if (IsElement(child, local_name)) return child;
  }
  return {};
}

// An attribute by local name (attributes in OME are unqualified, but tolerate prefixes).
pugi::xml_attribute Attribute(const pugi::xml_node& node, std::string_view local_name) {
  for (pugi::xml_attribute attr : node.attributes()) {
    std::string_view name = attr.name();
    size_t colon = name.rfind(':');
    if (colon != std::string_view::npos) {
      if (name.substr(0, colon) == "xmlns") continue;
      name = name.substr(colon + 1);
    }
    if (name == local_name) return attr;
  }
  return {};
}

// Parsing context: builds error messages that name the file and the element.
class Parser {
 public:
  explicit Parser(std::string_view source) : source_(source) {}

  Status Error(const std::string& what) const {
    return CorruptError(std::string(source_) + ": OME-XML " + context_ + what);
  }

  // An optional non-negative integer attribute; nullopt when absent.
  Result<std::optional<int64_t>> OptionalIndex(const pugi::xml_node& node, std::string_view name,
                                               std::string_view element) const {
    pugi::xml_attribute attr = Attribute(node, name);
    if (!attr) return std::optional<int64_t>();
    std::optional<int64_t> value = ParseInt64(attr.value());
    if (!value) {
      return Error(std::string(element) + "@" + std::string(name) + " is not an integer: \"" +
                   Printable(attr.value()) + "\"");
    }
    if (*value < 0) {
      return Error(std::string(element) + "@" + std::string(name) + " is negative (" +
                   std::to_string(*value) + ")");
    }
    return std::optional<int64_t>(*value);
  }

  // A required size attribute in [1, 2^31].
  Result<int64_t> Size(const pugi::xml_node& pixels, std::string_view name) const {
    pugi::xml_attribute attr = Attribute(pixels, name);
    if (!attr) return Error("Pixels@" + std::string(name) + " is missing");
    std::optional<int64_t> value = ParseInt64(attr.value());
    if (!value) {
      return Error("Pixels@" + std::string(name) + " is not an integer: \"" +
                   Printable(attr.value()) + "\"");
    }
    if (*value < 1) {
      return Error("Pixels@" + std::string(name) + " is " + std::to_string(*value) +
                   ", must be at least 1");
    }
    if (*value > kMaxDimension) {
      return Error("Pixels@" + std::string(name) + " is " + std::to_string(*value) +
                   ", more than 2^31");
    }
    return *value;
  }

  // PhysicalSize<axis> in micrometres.
  Result<std::optional<double>> PhysicalSize(const pugi::xml_node& pixels,
                                             std::string_view axis) const {
    std::string name = "PhysicalSize" + std::string(axis);
    pugi::xml_attribute attr = Attribute(pixels, name);
    if (!attr) return std::optional<double>();
    std::optional<double> value = ParseDouble(attr.value());
    if (!value || !std::isfinite(*value)) {
      return Error("Pixels@" + name + " is not a number: \"" + Printable(attr.value()) + "\"");
    }
    double factor = 1.0;
    pugi::xml_attribute unit_attr = Attribute(pixels, name + "Unit");
    if (unit_attr) {
      std::string_view unit = TrimWhitespace(unit_attr.value());
      if (unit == "pixel" || unit == "reference frame") return std::optional<double>();
      std::optional<double> f = MicrometresPerLengthUnit(unit);
      if (!f) {
        return Error("Pixels@" + name + "Unit \"" + Printable(unit) + "\" is not a length unit");
      }
      factor = *f;
    }
    double um = *value * factor;
    // Writers put 0 (or worse) for "unknown"; that is no spacing rather than a broken file.
    if (!(um > 0) || !std::isfinite(um)) return std::optional<double>();
    return std::optional<double>(um);
  }

  Result<OmeChannel> Channel(const pugi::xml_node& node) const {
    OmeChannel channel;
    channel.name = Attribute(node, "Name").value();
    if (pugi::xml_attribute color = Attribute(node, "Color")) {
      channel.color = ParseOmeColor(color.value());
      if (!channel.color) {
        return Error("Channel@Color is not a 32-bit integer: \"" + Printable(color.value()) + "\"");
      }
    }
    if (pugi::xml_attribute spp = Attribute(node, "SamplesPerPixel")) {
      std::optional<int64_t> value = ParseInt64(spp.value());
      if (!value || *value < 1 || *value > 65535) {
        return Error("Channel@SamplesPerPixel is invalid: \"" + Printable(spp.value()) + "\"");
      }
      channel.samples_per_pixel = static_cast<int>(*value);
    }
    return channel;
  }

  Result<OmeTiffData> TiffData(const pugi::xml_node& node, const OmePixels& pixels) const {
    OmeTiffData data;
    OCTO_ASSIGN_OR_RETURN(data.ifd, OptionalIndex(node, "IFD", "TiffData"));
    OCTO_ASSIGN_OR_RETURN(std::optional<int64_t> first_z,
                          OptionalIndex(node, "FirstZ", "TiffData"));
    OCTO_ASSIGN_OR_RETURN(std::optional<int64_t> first_c,
                          OptionalIndex(node, "FirstC", "TiffData"));
    OCTO_ASSIGN_OR_RETURN(std::optional<int64_t> first_t,
                          OptionalIndex(node, "FirstT", "TiffData"));
    OCTO_ASSIGN_OR_RETURN(data.plane_count, OptionalIndex(node, "PlaneCount", "TiffData"));
    data.first_z = first_z.value_or(0);
    data.first_c = first_c.value_or(0);
    data.first_t = first_t.value_or(0);
    if (data.first_z >= pixels.size_z || data.first_c >= pixels.size_c ||
        data.first_t >= pixels.size_time) {
      return Error("TiffData FirstZ/C/T (" + std::to_string(data.first_z) + ", " +
                   std::to_string(data.first_c) + ", " + std::to_string(data.first_t) +
                   ") lies outside the image (SizeZ " + std::to_string(pixels.size_z) + ", SizeC " +
                   std::to_string(pixels.size_c) + ", SizeT " + std::to_string(pixels.size_time) +
                   ")");
    }
    if (pugi::xml_node uuid = FirstChild(node, "UUID")) {
      data.uuid = std::string(TrimWhitespace(uuid.child_value()));
      data.file_name = std::string(TrimWhitespace(Attribute(uuid, "FileName").value()));
    }
    return data;
  }

  Result<OmePixels> Pixels(const pugi::xml_node& image, const pugi::xml_node& node) const {
    OmePixels pixels;
    pugi::xml_attribute order = Attribute(node, "DimensionOrder");
    if (!order) return Error("Pixels@DimensionOrder is missing");
    std::optional<DimensionOrder> parsed_order =
        DimensionOrderFromName(TrimWhitespace(order.value()));
    if (!parsed_order) {
      return Error("Pixels@DimensionOrder \"" + Printable(order.value()) + "\" is unknown");
    }
    pixels.dimension_order = *parsed_order;

    // "Type" since 2010; "PixelType" in the 2008/2009 schemas.
    pugi::xml_attribute type = Attribute(node, "Type");
    if (!type) type = Attribute(node, "PixelType");
    if (!type) return Error("Pixels@Type is missing");
    std::optional<volume::DataType> dtype =
        volume::DataTypeFromOmeName(TrimWhitespace(type.value()));
    if (!dtype) {
      return Error("Pixels@Type \"" + Printable(type.value()) + "\" is not a supported type");
    }
    pixels.type = *dtype;

    OCTO_ASSIGN_OR_RETURN(pixels.size_x, Size(node, "SizeX"));
    OCTO_ASSIGN_OR_RETURN(pixels.size_y, Size(node, "SizeY"));
    OCTO_ASSIGN_OR_RETURN(pixels.size_z, Size(node, "SizeZ"));
    OCTO_ASSIGN_OR_RETURN(pixels.size_c, Size(node, "SizeC"));
    OCTO_ASSIGN_OR_RETURN(pixels.size_time, Size(node, "SizeT"));
    std::optional<uint64_t> bytes = CheckedProduct(
        {static_cast<uint64_t>(pixels.size_x), static_cast<uint64_t>(pixels.size_y),
         static_cast<uint64_t>(pixels.size_z), static_cast<uint64_t>(pixels.size_c),
         static_cast<uint64_t>(pixels.size_time), volume::BytesPerSample(pixels.type)});
    if (!bytes) {
      return Error("Pixels sizes " + std::to_string(pixels.size_x) + "x" +
                   std::to_string(pixels.size_y) + "x" + std::to_string(pixels.size_z) + " x C" +
                   std::to_string(pixels.size_c) + " x T" + std::to_string(pixels.size_time) +
                   " overflow 64 bits");
    }

    OCTO_ASSIGN_OR_RETURN(pixels.physical_size_um[0], PhysicalSize(node, "X"));
    OCTO_ASSIGN_OR_RETURN(pixels.physical_size_um[1], PhysicalSize(node, "Y"));
    OCTO_ASSIGN_OR_RETURN(pixels.physical_size_um[2], PhysicalSize(node, "Z"));

    for (pugi::xml_node child : node.children()) {
      if (IsElement(child, "Channel")) {
        OCTO_ASSIGN_OR_RETURN(OmeChannel channel, Channel(child));
        pixels.channels.push_back(std::move(channel));
      } else if (IsElement(child, "TiffData")) {
        OCTO_ASSIGN_OR_RETURN(OmeTiffData data, TiffData(child, pixels));
        pixels.tiff_data.push_back(std::move(data));
      } else if (IsElement(child, "BinData")) {
        pixels.has_bin_data = true;
      }
    }
    // Before 2010 channels were LogicalChannel elements of the Image.
    if (pixels.channels.empty()) {
      for (pugi::xml_node child : image.children()) {
        if (!IsElement(child, "LogicalChannel")) continue;
        OCTO_ASSIGN_OR_RETURN(OmeChannel channel, Channel(child));
        pixels.channels.push_back(std::move(channel));
      }
    }
    if (static_cast<int64_t>(pixels.channels.size()) > pixels.size_c) {
      return Error("Pixels has " + std::to_string(pixels.channels.size()) +
                   " Channel elements but SizeC is " + std::to_string(pixels.size_c));
    }
    return pixels;
  }

  Result<OmeMetadata> Document(const pugi::xml_node& root) {
    OmeMetadata metadata;
    metadata.uuid = std::string(TrimWhitespace(Attribute(root, "UUID").value()));
    for (pugi::xml_node child : root.children()) {
      if (IsElement(child, "BinaryOnly")) {
        OmeBinaryOnly binary_only;
        binary_only.metadata_file =
            std::string(TrimWhitespace(Attribute(child, "MetadataFile").value()));
        binary_only.uuid = std::string(TrimWhitespace(Attribute(child, "UUID").value()));
        if (binary_only.metadata_file.empty()) {
          return Error("BinaryOnly element has no MetadataFile");
        }
        metadata.binary_only = std::move(binary_only);
      } else if (IsElement(child, "Image")) {
        pugi::xml_node pixels_node = FirstChild(child, "Pixels");
        OmeImage image;
        image.id = Attribute(child, "ID").value();
        image.name = Attribute(child, "Name").value();
        if (!pixels_node) return Error("Image \"" + Printable(image.id) + "\" has no Pixels");
        context_ = "Image " + std::to_string(metadata.images.size()) + ": ";
        OCTO_ASSIGN_OR_RETURN(image.pixels, Pixels(child, pixels_node));
        context_.clear();
        metadata.images.push_back(std::move(image));
      }
    }
    if (metadata.binary_only && !metadata.images.empty()) {
      return Error("document has both BinaryOnly and Image elements");
    }
    if (!metadata.binary_only && metadata.images.empty()) {
      return Error("document has no Image");
    }
    return metadata;
  }

 private:
  std::string_view source_;
  std::string context_;  // Which element is being parsed ("Image 2: "), for messages.
};

}  // namespace

std::optional<DimensionOrder> DimensionOrderFromName(std::string_view name) {
  if (name == "XYZCT") return DimensionOrder::kXYZCT;
  if (name == "XYZTC") return DimensionOrder::kXYZTC;
  if (name == "XYCTZ") return DimensionOrder::kXYCTZ;
  if (name == "XYCZT") return DimensionOrder::kXYCZT;
  if (name == "XYTCZ") return DimensionOrder::kXYTCZ;
  if (name == "XYTZC") return DimensionOrder::kXYTZC;
  return std::nullopt;
}

std::string_view DimensionOrderName(DimensionOrder order) {
  switch (order) {
    case DimensionOrder::kXYZCT:
      return "XYZCT";
    case DimensionOrder::kXYZTC:
      return "XYZTC";
    case DimensionOrder::kXYCTZ:
      return "XYCTZ";
    case DimensionOrder::kXYCZT:
      return "XYCZT";
    case DimensionOrder::kXYTCZ:
      return "XYTCZ";
    case DimensionOrder::kXYTZC:
      return "XYTZC";
  }
  return "?";
}

std::optional<double> MicrometresPerLengthUnit(std::string_view unit) {
  struct Entry {
    std::string_view symbol;
    double um;
  };
  // clang-format off
  static constexpr Entry kUnits[] = {
      {"Ym", 1e30}, {"Zm", 1e27}, {"Em", 1e24}, {"Pm", 1e21}, {"Tm", 1e18}, {"Gm", 1e15},
      {"Mm", 1e12}, {"km", 1e9}, {"hm", 1e8}, {"dam", 1e7}, {"m", 1e6}, {"dm", 1e5},
      {"cm", 1e4}, {"mm", 1e3}, {"um", 1}, {"\xC2\xB5m", 1} /* U+00B5 micro sign */,
      {"\xCE\xBCm", 1} /* U+03BC Greek mu */, {"nm", 1e-3}, {"pm", 1e-6}, {"fm", 1e-9},
      {"am", 1e-12}, {"zm", 1e-15}, {"ym", 1e-18},
      {"\xC3\x85", 1e-4} /* U+00C5 Å */, {"\xE2\x84\xAB", 1e-4} /* U+212B Angstrom sign */,
      {"angstrom", 1e-4}, {"Angstrom", 1e-4},
      {"thou", 25.4}, {"li", 2116.6666666666665} /* 1/12 in, per Bio-Formats */,
      {"in", 25400}, {"ft", 304800}, {"yd", 914400}, {"mi", 1609344000},
      {"ua", 1.495978707e17}, {"ly", 9.4607304725808e21}, {"pc", 3.0856775814913673e22},
      {"pt", 352.77777777777777},
  };
  // clang-format on
  for (const Entry& e : kUnits) {
    if (unit == e.symbol) return e.um;
  }
  return std::nullopt;
}

std::optional<volume::Rgba> ParseOmeColor(std::string_view text) {
  std::optional<int64_t> value = ParseInt64(text);
  // Signed 32-bit is the schema's type; some writers emit the same bits unsigned.
  if (!value || *value < std::numeric_limits<int32_t>::min() ||
      *value > std::numeric_limits<uint32_t>::max()) {
    return std::nullopt;
  }
  uint32_t bits = static_cast<uint32_t>(*value);
  volume::Rgba rgba;
  rgba.r = static_cast<uint8_t>(bits >> 24);
  rgba.g = static_cast<uint8_t>(bits >> 16);
  rgba.b = static_cast<uint8_t>(bits >> 8);
  rgba.a = static_cast<uint8_t>(bits);
  return rgba;
}

namespace {

// The root element's local name is "OME" (after the prolog: declaration, comments, whitespace).
bool RootIsOme(std::string_view text) {
  size_t at = 0;
  while (at < text.size()) {
    at = text.find('<', at);
    if (at == std::string_view::npos || at + 1 >= text.size()) return false;
    char next = text[at + 1];
    if (next == '?' || next == '!') {
      std::string_view end_marker = text.compare(at, 4, "<!--") == 0 ? "-->" : ">";
      size_t end = text.find(end_marker, at + 2);
      if (end == std::string_view::npos) return false;
      at = end + end_marker.size();
      continue;
    }
    size_t name_end = text.find_first_of(" \t\r\n/>", at + 1);
    if (name_end == std::string_view::npos) return false;
    std::string_view name = text.substr(at + 1, name_end - at - 1);
    size_t colon = name.rfind(':');
    if (colon != std::string_view::npos) name = name.substr(colon + 1);
    return name == "OME";
  }
  return false;
}

}  // namespace

bool LooksLikeOmeXml(std::string_view text) {
  if (RootIsOme(text)) return true;
  // A document whose start is damaged still shows what it is by its end (tifffile's test) or by
  // the OME namespace.
  while (!text.empty() &&
         (text.back() == '\0' || std::isspace(static_cast<unsigned char>(text.back())))) {
    text.remove_suffix(1);
  }
  return text.ends_with("OME>") ||
         text.find("openmicroscopy.org/Schemas/OME/") != std::string_view::npos;
}

Result<OmeMetadata> ParseOmeXml(std::string_view xml, std::string_view source) {
  Parser parser(source);
  if (xml.size() > kMaxOmeXmlBytes) {
    return ResourceExhaustedError(std::string(source) + ": OME-XML of " +
                                  std::to_string(xml.size()) + " bytes exceeds the limit of " +
                                  std::to_string(kMaxOmeXmlBytes));
  }
  // Descriptions written by some tools carry trailing NULs; they are not part of the document.
  while (!xml.empty() && xml.back() == '\0') xml.remove_suffix(1);
  pugi::xml_document doc;
  pugi::xml_parse_result parsed =
      doc.load_buffer(xml.data(), xml.size(), pugi::parse_default, pugi::encoding_utf8);
  if (!parsed) {
    return parser.Error("is malformed: " + std::string(parsed.description()) + " at byte " +
                        std::to_string(parsed.offset));
  }
  pugi::xml_node root = doc.document_element();
  if (!root || LocalName(root) != "OME") {
    return parser.Error("root element is \"" + Printable(root ? root.name() : "") + "\", not OME");
  }
  return parser.Document(root);
}

}  // namespace octoscope::io
