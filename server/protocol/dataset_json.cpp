#include "protocol/dataset_json.h"

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
  for (const char* required : {"size", "channels", "dtype"}) {
    if (!doc.contains(required)) {
      return with_context(FieldError(required, "is required"));
    }
  }
  StreamRequest r;
  auto parse = [&]() -> Status {
    if (auto it = doc.find("name"); it != doc.end()) {
      OCTO_ASSIGN_OR_RETURN(r.name, GetString(*it, "name"));
      if (r.name.size() > kMaxStreamNameBytes) {
        return FieldError("name",
                          "is longer than " + std::to_string(kMaxStreamNameBytes) + " bytes");
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
      return FieldError("dtype", "is \"" + Printable(dtype, 40) +
                                     "\", must be one of uint8, uint16, int8, int16");
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
      OCTO_RETURN_IF_ERROR(CheckArray(*it, "channel_names", static_cast<size_t>(r.channels)));
      for (size_t c = 0; c < it->size(); ++c) {
        OCTO_ASSIGN_OR_RETURN(std::string name, GetString((*it)[c], Index("channel_names", c)));
        if (name.size() > kMaxStreamNameBytes) {
          return FieldError(Index("channel_names", c),
                            "is longer than " + std::to_string(kMaxStreamNameBytes) + " bytes");
        }
        r.channel_names.push_back(std::move(name));
      }
    }
    if (auto it = doc.find("index_base"); it != doc.end()) {
      OCTO_ASSIGN_OR_RETURN(int64_t base, GetInteger(*it, "index_base", 0, 1));
      r.index_base = static_cast<int>(base);
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
