// OME-XML: the metadata block of OME-TIFF files and companion (.companion.ome) files, parsed into
// plain structs. Only what Octoscope needs is kept: images (series), their Pixels (extent, sample
// type, dimension order, physical voxel size), channels, and the TiffData elements that say which
// TIFF pages hold which planes. Schema years 2008-2016 are accepted: elements are matched by local
// name, ignoring namespace prefixes.
//
// Parsing is strict: every size, index and type is validated, so a consumer can index with the
// values without further checks beyond those stated on each field.
//
// Thread safety: pure functions on values.
#ifndef OCTOSCOPE_IO_OME_XML_H_
#define OCTOSCOPE_IO_OME_XML_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"
#include "volume/data_type.h"
#include "volume/volume_info.h"

namespace octoscope::io {

// The order of planes in an OME image, X and Y fastest; the three letters after "XY" give Z, C
// and T from fastest to slowest varying.
enum class DimensionOrder { kXYZCT, kXYZTC, kXYCTZ, kXYCZT, kXYTCZ, kXYTZC };

std::optional<DimensionOrder> DimensionOrderFromName(std::string_view name);
std::string_view DimensionOrderName(DimensionOrder order);

// One Channel element. SamplesPerPixel > 1 marks an RGB-style channel: that many consecutive C
// indices stored as the samples of one TIFF page.
struct OmeChannel {
  std::string name;                      // "" when absent.
  std::optional<volume::Rgba> color;     // From the signed 32-bit RGBA Color attribute.
  std::optional<int> samples_per_pixel;  // >= 1 when present.
};

// One TiffData element: `plane_count` planes starting at plane (first_z, first_c, first_t) are
// stored in consecutive IFDs of one TIFF file, starting at `ifd`.
// Invariants: all present values >= 0; first_z < size_z, first_t < size_time, first_c < size_c.
struct OmeTiffData {
  std::optional<int64_t> ifd;  // nullopt: attribute absent (means 0).
  int64_t first_z = 0;
  int64_t first_c = 0;
  int64_t first_t = 0;
  std::optional<int64_t> plane_count;  // nullopt: attribute absent (see the OME-TIFF spec).
  std::string uuid;                    // UUID child text; "" when absent.
  std::string file_name;               // UUID@FileName; "" when absent.
};

// One Pixels element.
// Invariants: 1 <= size_* <= 2^31; size_x*size_y*size_z*size_c*size_time*BytesPerSample(type) fits
// in 64 bits; physical sizes, where known, are finite and > 0.
struct OmePixels {
  DimensionOrder dimension_order = DimensionOrder::kXYZCT;
  int64_t size_x = 1, size_y = 1, size_z = 1, size_c = 1;
  int64_t size_time = 1;  // SizeT (named so as not to shadow the type size_t).
  volume::DataType type = volume::DataType::kUint8;
  // PhysicalSizeX/Y/Z converted to micrometres; nullopt when absent, non-positive, or given in a
  // non-physical unit ("pixel", "reference frame").
  std::array<std::optional<double>, 3> physical_size_um;
  std::vector<OmeChannel> channels;
  std::vector<OmeTiffData> tiff_data;
  bool has_bin_data = false;  // Pixel data embedded as BinData (not an OME-TIFF layout).
};

struct OmeImage {
  std::string id;
  std::string name;
  OmePixels pixels;
};

// A BinaryOnly element: this file holds pixels only; the metadata lives in another file.
struct OmeBinaryOnly {
  std::string metadata_file;  // Relative to the file holding this XML.
  std::string uuid;
};

struct OmeMetadata {
  std::string uuid;                          // OME@UUID; "" when absent.
  std::vector<OmeImage> images;              // Empty when binary_only is set.
  std::optional<OmeBinaryOnly> binary_only;  // Set when the document is only a reference.
};

// Largest OME-XML document accepted (bytes).
inline constexpr uint64_t kMaxOmeXmlBytes = uint64_t{64} << 20;

// Parses `xml`. `source` names the file the XML came from (for error messages). Errors: malformed
// XML, no OME root, missing or invalid sizes/types/orders, negative indices, absurd sizes. A
// document that holds neither an Image nor a BinaryOnly element is an error too.
Result<OmeMetadata> ParseOmeXml(std::string_view xml, std::string_view source);

// True when `text` claims to be an OME-XML document (cheap sniffing, no full parse): its root
// element's local name is "OME", or (a damaged start) it ends with "OME>" or names the OME schema
// namespace. A claim is not a promise: ParseOmeXml decides whether the document is usable.
bool LooksLikeOmeXml(std::string_view text);

// Micrometres per `unit` for the OME UnitsLength symbols (SI "Ym".."ym", "Å"/"angstrom", "in",
// "ft", "yd", "mi", "thou", "li", "ua", "ly", "pc", "pt"; "um"/"µm"/"μm"). nullopt for anything
// else, including the non-physical "pixel" and "reference frame".
std::optional<double> MicrometresPerLengthUnit(std::string_view unit);

// The OME Color attribute (a signed 32-bit integer 0xRRGGBBAA; unsigned spelling accepted) as RGBA.
std::optional<volume::Rgba> ParseOmeColor(std::string_view text);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_OME_XML_H_
