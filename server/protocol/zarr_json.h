// Zarr JSON: parses the JSON documents of a Zarr store into the typed metadata of
// io/zarr_metadata.h — a Zarr v2 `.zarray`, a Zarr v3 array `zarr.json` (codecs, sharding, chunk
// key encodings), and group attributes: v2 `.zattrs` or v3 `zarr.json` with OME-NGFF 0.1 – 0.5
// `multiscales`, `omero` channels, `bioformats2raw.layout`, `plate`/`well`. docs/formats.md
// specifies which values are accepted.
//
// Syntax and types are checked here (errors name the key: `"chunks"[2] must be a positive
// integer`); what the values mean (limits, consistency with the shape) is checked by the reader.
// Valid features Octoscope does not decode (filters, other codecs, 64-bit integer samples,
// nested sharding) are Unsupported, naming the feature. Nothing throws, whatever the input;
// documents nesting deeper than kMaxZarrJsonDepth are refused.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_ZARR_JSON_H_
#define OCTOSCOPE_PROTOCOL_ZARR_JSON_H_

#include <string_view>

#include "io/zarr_metadata.h"
#include "util/result.h"

namespace octoscope::protocol {

inline constexpr int kMaxZarrJsonDepth = 64;

// A v2 `.zarray` or a v3 array `zarr.json`.
Result<io::ZarrArrayMetadata> ParseZarrArrayJson(std::string_view json_text);

// A v2 `.zattrs`, or a v3 `zarr.json` (group or array; NGFF 0.5 attributes live under "ome").
Result<io::NgffAttributes> ParseZarrAttributesJson(std::string_view json_text);

// Both, as app/ injects them into io::OpenOptions.
io::ZarrJsonParsers MakeZarrJsonParsers();

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_ZARR_JSON_H_
