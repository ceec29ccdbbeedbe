// Zarr and OME-NGFF metadata as typed values: what a Zarr array's `.zarray` (Zarr v2) or
// `zarr.json` (Zarr v3) says about its shape, chunks, sample type and chunk encoding, and what an
// OME-Zarr image's attributes (`.zattrs`, or `zarr.json` "attributes"/"ome" in NGFF 0.5) say about
// its axes, resolution levels, physical scale and channels. docs/formats.md specifies the mapping.
//
// The JSON text is parsed in protocol/ (the only layer with JSON, protocol/zarr_json.h) and reaches
// io/ through ZarrJsonParsers in OpenOptions, set by app/ — the same layering as the raw sidecar.
// Parsers check syntax and types; the reader (io/ome_zarr_volume.h) checks what the values mean
// (sizes, limits, consistency) before anything is allocated.
//
// Thread safety: plain value types.
#ifndef OCTOSCOPE_IO_ZARR_METADATA_H_
#define OCTOSCOPE_IO_ZARR_METADATA_H_

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "io/chunk_codecs.h"
#include "util/result.h"
#include "volume/data_type.h"
#include "volume/volume_info.h"

namespace octoscope::io {

// How one chunk's bytes encode its samples.
struct ZarrChunkEncoding {
  // Axis order of the stored samples (C order over the chunk's axes permuted by `order`: stored
  // axis k is chunk axis order[k]). Empty: C order. Zarr v2 "order": "F" is the reversed order;
  // Zarr v3 "transpose" gives it.
  std::vector<int> order;
  bool big_endian = false;  // Byte order of multi-byte samples.
  // Bytes-to-bytes codecs in encoding order (decoded last to first): at most one compressor
  // plus any crc32c.
  std::vector<ChunkCodec> codecs;
};

// Zarr v3 "sharding_indexed": each chunk of the grid is a shard file holding inner chunks plus
// an index of (offset, nbytes) pairs (uint64 little-endian; both 2^64-1 for an absent chunk).
struct ZarrSharding {
  std::vector<int64_t> inner_chunks;  // Inner chunk shape; divides the shard shape.
  ZarrChunkEncoding inner;            // Encoding of each inner chunk.
  bool index_at_end = true;           // "index_location": "end" (default) or "start".
  bool index_crc32c = false;          // Index codecs [bytes little, crc32c] instead of [bytes].
};

struct ZarrArrayMetadata {
  int zarr_format = 2;          // 2 or 3.
  std::vector<int64_t> shape;   // Samples per dimension.
  std::vector<int64_t> chunks;  // Chunk (v3 sharded: shard) shape, one per dimension.
  volume::DataType dtype = volume::DataType::kUint8;
  // Value of samples in absent chunks; nullopt for v2's `null` (read as 0).
  std::optional<double> fill_value;
  ZarrChunkEncoding encoding;  // Of each chunk; unused when `sharding` is set.
  std::optional<ZarrSharding> sharding;
  // Chunk keys: [prefix + separator] + indexes joined by the separator. v2: no prefix, separator
  // "." or "/"; v3 "default": prefix "c", separator "/" or "."; v3 "v2": as v2.
  std::string key_prefix;
  char separator = '.';
  std::vector<std::string> dimension_names;  // v3, optional: one per dimension or empty.
};

struct NgffAxis {
  std::string name;  // "x", "y", "z", "c", "t", or anything (custom).
  std::string type;  // "space", "time", "channel", "" (unknown) or custom.
  std::string unit;  // As written ("micrometer", "nanometer", "second", …); "" when absent.
};

// A scale and translation (NGFF "coordinateTransformations"); empty when absent.
struct NgffTransform {
  std::vector<double> scale;
  std::vector<double> translation;
};

struct NgffDataset {
  std::string path;  // The level's array, relative to the image group.
  NgffTransform transform;
};

struct NgffMultiscale {
  std::string version;  // "0.1" … "0.5"; "" when absent.
  std::string name;
  std::vector<NgffAxis> axes;         // Empty for NGFF 0.1/0.2 (implicitly t, c, z, y, x).
  std::vector<NgffDataset> datasets;  // Finest first.
  NgffTransform transform;            // Applies to every dataset (after its own).
};

struct OmeroChannel {
  std::string label;
  std::optional<volume::Rgba> color;  // From "RRGGBB".
  std::optional<volume::DisplayWindow> window;
};

// The group attributes that matter to Octoscope.
struct NgffAttributes {
  // v3 zarr.json only: "group" or "array" (for an array the attributes below are empty and the
  // array metadata is parsed from the same text); "" for v2 .zattrs.
  std::string node_type;
  std::vector<NgffMultiscale> multiscales;
  std::vector<OmeroChannel> omero_channels;
  bool has_omero = false;
  std::optional<int64_t> bioformats2raw_layout;  // A bioformats2raw.layout group (series 0, 1, …).
  bool is_plate = false;                         // HCS "plate" or "well" groups (not images).
};

// JSON parsers for the Zarr documents, injected by app/ from protocol/. Each returns Corrupt
// (or Unsupported for valid but unhandled features) with a message naming the key.
struct ZarrJsonParsers {
  // `.zarray` (v2) or an array's `zarr.json` (v3).
  std::function<Result<ZarrArrayMetadata>(std::string_view json)> array;
  // `.zattrs` (v2) or a group's or array's `zarr.json` (v3).
  std::function<Result<NgffAttributes>(std::string_view json)> attributes;
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_ZARR_METADATA_H_
