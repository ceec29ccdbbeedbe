// ServeConfig: the configuration file of `octoscope serve --config FILE` (docs/server.md,
// "Configuration"): a JSON object whose keys are the long flag names (every option is also a
// flag; a flag given on the command line wins). Strict: unknown keys, wrong types and values out
// of range are errors naming the key.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_
#define OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::protocol {

inline constexpr uint64_t kMaxServeConfigBytes = 1 << 20;

// One user of a shared server (docs/server.md, "Users and access").
struct UserConfig {
  std::string name;                       // [A-Za-z0-9._-]{1,64}, unique.
  std::optional<std::string> token;       // Exactly one of token and token_file.
  std::optional<std::string> token_file;  // Its first line is the token.
  std::vector<std::string> folders;       // The user sees the datasets under these.
  bool admin = false;                     // Sees every dataset, /metrics.
  std::optional<int64_t> expires_unix_s;  // "expires": RFC 3339 UTC, e.g. "2027-01-31T00:00:00Z".
};

inline constexpr size_t kMaxUsers = 10000;

struct ServeConfig {
  std::vector<std::string> data;   // "data": [folders].
  std::vector<std::string> watch;  // "watch": [folders].
  std::optional<bool> demo;
  std::optional<std::string> cache;
  std::optional<std::string> bind;
  std::optional<int64_t> port;  // [0, 65535].
  std::optional<std::string> token;
  std::optional<std::string> token_file;
  std::optional<int64_t> ram_mb;     // [64, 2^24].
  std::optional<int64_t> device_mb;  // [0, 2^24].
  std::optional<std::string> device;
  std::optional<std::string> web;
  std::optional<int64_t> io_threads;              // [1, 64].
  std::optional<int64_t> max_upload_mb;           // [1, 2^20].
  std::optional<std::vector<int64_t>> demo_size;  // [x, y, z], each [16, 4096].
  std::optional<double> demo_rate;                // Planes per second, (0, 1000].
  std::optional<std::string> public_url;          // http(s)://host[:port][/prefix]/
  std::vector<std::string> trusted_proxy;         // Addresses or CIDRs.
  std::optional<std::vector<UserConfig>> users;
  std::optional<std::string> users_file;
  std::optional<std::string> state_dir;
  std::optional<int64_t> max_sessions;      // [1, 100000].
  std::optional<int64_t> max_participants;  // [1, 1000].
  std::optional<int64_t> idle_timeout_s;    // [1, 30 days].
  // Per-principal limits (docs/server.md, "Threat model").
  std::optional<int64_t> max_sessions_per_user;      // [1, 100000].
  std::optional<int64_t> max_streams_per_user;       // [1, 100000].
  std::optional<int64_t> max_view_links_per_user;    // [1, 10^7].
  std::optional<int64_t> view_links_per_minute;      // [1, 100000].
  std::optional<int64_t> max_screenshots_in_flight;  // [1, 64].
  std::optional<int64_t> max_messages_per_second;    // [10, 100000].
  // Connections: caps, and the web origins besides the server's own whose pages may open
  // WebSockets (origins or URLs, checked by net::OriginPolicy).
  std::optional<int64_t> max_connections;              // [1, kMaxConnections].
  std::optional<int64_t> max_connections_per_address;  // [1, kMaxConnections].
  std::vector<std::string> allowed_origins;
};

inline constexpr int64_t kMaxConnections = 1000000;

// "2027-01-31T00:00:00Z" (RFC 3339 in UTC, optional fraction of a second, "z" or "Z") as seconds
// since 1970; kInvalidArgument naming `path` otherwise.
Result<int64_t> ParseRfc3339Utc(std::string_view text, const std::string& path);

// The users file: a JSON array of users as in the config's "users" (at most kMaxUsers).
Result<std::vector<UserConfig>> ParseUsersFile(std::string_view text, std::string_view what);

// `what` names the file in errors.
Result<ServeConfig> ParseServeConfig(std::string_view text, std::string_view what);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_
