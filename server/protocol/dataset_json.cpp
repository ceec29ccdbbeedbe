#include "protocol/dataset_json.h"

#include <algorithm>
#include <nlohmann/json.hpp>

#include "protocol/json_fields.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

// Request documents nest at most two levels (object > array).
constexpr int kMaxStreamRequestDepth = 4;

json DescriptionObject(const DatasetDescription& d) {
  const volume::VolumeInfo& info = d.info;
  json j;
  j["id"] = d.id;
  j["name"] = d.name;
  j["format"] = info.format;
  j["size"] = json::array({info.size[0], info.size[1], info.size[2]});
  j["channels"] = info.channel_count();
  json names = json::array(), colors = json::array();
  for (const volume::ChannelInfo& c : info.channels) {
    names.push_back(c.name);
    if (c.color) {
      colors.push_back(json::array({c.color->r / 255.0, c.color->g / 255.0, c.color->b / 255.0}));
    } else {
      colors.push_back(nullptr);
    }
  }
  j["channel_names"] = std::move(names);
  j["channel_colors"] = std::move(colors);
  j["dtype"] = std::string(volume::NumpyName(info.dtype));
  j["spacing"] = json::array({d.spacing_um[0], d.spacing_um[1], d.spacing_um[2]});
  j["state"] = d.state;
  j["progress"] = d.planes_total == 0 ? 0.0
                                      : static_cast<double>(d.planes_inserted) /
                                            static_cast<double>(d.planes_total);
  j["planes_total"] = d.planes_total;
  j["planes_received"] = d.planes_received;
  j["planes_inserted"] = d.planes_inserted;
  j["missing_planes"] = d.missing_planes ? json(*d.missing_planes) : json(nullptr);
  j["cache"] = d.cache;
  j["error"] = d.error.empty() ? json(nullptr) : json(d.error);
  j["warnings"] = info.warnings;
  // File value = offset + scale * stored value (the windows of render parameters are in stored
  // units); null until the dataset's octree is opened.
  if (d.value_maps.empty()) {
    j["value_maps"] = nullptr;
  } else {
    json maps = json::array();
    for (const volume::ValueMap& m : d.value_maps) {
      maps.push_back({{"offset", m.offset},
                      {"scale", m.scale},
                      {"stored_max", m.stored_type == volume::DataType::kUint8 ? 255 : 65535}});
    }
    j["value_maps"] = std::move(maps);
  }
  return j;
}

}  // namespace

std::string DatasetJson(const DatasetDescription& dataset) {
  return Dump(DescriptionObject(dataset));
}

std::string DatasetListJson(std::span<const DatasetDescription> datasets) {
  json list = json::array();
  for (const DatasetDescription& d : datasets) list.push_back(DescriptionObject(d));
  return Dump(list);
}

std::string HistogramJson(std::span<const HistogramChannelDescription> channels) {
  json list = json::array();
  for (const HistogramChannelDescription& c : channels) {
    json j;
    j["count"] = c.count;
    j["min"] = c.min;
    j["max"] = c.max;
    j["lo"] = c.lo;
    j["hi"] = c.hi;
    j["bins"] = c.bins;
    j["p001"] = c.p001;
    j["p999"] = c.p999;
    list.push_back(std::move(j));
  }
  json doc;
  doc["channels"] = std::move(list);
  return Dump(doc);
}

namespace {

// The shape keys of a stream request or record: "size", "channels" and "dtype" (required),
// "name", "spacing" and "channel_names" (one per channel; with `names_may_be_empty` also []).
Status ParseStreamShape(const json& doc, bool names_may_be_empty, StreamRequest& r) {
  for (const char* required : {"size", "channels", "dtype"}) {
    if (!doc.contains(required)) return FieldError(required, "is required");
  }
  if (auto it = doc.find("name"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(r.name, GetString(*it, "name"));
    if (r.name.size() > kMaxStreamNameBytes) {
      return FieldError("name", "is longer than " + std::to_string(kMaxStreamNameBytes) + " bytes");
    }
  }
  const json& size = doc["size"];
  OCTO_RETURN_IF_ERROR(CheckArray(size, "size", 3));
  for (size_t a = 0; a < 3; ++a) {
    OCTO_ASSIGN_OR_RETURN(r.size[a], GetInteger(size[a], Index("size", a), 1, kMaxStreamAxis));
  }
  OCTO_ASSIGN_OR_RETURN(int64_t channels,
                        GetInteger(doc["channels"], "channels", 1, kMaxStreamChannels));
  r.channels = static_cast<int>(channels);
  OCTO_ASSIGN_OR_RETURN(std::string dtype, GetString(doc["dtype"], "dtype"));
  const std::optional<volume::DataType> type = volume::DataTypeFromNumpyName(dtype);
  if (!type || volume::BytesPerSample(*type) > 2 || volume::IsFloat(*type)) {
    return FieldError(
        "dtype", "is \"" + Printable(dtype, 40) + "\", must be one of uint8, uint16, int8, int16");
  }
  r.dtype = *type;
  if (auto it = doc.find("spacing"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::vector<double> s, GetNumbers(*it, "spacing", 3, 0, kMaxSpacingUm));
    for (size_t a = 0; a < 3; ++a) {
      if (!(s[a] > 0)) return FieldError(Index("spacing", a), "must be > 0");
      r.spacing_um[a] = s[a];
    }
  }
  if (auto it = doc.find("channel_names"); it != doc.end()) {
    if (!(names_may_be_empty && it->is_array() && it->empty())) {
      OCTO_RETURN_IF_ERROR(CheckArray(*it, "channel_names", static_cast<size_t>(r.channels)));
    }
    for (size_t c = 0; c < it->size(); ++c) {
      OCTO_ASSIGN_OR_RETURN(std::string name, GetString((*it)[c], Index("channel_names", c)));
      if (name.size() > kMaxStreamNameBytes) {
        return FieldError(Index("channel_names", c),
                          "is longer than " + std::to_string(kMaxStreamNameBytes) + " bytes");
      }
      r.channel_names.push_back(std::move(name));
    }
  }
  return Status::Ok();
}

}  // namespace

Result<StreamRequest> ParseStreamRequest(std::string_view json_text, StreamRequestKind kind,
                                         std::string_view what) {
  OCTO_ASSIGN_OR_RETURN(
      json doc, ParseJsonObject(json_text, what, kMaxStreamRequestBytes, kMaxStreamRequestDepth));
  const std::string prefix(what);
  auto with_context = [&](const Status& s) { return s.WithContext(prefix); };
  Status keys =
      kind == StreamRequestKind::kSidecar
          ? CheckKeys(
                doc, "",
                {"name", "size", "channels", "dtype", "spacing", "channel_names", "index_base"})
          : CheckKeys(doc, "", {"name", "size", "channels", "dtype", "spacing", "channel_names"});
  if (!keys.ok()) return with_context(keys);
  StreamRequest r;
  if (Status s = ParseStreamShape(doc, false, r); !s.ok()) return with_context(s);
  if (auto it = doc.find("index_base"); it != doc.end()) {
    auto base = GetInteger(*it, "index_base", 0, 1);
    if (!base.ok()) return with_context(base.status());
    r.index_base = static_cast<int>(*base);
  }
  return r;
}

std::string StreamRecordJson(const StreamRecord& record) {
  json j;
  j["version"] = StreamRecord::kVersion;
  j["id"] = record.id;
  const StreamRequest& shape = record.shape;
  j["name"] = shape.name;
  j["size"] = json::array({shape.size[0], shape.size[1], shape.size[2]});
  j["channels"] = shape.channels;
  j["dtype"] = std::string(volume::NumpyName(shape.dtype));
  j["spacing"] = json::array({shape.spacing_um[0], shape.spacing_um[1], shape.spacing_um[2]});
  j["channel_names"] = shape.channel_names;
  j["creator"] = record.creator;
  j["watch"] = record.watch.empty() ? json(nullptr) : json(record.watch);
  j["cache"] = record.cache;
  j["state"] = record.finished ? "ready" : "streaming";
  j["missing_planes"] = record.missing_planes ? json(*record.missing_planes) : json(nullptr);
  j["created_unix_ms"] = record.created_unix_ms;
  j["warnings"] = record.warnings;
  return Dump(j);
}

Result<StreamRecord> ParseStreamRecord(std::string_view json_text, std::string_view what) {
  const std::string prefix(what);
  auto with_context = [&](const Status& s) { return s.WithContext(prefix); };
  OCTO_ASSIGN_OR_RETURN(
      json doc, ParseJsonObject(json_text, what, kMaxStreamRecordBytes, kMaxStreamRequestDepth));
  StreamRecord r;
  auto parse = [&]() -> Status {
    OCTO_RETURN_IF_ERROR(CheckKeys(
        doc, "",
        {"version", "id", "name", "size", "channels", "dtype", "spacing", "channel_names",
         "creator", "watch", "cache", "state", "missing_planes", "created_unix_ms", "warnings"}));
    for (const char* key : {"version", "id", "name", "spacing", "channel_names", "creator", "watch",
                            "cache", "state", "missing_planes", "created_unix_ms", "warnings"}) {
      if (!doc.contains(key)) return FieldError(key, "is required");
    }
    OCTO_RETURN_IF_ERROR(
        GetInteger(doc["version"], "version", StreamRecord::kVersion, StreamRecord::kVersion)
            .status());
    OCTO_ASSIGN_OR_RETURN(r.id, GetString(doc["id"], "id", 12, true));
    if (r.id.size() != 12 || !std::all_of(r.id.begin(), r.id.end(), [](char c) {
          return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
        })) {
      return FieldError("id", "is not a stream id ([a-z0-9]{12})");
    }
    OCTO_RETURN_IF_ERROR(ParseStreamShape(doc, /*names_may_be_empty=*/true, r.shape));
    OCTO_ASSIGN_OR_RETURN(r.creator, GetString(doc["creator"], "creator", 1024, true));
    if (!doc["watch"].is_null()) {
      OCTO_ASSIGN_OR_RETURN(r.watch, GetString(doc["watch"], "watch", 4096, true));
      if (r.watch.empty()) return FieldError("watch", "must be null or a path");
    }
    OCTO_ASSIGN_OR_RETURN(r.cache, GetString(doc["cache"], "cache", 4096, true));
    if (r.cache.empty()) return FieldError("cache", "must be a path");
    OCTO_ASSIGN_OR_RETURN(std::string state, GetString(doc["state"], "state", 16, true));
    if (state != "streaming" && state != "ready") {
      return FieldError("state", "must be \"streaming\" or \"ready\"");
    }
    r.finished = state == "ready";
    if (!doc["missing_planes"].is_null()) {
      if (!r.finished) return FieldError("missing_planes", "must be null while streaming");
      OCTO_ASSIGN_OR_RETURN(const int64_t missing,
                            GetInteger(doc["missing_planes"], "missing_planes", 0,
                                       kMaxStreamAxis * kMaxStreamChannels));
      r.missing_planes = static_cast<uint64_t>(missing);
    }
    OCTO_ASSIGN_OR_RETURN(r.created_unix_ms, GetInteger(doc["created_unix_ms"], "created_unix_ms",
                                                        0, int64_t{1} << 53));
    const json& warnings = doc["warnings"];
    if (!warnings.is_array() || warnings.size() > kMaxStreamRecordWarnings) {
      return FieldError("warnings", "must be an array of at most " +
                                        std::to_string(kMaxStreamRecordWarnings) + " strings");
    }
    for (size_t i = 0; i < warnings.size(); ++i) {
      OCTO_ASSIGN_OR_RETURN(std::string w,
                            GetString(warnings[i], Index("warnings", i), 8192, true));
      r.warnings.push_back(std::move(w));
    }
    return Status::Ok();
  };
  if (Status s = parse(); !s.ok()) return with_context(s);
  return r;
}

std::string CreatedJson(std::string_view id) {
  json j;
  j["id"] = std::string(id);
  return Dump(j);
}

}  // namespace octoscope::protocol
