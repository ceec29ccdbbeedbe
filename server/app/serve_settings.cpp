#include "app/serve_settings.h"

#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "app/access_control.h"
#include "net/origin_policy.h"
#include "net/trusted_proxies.h"
#include "protocol/serve_config.h"
#include "util/random_token.h"
#include "util/strings.h"

#ifndef OCTOSCOPE_SOURCE_DIR
#define OCTOSCOPE_SOURCE_DIR ""
#endif

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

fs::path DefaultCacheDir() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg != nullptr && *xdg == '/') {
    return fs::path(xdg) / "octoscope";
  }
  if (const char* home = std::getenv("HOME"); home != nullptr && *home == '/') {
    return fs::path(home) / ".cache" / "octoscope";
  }
  return fs::current_path() / "octoscope-cache";
}

// The web client beside the installed binary, in the checkout the build folder lies in, or the
// source tree the binary was built from.
fs::path DefaultWebRoot() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  std::vector<fs::path> candidates;
  if (!ec) {
    candidates = {exe.parent_path() / "web", exe.parent_path().parent_path() / "web",
                  exe.parent_path().parent_path() / "share" / "octoscope" / "web"};
  }
  if (*OCTOSCOPE_SOURCE_DIR != '\0') candidates.push_back(fs::path(OCTOSCOPE_SOURCE_DIR) / "web");
  for (const fs::path& c : candidates) {
    if (fs::is_regular_file(c / "index.html", ec)) return c;
  }
  return {};
}

fs::path DefaultStateDir() {
  if (const char* xdg = std::getenv("XDG_STATE_HOME"); xdg != nullptr && *xdg == '/') {
    return fs::path(xdg) / "octoscope";
  }
  if (const char* home = std::getenv("HOME"); home != nullptr && *home == '/') {
    return fs::path(home) / ".local" / "state" / "octoscope";
  }
  return fs::current_path() / "octoscope-state";
}

// http(s)://HOST[:PORT][/PATH]: the base of the URLs the server prints and puts in links; a
// trailing slash is added.
Result<std::string> CheckPublicUrl(std::string url) {
  const bool http = url.starts_with("http://"), https = url.starts_with("https://");
  const size_t host_at = https ? 8 : 7;
  if ((!http && !https) || url.size() <= host_at || url[host_at] == '/') {
    return InvalidArgumentError("--public-url: expected http(s)://HOST[:PORT][/PATH/], got '" +
                                url + "'");
  }
  for (char c : url) {
    if (static_cast<unsigned char>(c) <= ' ' || c == '?' || c == '#' || c == '"' || c == '<' ||
        c == '>' || c == '\\' || static_cast<unsigned char>(c) >= 0x7f) {
      return InvalidArgumentError(
          "--public-url: no spaces, quotes, '?' or '#' (query and fragment are the server's)");
    }
  }
  if (!url.ends_with('/')) url += '/';
  return url;
}

uint64_t DefaultRamMb() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return 1024;
  const uint64_t total_mb = static_cast<uint64_t>(pages) * static_cast<uint64_t>(page) >> 20;
  // A quarter of the machine, as the paper's viewer on a shared lab PC: the rest stays for the
  // acquisition software and the OS page cache.
  return std::max<uint64_t>(256, total_mb / 4);
}

}  // namespace

void AddServeFlags(Flags& flags) {
  flags.AddValue("data", "DIR", "serve every scan under DIR (repeatable)");
  flags.AddSwitch("demo", "stream the built-in demo specimen in like an acquisition");
  flags.AddValue("demo-size", "X,Y,Z", "size of the demo specimen", "256,256,160");
  flags.AddValue("demo-rate", "PLANES", "demo planes per second", "5");
  flags.AddValue("watch", "DIR",
                 "stream in the TIFF planes an acquisition writes into DIR (repeatable)");
  flags.AddValue("cache", "DIR", "octree caches, one folder per dataset",
                 "$XDG_CACHE_HOME/octoscope");
  flags.AddValue("bind", "ADDR", "address to listen on", "127.0.0.1");
  flags.AddValue("port", "N", "port (0 picks a free one)", "8080");
  flags.AddValue("token", "T", "access token (default: a random 128-bit one, printed in the URL)");
  flags.AddValue("token-file", "F", "read the access token from the first line of F");
  flags.AddValue("config", "FILE", "JSON file with any of these options (flags win)");
  flags.AddValue("ram-mb", "N", "RAM budget of all datasets' page caches", "a quarter of RAM");
  flags.AddValue("device-mb", "N", "device memory for bricks", "automatic");
  flags.AddValue("device", "PREF", "OpenCL device: gpu, cpu, N, P:D or name text", "best");
  flags.AddValue("web", "DIR", "the web client's files", "web/ beside the binary");
  flags.AddValue("io-threads", "N", "network I/O threads", "2");
  flags.AddValue("max-upload-mb", "N", "largest slab upload", "1024");
  flags.AddValue("public-url", "URL",
                 "base of the URLs printed and put in share/view links (behind a proxy)",
                 "http://BIND:PORT/");
  flags.AddValue("trusted-proxy", "ADDR",
                 "believe X-Forwarded-For/-Proto from this address or CIDR network (repeatable)");
  flags.AddValue("users", "JSON", "the users as a JSON array (as the config's \"users\")");
  flags.AddValue("users-file", "F", "read the users from the JSON file F (again on SIGHUP)");
  flags.AddValue("state-dir", "DIR", "durable server state (view links); back it up",
                 "$XDG_STATE_HOME/octoscope");
  flags.AddValue("max-sessions", "N", "viewing sessions at once", "64");
  flags.AddValue("max-participants", "N", "participants of one session", "16");
  flags.AddValue("idle-timeout-s", "S",
                 "release sessions nobody is connected to and datasets nobody views after S s",
                 "900");
  flags.AddValue("max-sessions-per-user", "N", "sessions one user or view link holds", "16");
  flags.AddValue("max-streams-per-user", "N", "unfinished streams one user created", "8");
  flags.AddValue("max-view-links-per-user", "N", "view links one user owns", "1000");
  flags.AddValue("view-links-per-minute", "N", "view links one user may save per minute", "20");
  flags.AddValue("max-screenshots-in-flight", "N", "screenshots one participant renders at once",
                 "2");
  flags.AddValue("max-messages-per-second", "N",
                 "messages one participant may send per second (bursts of twice that)", "200");
  flags.AddValue("max-connections", "N", "open connections in all (503 beyond)", "1024");
  flags.AddValue("max-connections-per-address", "N",
                 "open connections per client address (503 beyond)", "64");
  flags.AddValue("allowed-origins", "URL",
                 "pages of this origin may open WebSockets too, besides the public URL's "
                 "(repeatable, or comma-separated)");
}

Result<ServeSettings> ResolveServeSettings(const Flags& flags) {
  ServeSettings s;
  protocol::ServeConfig config;
  if (auto path = flags.Get("config")) {
    std::ifstream in(*path, std::ios::binary);
    if (!in) return NotFoundError(*path + ": cannot read the config file");
    std::ostringstream text;
    text << in.rdbuf();
    auto parsed = protocol::ParseServeConfig(text.str(), *path);
    if (!parsed.ok()) return InvalidArgumentError(parsed.status().message());
    config = std::move(*parsed);
  }
  // Flags win over the file.
  auto text = [&](const char* flag, const std::optional<std::string>& from_config) {
    if (auto v = flags.Get(flag)) return std::optional<std::string>(*v);
    return from_config;
  };
  auto integer = [&](const char* flag, const std::optional<int64_t>& from_config, int64_t fallback,
                     int64_t lo, int64_t hi) -> Result<int64_t> {
    if (flags.Has(flag)) return flags.GetInt(flag, fallback, lo, hi);
    return from_config.value_or(fallback);
  };

  for (const std::string& d : flags.Has("data") ? flags.GetAll("data") : config.data) {
    s.data_dirs.push_back(d);
  }
  for (const std::string& d : flags.Has("watch") ? flags.GetAll("watch") : config.watch) {
    s.watch_dirs.push_back(d);
  }
  s.demo = flags.Has("demo") || config.demo.value_or(false);
  if (auto v = flags.Get("demo-size")) {
    std::array<int64_t, 3> size{};
    std::istringstream in(*v);
    char comma1 = 0, comma2 = 0;
    if (!(in >> size[0] >> comma1 >> size[1] >> comma2 >> size[2]) || comma1 != ',' ||
        comma2 != ',' || !in.eof()) {
      return InvalidArgumentError("--demo-size: expected X,Y,Z, got '" + *v + "'");
    }
    for (int64_t n : size) {
      if (n < 16 || n > 4096) return InvalidArgumentError("--demo-size: each in [16, 4096]");
    }
    s.demo_size = size;
  } else if (config.demo_size) {
    s.demo_size = {(*config.demo_size)[0], (*config.demo_size)[1], (*config.demo_size)[2]};
  }
  if (flags.Has("demo-rate")) {
    auto rate = flags.GetDouble("demo-rate", 5);
    if (!rate.ok()) return rate.status();
    if (!(*rate > 0 && *rate <= 1000)) return InvalidArgumentError("--demo-rate: in (0, 1000]");
    s.demo_rate = *rate;
  } else if (config.demo_rate) {
    s.demo_rate = *config.demo_rate;
  }
  for (const fs::path& d : s.data_dirs) {
    std::error_code ec;
    if (!fs::is_directory(d, ec)) return NotFoundError(d.string() + ": not a folder (--data)");
  }
  s.cache_dir = text("cache", config.cache).value_or(DefaultCacheDir().string());
  if (auto web = text("web", config.web)) {
    s.web_root = *web;
    std::error_code ec;
    if (!fs::is_regular_file(s.web_root / "index.html", ec)) {
      return NotFoundError(s.web_root.string() + ": no index.html (--web)");
    }
  } else {
    s.web_root = DefaultWebRoot();
  }
  s.bind = text("bind", config.bind).value_or("127.0.0.1");
  auto port = integer("port", config.port, 8080, 0, 65535);
  if (!port.ok()) return port.status();
  s.port = static_cast<uint16_t>(*port);
  auto ram =
      integer("ram-mb", config.ram_mb, static_cast<int64_t>(DefaultRamMb()), 64, int64_t{1} << 24);
  if (!ram.ok()) return ram.status();
  s.ram_mb = static_cast<uint64_t>(*ram);
  auto device_mb = integer("device-mb", config.device_mb, 0, 0, int64_t{1} << 24);
  if (!device_mb.ok()) return device_mb.status();
  s.device_mb = static_cast<uint64_t>(*device_mb);
  s.device = text("device", config.device).value_or("");
  auto io = integer("io-threads", config.io_threads, 2, 1, 64);
  if (!io.ok()) return io.status();
  s.io_threads = static_cast<int>(*io);
  auto upload = integer("max-upload-mb", config.max_upload_mb, 1024, 1, int64_t{1} << 20);
  if (!upload.ok()) return upload.status();
  s.max_upload_mb = static_cast<uint64_t>(*upload);

  if (auto v = text("public-url", config.public_url)) {
    OCTO_ASSIGN_OR_RETURN(s.public_url, CheckPublicUrl(*v));
  }
  s.trusted_proxies =
      flags.Has("trusted-proxy") ? flags.GetAll("trusted-proxy") : config.trusted_proxy;
  if (auto proxies = net::TrustedProxies::Parse(s.trusted_proxies); !proxies.ok()) {
    return InvalidArgumentError("--" + proxies.status().message());
  }
  s.state_dir = text("state-dir", config.state_dir).value_or(DefaultStateDir().string());
  OCTO_ASSIGN_OR_RETURN(const int64_t max_sessions,
                        integer("max-sessions", config.max_sessions, 64, 1, 100000));
  s.limits.max_sessions = static_cast<int>(max_sessions);
  OCTO_ASSIGN_OR_RETURN(const int64_t max_participants,
                        integer("max-participants", config.max_participants, 16, 1, 1000));
  s.limits.max_participants = static_cast<int>(max_participants);
  OCTO_ASSIGN_OR_RETURN(const int64_t idle,
                        integer("idle-timeout-s", config.idle_timeout_s, 900, 1, 30 * 86400));
  s.limits.idle_timeout = std::chrono::seconds(idle);
  struct PerPrincipal {
    const char* flag;
    const std::optional<int64_t>& config;
    int64_t lo, hi;
    int* out;
  };
  for (const PerPrincipal& p : std::initializer_list<PerPrincipal>{
           {"max-sessions-per-user", config.max_sessions_per_user, 1, 100000,
            &s.limits.max_sessions_per_user},
           {"max-streams-per-user", config.max_streams_per_user, 1, 100000,
            &s.limits.max_streams_per_user},
           {"max-view-links-per-user", config.max_view_links_per_user, 1, 10000000,
            &s.limits.max_view_links_per_user},
           {"view-links-per-minute", config.view_links_per_minute, 1, 100000,
            &s.limits.view_links_per_minute},
           {"max-screenshots-in-flight", config.max_screenshots_in_flight, 1, 64,
            &s.limits.max_screenshots_in_flight},
           {"max-messages-per-second", config.max_messages_per_second, 10, 100000,
            &s.limits.max_messages_per_second}}) {
    OCTO_ASSIGN_OR_RETURN(const int64_t value, integer(p.flag, p.config, *p.out, p.lo, p.hi));
    *p.out = static_cast<int>(value);
  }
  OCTO_ASSIGN_OR_RETURN(
      const int64_t max_connections,
      integer("max-connections", config.max_connections, 1024, 1, protocol::kMaxConnections));
  s.max_connections = static_cast<size_t>(max_connections);
  OCTO_ASSIGN_OR_RETURN(const int64_t per_address,
                        integer("max-connections-per-address", config.max_connections_per_address,
                                64, 1, protocol::kMaxConnections));
  s.max_connections_per_address = static_cast<size_t>(per_address);
  for (const std::string& list :
       flags.Has("allowed-origins") ? flags.GetAll("allowed-origins") : config.allowed_origins) {
    for (std::string_view origin : Split(list, ',')) {
      if (!TrimWhitespace(origin).empty()) s.allowed_origins.emplace_back(TrimWhitespace(origin));
    }
  }
  if (auto origins = net::OriginPolicy::Parse(s.allowed_origins); !origins.ok()) {
    return InvalidArgumentError("--allowed-origins: " + origins.status().message());
  }

  // Users: from --users, --users-file or the config (one of them).
  const auto users_file = text("users-file", config.users_file);
  const bool users_flag = flags.Has("users");
  if (users_flag + users_file.has_value() + (config.users.has_value() && !flags.Has("users-file")) >
      1) {
    return InvalidArgumentError("give the users once: --users, --users-file or \"users\"");
  }
  if (users_flag) {
    OCTO_ASSIGN_OR_RETURN(std::vector<protocol::UserConfig> entries,
                          protocol::ParseUsersFile(*flags.Get("users"), "--users"));
    OCTO_ASSIGN_OR_RETURN(s.users, LoadUsers(entries, "--users"));
  } else if (users_file) {
    s.users_file = *users_file;
    auto loaded = LoadUsersFile(s.users_file);
    if (!loaded.ok()) return loaded.status();
    s.users = std::move(*loaded);
  } else if (config.users) {
    OCTO_ASSIGN_OR_RETURN(s.users, LoadUsers(*config.users, "--config"));
  }
  const bool have_users = users_flag || users_file || config.users;

  // The admin token: given, from a file, or generated (as Jupyter does) when there are no users.
  const auto token = text("token", config.token);
  const auto token_file = text("token-file", config.token_file);
  if (token && token_file) return InvalidArgumentError("give --token or --token-file, not both");
  if (token) {
    s.token = *token;
  } else if (token_file) {
    auto read = ReadTokenFile(*token_file);
    if (!read.ok()) return read.status();
    s.token = *read;
  }
  if (!s.token.empty()) {
    OCTO_RETURN_IF_ERROR(CheckToken(s.token));
  } else if (!have_users) {
    if (!IsLoopback(s.bind)) {
      return InvalidArgumentError("--bind " + s.bind +
                                  " is reachable from other machines: give --token, "
                                  "--token-file or users (a random token is generated only for "
                                  "loopback)");
    }
    auto generated = RandomHex(16);
    if (!generated.ok()) return generated.status();
    s.token = *generated;
    s.token_generated = true;
  }
  OCTO_RETURN_IF_ERROR(CheckUsersBesideAdmin(s.users, s.token));
  return s;
}

bool IsLoopback(const std::string& address) {
  return address == "localhost" || address == "::1" || address.starts_with("127.");
}

std::string PublicBaseUrl(const ServeSettings& settings, uint16_t port) {
  if (!settings.public_url.empty()) return settings.public_url;
  std::string host = settings.bind;
  if (host == "0.0.0.0" || host == "::") {
    char name[256] = {};
    host = gethostname(name, sizeof name - 1) == 0 && name[0] != '\0' ? name : "localhost";
  }
  if (host.find(':') != std::string::npos) host = "[" + host + "]";
  return "http://" + host + ":" + std::to_string(port) + "/";
}

std::string ServeUrl(const ServeSettings& settings, uint16_t port, const std::string& dataset) {
  const std::string url = PublicBaseUrl(settings, port);
  std::string query;
  if (!settings.token.empty()) query = "token=" + settings.token;
  if (!dataset.empty()) query += (query.empty() ? "" : "&") + std::string("dataset=") + dataset;
  return query.empty() ? url : url + "?" + query;
}

}  // namespace octoscope::app
