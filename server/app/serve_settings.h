// ServeSettings: the options of `octoscope serve`, from the flags and the --config file (a flag
// on the command line wins over the file; docs/server.md "Configuration"), with defaults
// resolved and checked: the cache folder, the web client's folder, the admin token (given, read
// from a file, or a fresh random 128-bit one when there are no users), the users, the public URL,
// trusted proxies, the state folder, the session and connection limits, the allowed web origins,
// and the safety rule that a
// non-loopback bind needs an explicit token or users.
//
// Thread safety: functions of the main thread at start-up.
#ifndef OCTOSCOPE_APP_SERVE_SETTINGS_H_
#define OCTOSCOPE_APP_SERVE_SETTINGS_H_

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "app/access_control.h"
#include "app/flags.h"
#include "util/result.h"

namespace octoscope::app {

// The limits of a shared server that the session layer enforces (docs/server.md).
struct ServerLimits {
  int max_sessions = 64;
  int max_participants = 16;  // Per session.
  // A session with no participant, and a dataset no session uses, is released after this long.
  std::chrono::seconds idle_timeout{900};
  // Per principal (docs/server.md, "Threat model"): sessions one user (or one view link) holds,
  // unfinished streams one user created, view links one user owns and may make per minute.
  int max_sessions_per_user = 16;
  int max_streams_per_user = 8;
  int max_view_links_per_user = 1000;
  int view_links_per_minute = 20;
  // Per participant: screenshots rendering at once, messages per second (bursts of twice that).
  int max_screenshots_in_flight = 2;
  int max_messages_per_second = 200;
};

struct ServeSettings {
  std::vector<std::filesystem::path> data_dirs;
  std::vector<std::filesystem::path> watch_dirs;
  bool demo = false;
  std::array<int64_t, 3> demo_size{256, 256, 160};
  double demo_rate = 5;  // Planes (all channels) per second.
  std::filesystem::path cache_dir;
  std::filesystem::path web_root;
  std::string bind = "127.0.0.1";
  uint16_t port = 8080;
  std::string token;
  bool token_generated = false;
  uint64_t ram_mb = 0;
  uint64_t device_mb = 0;  // 0 = automatic.
  std::string device;      // OpenCL device preference ("" = best).
  int io_threads = 2;
  int encoder_threads = 2;
  uint64_t max_upload_mb = 1024;
  // "" = http://BIND:PORT/; else the checked URL with a trailing slash (PublicBaseUrl).
  std::string public_url;
  std::vector<std::string> trusted_proxies;  // Addresses or CIDRs (checked).
  // The users (empty: only the admin token). users_file is set when they came from a file
  // (re-read on SIGHUP).
  std::vector<User> users;
  std::filesystem::path users_file;
  std::filesystem::path state_dir;  // View links and other durable state.
  ServerLimits limits;
  // Connections (net::ServerOptions): caps, and the web origins besides the server's own whose
  // pages may open WebSockets (checked).
  size_t max_connections = 1024;
  size_t max_connections_per_address = 64;
  std::vector<std::string> allowed_origins;
};

void AddServeFlags(Flags& flags);

// kInvalidArgument for contradictory or unsafe options (exit 64), other errors for files that
// cannot be read (exit 2).
Result<ServeSettings> ResolveServeSettings(const Flags& flags);

// The base of every URL the server prints or puts in links: --public-url, else http://HOST:PORT/.
std::string PublicBaseUrl(const ServeSettings& settings, uint16_t port);
// The URL to open: BASE?token=TOKEN[&dataset=ID] (no token when there is no admin token).
std::string ServeUrl(const ServeSettings& settings, uint16_t port, const std::string& dataset);

// True for 127.0.0.0/8, ::1 and "localhost".
bool IsLoopback(const std::string& address);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_SERVE_SETTINGS_H_
