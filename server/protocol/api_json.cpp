#include "protocol/api_json.h"

#include <cmath>
#include <optional>

#include "octree/brick_geometry.h"
#include "protocol/json_fields.h"
#include "protocol/query_string.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using json_fields::FieldError;
using json_fields::Json;

constexpr json_fields::ParseLimits kBodyLimits{kMaxApiJsonBodyBytes, kMaxApiJsonDepth,
                                               kMaxDatasetNameBytes};

std::string Number(double v) { return std::isfinite(v) ? Json(v).dump() : "null"; }

// A query parameter value of decimal digits only (no sign, spaces or exponent), in [lo, hi].
Result<int64_t> QueryInteger(const QueryParameter& p, int64_t lo, int64_t hi) {
  const std::string path = "query parameter \"" + p.name + "\"";
  bool digits = !p.value.empty() && p.value.size() <= 18;
  for (char c : p.value) digits = digits && c >= '0' && c <= '9';
  if (!digits) {
    return FieldError(path, "must be a decimal integer, got \"" + Printable(p.value, 30) + "\"");
  }
  const int64_t v = std::stoll(p.value);
  if (v < lo || v > hi) {
    return FieldError(path, "is " + std::to_string(v) + ", must be in [" + std::to_string(lo) +
                                ", " + std::to_string(hi) + "]");
  }
  return v;
}

}  // namespace

std::string HttpErrorJson(std::string_view message) {
  return "{\"error\":" + json_fields::Quote(json_fields::OneLine(message, 1000)) + "}";
}

std::string HealthJson(const HealthInfo& h) {
  return "{\"status\":\"ok\",\"version\":" + json_fields::Quote(h.version) +
         ",\"uptime_s\":" + Number(h.uptime_s) + ",\"datasets\":" + std::to_string(h.datasets) +
         ",\"sessions\":" + std::to_string(h.sessions) + "}";
}

Result<CreateDatasetRequest> ParseCreateDatasetRequest(std::string_view body) {
  OCTO_ASSIGN_OR_RETURN(Json doc, json_fields::ParseObject(body, "request body", kBodyLimits));
  OCTO_RETURN_IF_ERROR(json_fields::CheckKeys(
      doc, "", {"name", "size", "channels", "dtype", "spacing", "channel_names"}));
  CreateDatasetRequest r;
  OCTO_ASSIGN_OR_RETURN(const Json* name, json_fields::Require(doc, "", "name"));
  OCTO_ASSIGN_OR_RETURN(r.name, json_fields::GetString(*name, "name", kMaxDatasetNameBytes, true));
  if (TrimWhitespace(r.name).empty()) return FieldError("name", "must not be empty");

  OCTO_ASSIGN_OR_RETURN(const Json* size, json_fields::Require(doc, "", "size"));
  if (!size->is_array() || size->size() != 3) {
    return FieldError("size", "must be an array of 3 integers [x, y, z]");
  }
  for (size_t i = 0; i < 3; ++i) {
    OCTO_ASSIGN_OR_RETURN(r.size[i], json_fields::GetInteger((*size)[i], json_fields::Index("size", i),
                                                             1, octree::kMaxVolumeAxis));
  }

  OCTO_ASSIGN_OR_RETURN(const Json* channels, json_fields::Require(doc, "", "channels"));
  OCTO_ASSIGN_OR_RETURN(int64_t c,
                        json_fields::GetInteger(*channels, "channels", 1, octree::kMaxChannels));
  r.channels = static_cast<int>(c);

  OCTO_ASSIGN_OR_RETURN(const Json* dtype, json_fields::Require(doc, "", "dtype"));
  OCTO_ASSIGN_OR_RETURN(std::string dtype_name, json_fields::GetString(*dtype, "dtype", 16, true));
  std::optional<volume::DataType> type = volume::DataTypeFromNumpyName(dtype_name);
  if (!type || (*type != volume::DataType::kUint8 && *type != volume::DataType::kUint16 &&
                *type != volume::DataType::kInt8 && *type != volume::DataType::kInt16)) {
    return FieldError("dtype", "is \"" + Printable(dtype_name, 16) +
                                   "\", expected uint8, uint16, int8 or int16");
  }
  r.dtype = *type;

  if (auto it = doc.find("spacing"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(r.spacing, json_fields::GetNumber3(*it, "spacing", 0, kMaxSpacingUm));
    for (size_t i = 0; i < 3; ++i) {
      if (!(r.spacing[i] > 0)) return FieldError(json_fields::Index("spacing", i), "must be > 0");
    }
  }

  if (auto it = doc.find("channel_names"); it != doc.end()) {
    if (!it->is_array() || it->size() != static_cast<size_t>(r.channels)) {
      return FieldError("channel_names",
                        "must be an array of " + std::to_string(r.channels) + " strings");
    }
    for (size_t i = 0; i < it->size(); ++i) {
      OCTO_ASSIGN_OR_RETURN(std::string channel_name,
                            json_fields::GetString((*it)[i], json_fields::Index("channel_names", i),
                                                   kMaxChannelNameBytes, true));
      r.channel_names.push_back(std::move(channel_name));
    }
  }
  return r;
}

std::string CreatedDatasetJson(std::string_view id) {
  return "{\"id\":" + json_fields::Quote(id) + "}";
}

Result<SlabQuery> ParseSlabQuery(std::string_view query) {
  OCTO_ASSIGN_OR_RETURN(std::vector<QueryParameter> params, ParseQueryString(query));
  SlabQuery q;
  bool seen_z = false, seen_depth = false, seen_channel = false, seen_wait = false;
  for (const QueryParameter& p : params) {
    if (p.name == "token") continue;
    bool* seen = p.name == "z"         ? &seen_z
                 : p.name == "depth"   ? &seen_depth
                 : p.name == "channel" ? &seen_channel
                 : p.name == "wait"    ? &seen_wait
                                       : nullptr;
    const std::string path = "query parameter \"" + Printable(p.name, 30) + "\"";
    if (!seen) return FieldError(path, "unknown (known: z, depth, channel, wait)");
    if (*seen) return FieldError(path, "given twice");
    *seen = true;
    if (seen == &seen_z) {
      OCTO_ASSIGN_OR_RETURN(q.z, QueryInteger(p, 0, octree::kMaxVolumeAxis - 1));
    } else if (seen == &seen_depth) {
      OCTO_ASSIGN_OR_RETURN(q.depth, QueryInteger(p, 1, octree::kMaxVolumeAxis));
    } else if (seen == &seen_channel) {
      OCTO_ASSIGN_OR_RETURN(int64_t c, QueryInteger(p, 0, octree::kMaxChannels - 1));
      q.channel = static_cast<int>(c);
    } else {
      OCTO_ASSIGN_OR_RETURN(int64_t w, QueryInteger(p, 0, 1));
      q.wait = w == 1;
    }
  }
  if (!seen_z) return FieldError("query parameter \"z\"", "missing");
  if (!seen_depth) return FieldError("query parameter \"depth\"", "missing");
  if (!seen_channel) return FieldError("query parameter \"channel\"", "missing");
  if (q.z + q.depth > octree::kMaxVolumeAxis) {
    return FieldError("query parameter \"depth\"",
                      "z + depth = " + std::to_string(q.z + q.depth) + " exceeds " +
                          std::to_string(octree::kMaxVolumeAxis) + " planes");
  }
  return q;
}

std::string SlabResultJson(int64_t planes_received, int64_t planes_inserted) {
  return "{\"planes_received\":" + std::to_string(planes_received) +
         ",\"planes_inserted\":" + std::to_string(planes_inserted) + "}";
}

}  // namespace octoscope::protocol
