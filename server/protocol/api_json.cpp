#include "protocol/api_json.h"

#include <cmath>

#include "protocol/dataset_json.h"
#include "protocol/json_fields.h"
#include "protocol/query_string.h"
#include "protocol/ws_messages.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using Json = nlohmann::json;

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
  return "{\"error\":" + Quote(OneLine(message, 1000)) + "}";
}

std::string HealthJson(const HealthInfo& h) {
  return "{\"status\":\"ok\",\"version\":" + Quote(h.version) +
         ",\"uptime_s\":" + Number(h.uptime_s) + ",\"datasets\":" + std::to_string(h.datasets) +
         ",\"sessions\":" + std::to_string(h.sessions) + "}";
}

std::string ViewLinkListJson(const std::vector<ViewLinkInfo>& links) {
  auto text_or_null = [](const std::string& v) { return v.empty() ? std::string("null") : Quote(v); };
  std::string out = "[";
  for (size_t i = 0; i < links.size(); ++i) {
    const ViewLinkInfo& l = links[i];
    out += std::string(i ? "," : "") + "{\"id\":" + Quote(l.id) + ",\"url\":" + Quote(l.url) +
           ",\"dataset\":" + Quote(l.dataset) + ",\"dataset_name\":" + text_or_null(l.dataset_name) +
           ",\"made_through\":" + Quote(l.made_through) + ",\"owner\":" + text_or_null(l.owner) +
           ",\"created\":" + Quote(IsoUtc(l.created_unix_s)) + ",\"expires\":" +
           (l.expires_unix_s ? Quote(IsoUtc(*l.expires_unix_s)) : std::string("null")) +
           ",\"valid\":" + (l.valid ? "true" : "false") + ",\"reason\":" + text_or_null(l.reason) +
           "}";
  }
  return out + "]";
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
      OCTO_ASSIGN_OR_RETURN(q.z, QueryInteger(p, 0, kMaxStreamAxis - 1));
    } else if (seen == &seen_depth) {
      OCTO_ASSIGN_OR_RETURN(q.depth, QueryInteger(p, 1, kMaxStreamAxis));
    } else if (seen == &seen_channel) {
      OCTO_ASSIGN_OR_RETURN(int64_t c, QueryInteger(p, 0, kMaxStreamChannels - 1));
      q.channel = static_cast<int>(c);
    } else {
      OCTO_ASSIGN_OR_RETURN(int64_t w, QueryInteger(p, 0, 1));
      q.wait = w == 1;
    }
  }
  if (!seen_z) return FieldError("query parameter \"z\"", "missing");
  if (!seen_depth) return FieldError("query parameter \"depth\"", "missing");
  if (!seen_channel) return FieldError("query parameter \"channel\"", "missing");
  if (q.z + q.depth > kMaxStreamAxis) {
    return FieldError("query parameter \"depth\"", "z + depth = " + std::to_string(q.z + q.depth) +
                                                       " exceeds " +
                                                       std::to_string(kMaxStreamAxis) + " planes");
  }
  return q;
}

std::string SlabResultJson(int64_t planes_received, int64_t planes_inserted) {
  return "{\"planes_received\":" + std::to_string(planes_received) +
         ",\"planes_inserted\":" + std::to_string(planes_inserted) + "}";
}

}  // namespace octoscope::protocol
