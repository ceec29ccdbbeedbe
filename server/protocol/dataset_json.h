// DatasetJson: the JSON documents of the dataset layer of `octoscope serve` (docs/api.md):
//   - a dataset as GET /api/datasets lists it (DatasetJson, DatasetListJson);
//   - its histogram, GET /api/datasets/{id}/histogram (HistogramJson);
//   - the body of POST /api/datasets creating a streaming dataset, and the sidecar JSON of a
//     folder watched by `octoscope serve --watch` (ParseStreamRequest);
//   - a stream's record in the server's state folder, which brings it back after a restart
//     (StreamRecordJson, ParseStreamRecord; docs/server.md "Stream records").
// The types here are plain values filled by the dataset layer (protocol sits below it). Parsing
// is strict: unknown keys, wrong types and out-of-range values are kInvalidArgument naming the
// key; nothing throws out of these functions, whatever the input.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_DATASET_JSON_H_
#define OCTOSCOPE_PROTOCOL_DATASET_JSON_H_

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"
#include "volume/data_type.h"
#include "volume/value_map.h"
#include "volume/volume_info.h"

namespace octoscope::protocol {

// A dataset as the API describes it.
struct DatasetDescription {
  std::string id;
  std::string name;
  volume::VolumeInfo info;  // size, channels (names, colours), dtype, format, warnings.
  std::array<double, 3> spacing_um{1, 1, 1};  // Effective spacing (1 where the file says none).
  std::string state;             // "pending", "building", "streaming", "ready", "error".
  uint64_t planes_total = 0;     // z planes x channels.
  uint64_t planes_received = 0;  // Streams: distinct planes received; else = planes_inserted.
  uint64_t planes_inserted = 0;  // Visible in the octree.
  std::optional<uint64_t> missing_planes;    // Finished streams: planes that never arrived.
  std::string cache;                         // The cache directory.
  std::string error;                         // "" when none.
  std::vector<volume::ValueMap> value_maps;  // Per channel; empty until known.
};

// One object: {"id", "name", "format", "size", "channels", "channel_names", "channel_colors"
// ([r,g,b] in 0..1, null when the file gives none), "dtype", "spacing", "state", "progress"
// (planes_inserted / planes_total), "planes_total", "planes_received", "planes_inserted",
// "missing_planes" (null unless a finished stream), "cache", "error" (null when none),
// "warnings", "value_maps" ([{"offset", "scale", "stored_max"}] per channel: file value =
// offset + scale * stored value, stored values 0..stored_max; null until known)}.
std::string DatasetJson(const DatasetDescription& dataset);
// A JSON array of DatasetJson objects.
std::string DatasetListJson(std::span<const DatasetDescription> datasets);

// One channel's histogram for the API, in the file's units.
struct HistogramChannelDescription {
  uint64_t count = 0;          // Voxels counted; the other fields are 0 when it is 0.
  double min = 0, max = 0;     // Smallest and largest value present.
  double lo = 0, hi = 0;       // The bins cover [lo, hi) in equal steps.
  std::vector<uint64_t> bins;  // 256 counts.
  double p001 = 0, p999 = 0;   // The 0.1 % and 99.9 % percentiles (auto-contrast).
};

// {"channels": [{"count", "min", "max", "lo", "hi", "bins", "p001", "p999"}, ...]}.
std::string HistogramJson(std::span<const HistogramChannelDescription> channels);

// What creates a streaming dataset: POST /api/datasets, or a watched folder's sidecar.
struct StreamRequest {
  std::string name;  // "" when the document gives none.
  std::array<int64_t, 3> size{1, 1, 1};
  int channels = 1;
  volume::DataType dtype = volume::DataType::kUint16;
  std::array<double, 3> spacing_um{1, 1, 1};
  std::vector<std::string> channel_names;  // Empty, or one per channel.
  int index_base = 0;                      // Sidecars only: the first plane/channel number.
};

enum class StreamRequestKind {
  kApi,      // POST /api/datasets: name, size, channels, dtype, spacing, channel_names.
  kSidecar,  // A watched folder's sidecar: the same keys plus "index_base" (0 or 1).
};

// Limits of a stream request (also enforced by the dataset layer).
inline constexpr int64_t kMaxStreamAxis = 65536;
inline constexpr int kMaxStreamChannels = 64;
inline constexpr size_t kMaxStreamNameBytes = 256;
inline constexpr double kMaxSpacingUm = 1e6;
inline constexpr uint64_t kMaxStreamRequestBytes = 64 << 10;

// Parses a stream request: "size" ([x, y, z], each 1..65536), "channels" (1..64) and "dtype"
// ("uint8", "uint16", "int8", "int16") are required; "name" (at most 256 bytes), "spacing"
// ([x, y, z] µm, each in (0, 1e6], default 1) and "channel_names" (one string per channel,
// each at most 256 bytes) are optional; a sidecar may also say "index_base" (0 or 1).
// `what` names the document in errors ("request body", the sidecar's path).
Result<StreamRequest> ParseStreamRequest(std::string_view json_text, StreamRequestKind kind,
                                         std::string_view what);

// A stream as its record keeps it (STATE_DIR/streams/ID.json): what it is, who created it, where
// its cache is, and how it stands. What it received is in its cache, not here.
struct StreamRecord {
  static constexpr int kVersion = 1;
  std::string id;  // [a-z0-9]{12}.
  // Name (the dataset's, as listed), size, channels, dtype, spacing, channel names; index_base
  // is not kept.
  StreamRequest shape;
  std::string creator;                     // Opaque; "" for streams the server made.
  std::string watch;                       // The watched folder feeding it; "" for none.
  std::string cache;                       // Its cache directory.
  bool finished = false;                   // "state": "ready" (finished) or "streaming".
  std::optional<uint64_t> missing_planes;  // Finished streams: planes that never arrived.
  int64_t created_unix_ms = 0;             // When it was created (orders the list).
  std::vector<std::string> warnings;       // Shown with the dataset (e.g. an unclean stop).
};

inline constexpr uint64_t kMaxStreamRecordBytes = 256 << 10;
inline constexpr size_t kMaxStreamRecordWarnings = 16;

// {"version": 1, "id", "name", "size", "channels", "dtype", "spacing", "channel_names",
// "creator", "watch" (null or a path), "cache", "state" ("streaming" / "ready"),
// "missing_planes" (null unless ready), "created_unix_ms", "warnings"}.
std::string StreamRecordJson(const StreamRecord& record);
// Strict: every key above is required, unknown keys, wrong types and out-of-range values are
// kInvalidArgument naming the field (prefixed with `what`).
Result<StreamRecord> ParseStreamRecord(std::string_view json_text, std::string_view what);

// {"id": "<id>"}: the answer to POST /api/datasets.
std::string CreatedJson(std::string_view id);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_DATASET_JSON_H_
