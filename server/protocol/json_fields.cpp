#include "protocol/json_fields.h"

#include <exception>
#include <stdexcept>

#include "protocol/json_parse.h"
#include "util/strings.h"

namespace octoscope::protocol {

using nlohmann::json;

Status FieldError(const std::string& path, std::string_view problem) {
  return InvalidArgumentError(path + ": " + std::string(problem));
}

std::string TypeOf(const json& j) { return std::string(j.type_name()); }

std::string FormatDouble(double v) { return json(v).dump(); }

std::string Join(const std::string& path, std::string_view key) {
  return path.empty() ? std::string(key) : path + "." + std::string(key);
}

std::string Index(const std::string& path, size_t i) {
  return path + "[" + std::to_string(i) + "]";
}

Result<json> ParseJsonObject(std::string_view text, std::string_view what, uint64_t max_bytes,
                             int max_depth) {
  if (text.size() > max_bytes) {
    return InvalidArgumentError(std::string(what) + ": larger than " + std::to_string(max_bytes) +
                                " bytes");
  }
  Result<json> parsed = ParseJsonLimited(text, max_depth);
  if (!parsed.ok())
    return InvalidArgumentError(std::string(what) + ": " + parsed.status().message());
  json doc = std::move(*parsed);
  if (!doc.is_object()) {
    return InvalidArgumentError(std::string(what) + ": must be a JSON object, got " + TypeOf(doc));
  }
  return doc;
}

Status CheckKeys(const json& object, const std::string& path,
                 std::initializer_list<std::string_view> known) {
  for (const auto& item : object.items()) {
    bool found = false;
    for (std::string_view k : known) found = found || item.key() == k;
    if (!found) {
      std::string list;
      for (std::string_view k : known) list += (list.empty() ? "" : ", ") + std::string(k);
      return InvalidArgumentError("unknown key \"" + Printable(item.key(), 60) + "\"" +
                                  (path.empty() ? "" : " in " + path) + " (known: " + list + ")");
    }
  }
  return Status::Ok();
}

Result<double> GetNumber(const json& j, const std::string& path) {
  if (!j.is_number()) return FieldError(path, "must be a number, got " + TypeOf(j));
  const double v = j.get<double>();
  if (!std::isfinite(v)) return FieldError(path, "must be finite");
  return v;
}

Result<double> GetNumberIn(const json& j, const std::string& path, double lo, double hi) {
  OCTO_ASSIGN_OR_RETURN(double v, GetNumber(j, path));
  if (v < lo || v > hi) {
    return FieldError(path, "is " + FormatDouble(v) + ", must be in [" + FormatDouble(lo) + ", " +
                                FormatDouble(hi) + "]");
  }
  return v;
}

Result<int64_t> GetInteger(const json& j, const std::string& path, int64_t lo, int64_t hi) {
  if (!j.is_number_integer()) {
    return FieldError(path, "must be an integer, got " +
                                (j.is_number_float() ? Printable(j.dump(), 40) : TypeOf(j)));
  }
  if (j.is_number_unsigned() && j.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX)) {
    return FieldError(path, "is " + Printable(j.dump(), 40) + ", too large");
  }
  const int64_t v = j.get<int64_t>();
  if (v < lo || v > hi) {
    return FieldError(path, "is " + std::to_string(v) + ", must be in " + std::to_string(lo) +
                                ".." + std::to_string(hi));
  }
  return v;
}

Result<bool> GetBool(const json& j, const std::string& path) {
  if (!j.is_boolean()) return FieldError(path, "must be true or false, got " + TypeOf(j));
  return j.get<bool>();
}

Result<std::string> GetString(const json& j, const std::string& path) {
  if (!j.is_string()) return FieldError(path, "must be a string, got " + TypeOf(j));
  return j.get<std::string>();
}

Status CheckArray(const json& j, const std::string& path, size_t length) {
  if (!j.is_array()) return FieldError(path, "must be an array, got " + TypeOf(j));
  if (j.size() != length) {
    return FieldError(
        path, "must have " + std::to_string(length) + " elements, has " + std::to_string(j.size()));
  }
  return Status::Ok();
}

Result<std::vector<double>> GetNumbers(const json& j, const std::string& path, size_t n, double lo,
                                       double hi) {
  OCTO_RETURN_IF_ERROR(CheckArray(j, path, n));
  std::vector<double> out(n);
  for (size_t i = 0; i < n; ++i) {
    OCTO_ASSIGN_OR_RETURN(out[i], GetNumberIn(j[i], Index(path, i), lo, hi));
  }
  return out;
}

}  // namespace octoscope::protocol
