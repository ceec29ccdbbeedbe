#include "protocol/serve_config.h"

#include "protocol/json_fields.h"

namespace octoscope::protocol {
namespace {

Result<std::vector<std::string>> GetStrings(const nlohmann::json& j, const std::string& path) {
  if (!j.is_array()) return FieldError(path, "must be an array of strings, is " + TypeOf(j));
  std::vector<std::string> out;
  for (size_t i = 0; i < j.size(); ++i) {
    auto s = GetString(j[i], Index(path, i));
    if (!s.ok()) return s.status();
    out.push_back(*s);
  }
  return out;
}

}  // namespace

Result<ServeConfig> ParseServeConfig(std::string_view text, std::string_view what) {
  auto doc = ParseJsonObject(text, what, kMaxServeConfigBytes, 8);
  if (!doc.ok()) return doc.status();
  const nlohmann::json& j = *doc;
  OCTO_RETURN_IF_ERROR(CheckKeys(
      j, "",
      {"data", "watch", "demo", "cache", "bind", "port", "token", "token-file", "ram-mb",
       "device-mb", "device", "web", "io-threads", "max-upload-mb", "demo-size", "demo-rate"}));
  ServeConfig config;
  auto strings = [&](const char* key, std::vector<std::string>* out) -> Status {
    if (!j.contains(key)) return Status::Ok();
    auto v = GetStrings(j.at(key), key);
    if (!v.ok()) return v.status();
    *out = std::move(*v);
    return Status::Ok();
  };
  auto string = [&](const char* key, std::optional<std::string>* out) -> Status {
    if (!j.contains(key)) return Status::Ok();
    auto v = GetString(j.at(key), key);
    if (!v.ok()) return v.status();
    *out = std::move(*v);
    return Status::Ok();
  };
  auto integer = [&](const char* key, int64_t lo, int64_t hi,
                     std::optional<int64_t>* out) -> Status {
    if (!j.contains(key)) return Status::Ok();
    auto v = GetInteger(j.at(key), key, lo, hi);
    if (!v.ok()) return v.status();
    *out = *v;
    return Status::Ok();
  };
  OCTO_RETURN_IF_ERROR(strings("data", &config.data));
  OCTO_RETURN_IF_ERROR(strings("watch", &config.watch));
  if (j.contains("demo")) {
    auto v = GetBool(j.at("demo"), "demo");
    if (!v.ok()) return v.status();
    config.demo = *v;
  }
  OCTO_RETURN_IF_ERROR(string("cache", &config.cache));
  OCTO_RETURN_IF_ERROR(string("bind", &config.bind));
  OCTO_RETURN_IF_ERROR(integer("port", 0, 65535, &config.port));
  OCTO_RETURN_IF_ERROR(string("token", &config.token));
  OCTO_RETURN_IF_ERROR(string("token-file", &config.token_file));
  OCTO_RETURN_IF_ERROR(integer("ram-mb", 64, int64_t{1} << 24, &config.ram_mb));
  OCTO_RETURN_IF_ERROR(integer("device-mb", 0, int64_t{1} << 24, &config.device_mb));
  OCTO_RETURN_IF_ERROR(string("device", &config.device));
  OCTO_RETURN_IF_ERROR(string("web", &config.web));
  OCTO_RETURN_IF_ERROR(integer("io-threads", 1, 64, &config.io_threads));
  OCTO_RETURN_IF_ERROR(integer("max-upload-mb", 1, int64_t{1} << 20, &config.max_upload_mb));
  if (j.contains("demo-size")) {
    auto v = GetNumbers(j.at("demo-size"), "demo-size", 3, 16, 4096);
    if (!v.ok()) return v.status();
    std::vector<int64_t> size;
    for (size_t i = 0; i < 3; ++i) {
      auto n = GetInteger(j.at("demo-size")[i], Index("demo-size", i), 16, 4096);
      if (!n.ok()) return n.status();
      size.push_back(*n);
    }
    config.demo_size = size;
  }
  if (j.contains("demo-rate")) {
    auto v = GetNumberIn(j.at("demo-rate"), "demo-rate", 1e-3, 1000);
    if (!v.ok()) return v.status();
    config.demo_rate = *v;
  }
  return config;
}

}  // namespace octoscope::protocol
