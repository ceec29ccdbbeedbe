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

bool IsNameChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
         c == '_' || c == '-';
}

bool Digits(std::string_view text, size_t at, size_t n, int* out) {
  if (at + n > text.size()) return false;
  int v = 0;
  for (size_t i = at; i < at + n; ++i) {
    if (text[i] < '0' || text[i] > '9') return false;
    v = v * 10 + (text[i] - '0');
  }
  *out = v;
  return true;
}

// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's days_from_civil).
int64_t DaysFromCivil(int64_t y, int m, int d) {
  y -= m <= 2;
  const int64_t era = (y >= 0 ? y : y - 399) / 400;
  const int64_t yoe = y - era * 400;
  const int64_t doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
  const int64_t doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
  return era * 146097 + doe - 719468;
}

Result<UserConfig> ParseUser(const nlohmann::json& j, const std::string& path) {
  OCTO_RETURN_IF_ERROR(CheckObject(j, path));
  OCTO_RETURN_IF_ERROR(
      CheckKeys(j, path, {"name", "token", "token-file", "folders", "admin", "expires"}));
  UserConfig user;
  OCTO_ASSIGN_OR_RETURN(const nlohmann::json* name, Require(j, path, "name"));
  OCTO_ASSIGN_OR_RETURN(user.name, GetString(*name, Join(path, "name"), 64, true));
  if (user.name.empty()) return FieldError(Join(path, "name"), "must not be empty");
  for (char c : user.name) {
    if (!IsNameChar(c)) return FieldError(Join(path, "name"), "may hold only A-Z a-z 0-9 . _ -");
  }
  if (j.contains("token")) {
    OCTO_ASSIGN_OR_RETURN(user.token, GetString(j.at("token"), Join(path, "token"), 256, true));
  }
  if (j.contains("token-file")) {
    OCTO_ASSIGN_OR_RETURN(user.token_file,
                          GetString(j.at("token-file"), Join(path, "token-file"), 4096, true));
  }
  if (user.token.has_value() == user.token_file.has_value()) {
    return FieldError(path, "give exactly one of \"token\" and \"token-file\"");
  }
  if (j.contains("folders")) {
    const nlohmann::json& f = j.at("folders");
    const std::string fpath = Join(path, "folders");
    if (!f.is_array()) return FieldError(fpath, "must be an array of strings, is " + TypeOf(f));
    for (size_t i = 0; i < f.size(); ++i) {
      OCTO_ASSIGN_OR_RETURN(std::string folder, GetString(f[i], Index(fpath, i), 4096, true));
      if (folder.empty()) return FieldError(Index(fpath, i), "must not be empty");
      user.folders.push_back(std::move(folder));
    }
  }
  if (j.contains("admin")) {
    OCTO_ASSIGN_OR_RETURN(user.admin, GetBool(j.at("admin"), Join(path, "admin")));
  }
  if (j.contains("expires")) {
    OCTO_ASSIGN_OR_RETURN(std::string text,
                          GetString(j.at("expires"), Join(path, "expires"), 64, true));
    OCTO_ASSIGN_OR_RETURN(user.expires_unix_s, ParseRfc3339Utc(text, Join(path, "expires")));
  }
  return user;
}

Result<std::vector<UserConfig>> ParseUsers(const nlohmann::json& j, const std::string& path) {
  if (!j.is_array()) return FieldError(path, "must be an array of users, is " + TypeOf(j));
  if (j.size() > kMaxUsers) {
    return FieldError(path, "more than " + std::to_string(kMaxUsers) + " users");
  }
  std::vector<UserConfig> users;
  for (size_t i = 0; i < j.size(); ++i) {
    OCTO_ASSIGN_OR_RETURN(UserConfig user, ParseUser(j[i], Index(path, i)));
    for (const UserConfig& other : users) {
      if (other.name == user.name) {
        return FieldError(Index(path, i), "user \"" + user.name + "\" is listed twice");
      }
    }
    users.push_back(std::move(user));
  }
  return users;
}

}  // namespace

Result<int64_t> ParseRfc3339Utc(std::string_view text, const std::string& path) {
  // YYYY-MM-DDTHH:MM:SS[.fraction]Z
  int year = 0, month = 0, day = 0, hour = 0, minute = 0, second = 0;
  bool ok = text.size() >= 20 && Digits(text, 0, 4, &year) && text[4] == '-' &&
            Digits(text, 5, 2, &month) && text[7] == '-' && Digits(text, 8, 2, &day) &&
            (text[10] == 'T' || text[10] == 't') && Digits(text, 11, 2, &hour) && text[13] == ':' &&
            Digits(text, 14, 2, &minute) && text[16] == ':' && Digits(text, 17, 2, &second);
  size_t at = 19;
  if (ok && text[at] == '.') {
    ++at;
    const size_t first = at;
    while (at < text.size() && text[at] >= '0' && text[at] <= '9') ++at;
    ok = at > first;
  }
  ok = ok && at + 1 == text.size() && (text[at] == 'Z' || text[at] == 'z');
  if (!ok) {
    return FieldError(path, "expected an RFC 3339 UTC time like \"2027-01-31T00:00:00Z\", got " +
                                Quote(OneLine(text, 40)));
  }
  static constexpr int kDays[] = {31, 29, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31};
  const bool leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
  if (month < 1 || month > 12 || day < 1 || day > kDays[month - 1] ||
      (month == 2 && day == 29 && !leap) || hour > 23 || minute > 59 || second > 60) {
    return FieldError(path, "no such date or time: " + Quote(OneLine(text, 40)));
  }
  // A leap second counts as the next second's start.
  return DaysFromCivil(year, month, day) * 86400 + hour * 3600 + minute * 60 + second;
}

Result<std::vector<UserConfig>> ParseUsersFile(std::string_view text, std::string_view what) {
  if (text.size() > kMaxServeConfigBytes) {
    return InvalidArgumentError(std::string(what) + ": " + std::to_string(text.size()) +
                                " bytes, larger than " + std::to_string(kMaxServeConfigBytes));
  }
  Result<nlohmann::json> doc = ParseJsonLimited(text, 8);
  if (!doc.ok()) return InvalidArgumentError(std::string(what) + ": " + doc.status().message());
  Result<std::vector<UserConfig>> users = ParseUsers(*doc, "users");
  if (!users.ok()) return InvalidArgumentError(std::string(what) + ": " + users.status().message());
  return users;
}

Result<ServeConfig> ParseServeConfig(std::string_view text, std::string_view what) {
  auto doc = ParseJsonObject(text, what, kMaxServeConfigBytes, 8);
  if (!doc.ok()) return doc.status();
  const nlohmann::json& j = *doc;
  OCTO_RETURN_IF_ERROR(CheckKeys(j, "",
                                 {"data",
                                  "watch",
                                  "demo",
                                  "cache",
                                  "bind",
                                  "port",
                                  "token",
                                  "token-file",
                                  "ram-mb",
                                  "device-mb",
                                  "device",
                                  "web",
                                  "io-threads",
                                  "max-upload-mb",
                                  "demo-size",
                                  "demo-rate",
                                  "public-url",
                                  "trusted-proxy",
                                  "users",
                                  "users-file",
                                  "state-dir",
                                  "max-sessions",
                                  "max-participants",
                                  "idle-timeout-s",
                                  "max-sessions-per-user",
                                  "max-streams-per-user",
                                  "max-view-links-per-user",
                                  "view-links-per-minute",
                                  "max-screenshots-in-flight",
                                  "max-messages-per-second",
                                  "max-connections",
                                  "max-connections-per-address",
                                  "allowed-origins"}));
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
  OCTO_RETURN_IF_ERROR(string("public-url", &config.public_url));
  OCTO_RETURN_IF_ERROR(strings("trusted-proxy", &config.trusted_proxy));
  if (j.contains("users")) {
    OCTO_ASSIGN_OR_RETURN(config.users, ParseUsers(j.at("users"), "users"));
  }
  OCTO_RETURN_IF_ERROR(string("users-file", &config.users_file));
  if (config.users && config.users_file) {
    return InvalidArgumentError(std::string(what) + ": give \"users\" or \"users-file\", not both");
  }
  OCTO_RETURN_IF_ERROR(string("state-dir", &config.state_dir));
  OCTO_RETURN_IF_ERROR(integer("max-sessions", 1, 100000, &config.max_sessions));
  OCTO_RETURN_IF_ERROR(integer("max-participants", 1, 1000, &config.max_participants));
  OCTO_RETURN_IF_ERROR(integer("idle-timeout-s", 1, 30 * 86400, &config.idle_timeout_s));
  OCTO_RETURN_IF_ERROR(
      integer("max-sessions-per-user", 1, 100000, &config.max_sessions_per_user));
  OCTO_RETURN_IF_ERROR(integer("max-streams-per-user", 1, 100000, &config.max_streams_per_user));
  OCTO_RETURN_IF_ERROR(
      integer("max-view-links-per-user", 1, 10000000, &config.max_view_links_per_user));
  OCTO_RETURN_IF_ERROR(
      integer("view-links-per-minute", 1, 100000, &config.view_links_per_minute));
  OCTO_RETURN_IF_ERROR(
      integer("max-screenshots-in-flight", 1, 64, &config.max_screenshots_in_flight));
  OCTO_RETURN_IF_ERROR(
      integer("max-messages-per-second", 10, 100000, &config.max_messages_per_second));
  OCTO_RETURN_IF_ERROR(integer("max-connections", 1, kMaxConnections, &config.max_connections));
  OCTO_RETURN_IF_ERROR(integer("max-connections-per-address", 1, kMaxConnections,
                               &config.max_connections_per_address));
  OCTO_RETURN_IF_ERROR(strings("allowed-origins", &config.allowed_origins));
  return config;
}

}  // namespace octoscope::protocol
