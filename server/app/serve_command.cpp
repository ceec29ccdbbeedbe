// octoscope serve: the viewer server (docs/server.md). The composition root of the server: it
// reads the flags (and --config), builds the render service, the dataset registry (with the demo
// stream and watched folders), the shared session services and the HTTP/WebSocket server, prints
// the URL to open, re-reads the users file on SIGHUP, and on SIGINT/SIGTERM shuts them down in
// order: no new connections, sessions closed, unfinished streams checkpointed (never finished:
// they go on after the restart) and pages flushed, threads joined.
#include <ifaddrs.h>
#include <netdb.h>
#include <signal.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "app/access_control.h"
#include "app/user_ids.h"
#include "app/view_link_quota.h"
#include "app/api_routes.h"
#include "app/commands.h"
#include "app/flags.h"
#include "app/serve_settings.h"
#include "app/volume_options.h"
#include "app/ws_bridge.h"
#include "dataset/dataset_registry.h"
#include "dataset/demo_stream.h"
#include "dataset/folder_watcher.h"
#include "encode/jpeg_encoder.h"
#include "net/auth.h"
#include "net/origin_policy.h"
#include "net/server.h"
#include "render/device.h"
#include "render/render_service.h"
#include "session/dataset_hub.h"
#include "session/server_metrics.h"
#include "session/session_registry.h"
#include "session/view_session.h"
#include "session/view_store.h"
#include "util/latest_wins_executor.h"
#include "util/logger.h"
#include "util/random_token.h"
#include "util/timer_queue.h"

namespace octoscope::app {
namespace {

constexpr char kVersion[] = "0.1.0";

int Fail(const char* what, const Status& status) {
  std::fprintf(stderr, "octoscope serve: %s: %s\n", what, status.ToString().c_str());
  return kExitBadInput;
}

// Blocks SIGINT, SIGTERM and SIGHUP in this thread and every thread it starts afterwards, so that
// WaitForStopSignal receives them (no handler runs on a random thread).
sigset_t BlockStopSignals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  return set;
}

// The users `access` admits: the settings' users plus the admin token's user "admin".
std::vector<User> UsersWithAdmin(std::vector<User> users, const std::string& token) {
  if (!token.empty()) {
    users.push_back(User{kAdminUserName, token, {}, true, std::nullopt, kAdminUserName});
  }
  return users;
}

// A reload of the users file: validated as at start-up, the ids given, then in force; a bad
// file keeps the users in force.
void ReloadUsers(const ServeSettings& settings, UserIds& ids, AccessControl& access,
                 Logger& logger) {
  if (settings.users_file.empty()) {
    logger.Log(LogLevel::kInfo, "SIGHUP: no users file to re-read");
    return;
  }
  auto users = LoadUsersFile(settings.users_file);
  Status status = users.ok() ? CheckUsersBesideAdmin(*users, settings.token) : users.status();
  if (status.ok()) status = ids.Assign(*users);
  if (!status.ok()) {
    logger.Log(LogLevel::kError, "SIGHUP: keeping the users in force: " + status.message());
    return;
  }
  const size_t n = users->size();
  access.ReplaceUsers(UsersWithAdmin(std::move(*users), settings.token));
  logger.Log(LogLevel::kInfo,
             "SIGHUP: " + std::to_string(n) + " user(s) from " + settings.users_file.string());
}

// The machine's interface addresses (IPv6 ones in brackets), for origins.
std::vector<std::string> LocalAddresses() {
  std::vector<std::string> out;
  ifaddrs* list = nullptr;
  if (getifaddrs(&list) != 0) return out;
  for (ifaddrs* a = list; a != nullptr; a = a->ifa_next) {
    if (a->ifa_addr == nullptr) continue;
    const int family = a->ifa_addr->sa_family;
    if (family != AF_INET && family != AF_INET6) continue;
    char host[NI_MAXHOST];
    const socklen_t size = family == AF_INET ? sizeof(sockaddr_in) : sizeof(sockaddr_in6);
    if (getnameinfo(a->ifa_addr, size, host, sizeof host, nullptr, 0, NI_NUMERICHOST) != 0) continue;
    std::string text = host;
    if (text.find('%') != std::string::npos) continue;  // Link-local with a zone: not in URLs.
    out.push_back(family == AF_INET6 ? "[" + text + "]" : text);
  }
  freeifaddrs(list);
  return out;
}

int WaitForStopSignal(const sigset_t& set) {
  int signal = 0;
  while (sigwait(&set, &signal) != 0) {
  }
  return signal;
}

// What a WebSocket connection authenticated as (the Authenticator's Principal): a user, a share
// link or a view link, and the grant a session it creates is owned under.
WsCredential ConnectionCredential(const AccessControl& access, const net::WsConnectInfo& info) {
  WsCredential credential;
  credential.user = info.principal.user;
  credential.credential = info.principal.credential;
  credential.grant = access.GrantOf(info.principal).value_or(protocol::GrantRef{});
  switch (info.principal.kind) {
    case net::Principal::Kind::kUser:
      credential.kind = WsCredential::Kind::kUser;
      break;
    case net::Principal::Kind::kShare:
      credential.kind = WsCredential::Kind::kShare;
      break;
    case net::Principal::Kind::kView:
      credential.kind = WsCredential::Kind::kView;
      break;
  }
  return credential;
}

}  // namespace

int RunServe(std::span<const std::string> args) {
  Flags flags("octoscope serve [options]",
              "Serves the browser viewer: datasets under --data folders (built into octree\n"
              "caches on first view), the built-in demo (--demo, streamed in like an\n"
              "acquisition), folders an acquisition writes TIFF planes into (--watch), and\n"
              "streams sent over the HTTP API. Prints the URL to open (with the access token). "
              "docs/server.md.");
  AddServeFlags(flags);
  if (Status status = flags.Parse(args); !status.ok()) {
    std::fprintf(stderr, "%s: %s\n\n%s", flags.command().c_str(), status.message().c_str(),
                 flags.Help().c_str());
    return kExitUsage;
  }
  if (flags.help_requested()) {
    std::fputs(flags.Help().c_str(), stdout);
    return kExitOk;
  }
  auto settings = ResolveServeSettings(flags);
  if (!settings.ok()) {
    std::fprintf(stderr, "octoscope serve: %s\n", settings.status().message().c_str());
    return settings.status().code() == StatusCode::kInvalidArgument ? kExitUsage : kExitBadInput;
  }
  const sigset_t stop_signals = BlockStopSignals();
  StreamLogger logger(stderr, LogLevel::kInfo);

  // The device and its render thread.
  auto device = render::ChooseDevice(settings->device);
  if (!device.ok()) return Fail("no OpenCL device", device.status());
  auto context = render::ComputeContext::Create(*device);
  if (!context.ok()) return Fail("OpenCL", context.status());
  render::RenderServiceOptions render_options;
  render_options.device_memory_bytes = settings->device_mb << 20;
  auto renderer = render::RenderService::Create(std::move(*context), render_options);
  if (!renderer.ok()) return Fail("render service", renderer.status());

  // Datasets.
  dataset::RegistryOptions registry_options;
  registry_options.data_dirs = settings->data_dirs;
  registry_options.cache_root = settings->cache_dir;
  registry_options.ram_bytes = settings->ram_mb << 20;
  registry_options.open = DefaultOpenOptions();
  registry_options.state_dir = settings->state_dir;  // Stream records: streams outlive restarts.
  auto registry = dataset::DatasetRegistry::Create(registry_options);
  if (!registry.ok()) return Fail("datasets", registry.status());
  for (const std::string& message : (*registry)->restore_messages()) {
    logger.Log(LogLevel::kWarning, message);
  }
  std::unique_ptr<dataset::DemoStream> demo;
  std::string open_dataset;
  if (settings->demo) {
    dataset::DemoOptions demo_options;
    demo_options.size = settings->demo_size;
    demo_options.planes_per_second = settings->demo_rate;
    auto started = dataset::DemoStream::Start(registry->get(), demo_options);
    if (!started.ok()) return Fail("demo", started.status());
    demo = std::move(*started);
    open_dataset = demo->dataset_id();
  }
  std::vector<std::unique_ptr<dataset::FolderWatcher>> watchers;
  for (const auto& dir : settings->watch_dirs) {
    auto watcher = dataset::FolderWatcher::Start(registry->get(), dir, &logger);
    if (!watcher.ok()) return Fail("--watch", watcher.status());
    watchers.push_back(std::move(*watcher));
  }

  // Session services.
  session::ServerMetrics metrics;
  session::HubOptions hub_options;
  hub_options.idle_timeout = settings->limits.idle_timeout;
  hub_options.on_release = [registry = registry->get()] { registry->Rebalance(); };
  auto hub = std::make_unique<session::DatasetHub>(
      renderer->get(),
      [registry = registry->get()](std::string_view id) {
        auto opened = registry->Open(id);
        return opened.ok() ? *opened : nullptr;
      },
      hub_options);
  LatestWinsExecutor encoders(settings->encoder_threads);
  encode::JpegEncoderPool jpeg_encoders;
  auto uploads = std::make_unique<LatestWinsExecutor>(2);
  // View links' disk I/O (durable writes, reads, deletes): its own thread, never the encoders'.
  auto state_io = std::make_unique<LatestWinsExecutor>(1);
  TimerQueue timers;
  session::SessionContext session_context;
  session_context.renderer = renderer->get();
  session_context.datasets = hub.get();
  session_context.encoders = &encoders;
  session_context.jpeg = &jpeg_encoders;
  session_context.timers = &timers;
  session_context.metrics = &metrics;
  session_context.server_version = kVersion;
  // Sharing: view links in the state folder, sessions within their limits.
  auto views = session::ViewStore::Open(settings->state_dir);
  if (!views.ok()) return Fail("--state-dir", views.status());
  session::SessionLimits limits;
  limits.max_sessions = settings->limits.max_sessions;
  limits.max_sessions_per_owner = settings->limits.max_sessions_per_user;
  limits.idle_timeout = settings->limits.idle_timeout;
  auto sessions = std::make_unique<session::SessionRegistry>(&timers, limits);
  session_context.registry = sessions.get();
  session_context.views = views->get();
  session_context.max_participants = settings->limits.max_participants;
  session::LinkBase link_base;
  session_context.link_base = &link_base;

  // Who may do what: the users (and the admin token) with their stable ids, share links scoped
  // to the dataset they were made for, view links to theirs, each while the grant it was made
  // under holds.
  auto user_ids = UserIds::Open(settings->state_dir);
  if (!user_ids.ok()) return Fail("--state-dir", user_ids.status());
  if (Status s = (*user_ids)->Assign(settings->users); !s.ok()) return Fail("--state-dir", s);
  auto access = std::make_shared<AccessControl>(UsersWithAdmin(settings->users, settings->token));
  auto share_info = [](const std::optional<session::ShareLookup>& share)
      -> std::optional<ShareGrantInfo> {
    if (!share) return std::nullopt;
    const auto state = share->session->share_state(share->id);
    if (!state) return std::nullopt;
    return ShareGrantInfo{share->id, share->session->owner_grant(), state->dataset};
  };
  access->SetShareLookups(
      [sessions = sessions.get(), share_info](std::string_view token) {
        return share_info(sessions->FindShare(token));
      },
      [sessions = sessions.get(), share_info](std::string_view id) {
        return share_info(sessions->FindShareById(id));
      });
  access->SetViewLookup(
      [views = views->get()](std::string_view id) -> std::optional<ViewGrantInfo> {
        auto entry = views->Find(id);
        if (!entry) return std::nullopt;
        return ViewGrantInfo{entry->dataset, entry->grant};
      });
  access->SetDatasetFinder(
      [registry = registry->get()](std::string_view id) { return registry->Find(id); });
  session_context.grants = access.get();
  session_context.state_io = state_io.get();
  ViewLinkQuota view_quota(views->get(), settings->limits.max_view_links_per_user,
                           settings->limits.view_links_per_minute);
  session_context.admit_view_link = [&view_quota](const protocol::GrantRef& owner) {
    return view_quota.Admit(owner);
  };
  session::ViewSessionOptions session_options;
  session_options.max_screenshots_in_flight = settings->limits.max_screenshots_in_flight;
  session_options.messages_per_second = settings->limits.max_messages_per_second;
  session_options.message_burst = 2.0 * settings->limits.max_messages_per_second;

  net::ServerOptions server_options;
  server_options.bind_address = settings->bind;
  server_options.port = settings->port;
  server_options.io_threads = settings->io_threads;
  server_options.authenticator = access;
  server_options.trusted_proxies = settings->trusted_proxies;
  server_options.web_root = settings->web_root;
  server_options.max_upload_bytes = settings->max_upload_mb << 20;
  server_options.max_connections = settings->max_connections;
  server_options.max_connections_per_address = settings->max_connections_per_address;
  // Pages of the public URL may open WebSockets (the listening address always may; with --port 0
  // and no --public-url the public URL is that address).
  server_options.allowed_origins = settings->allowed_origins;
  if (const std::string base = PublicBaseUrl(*settings, settings->port);
      (!settings->public_url.empty() || settings->port != 0) && net::ParseWebOrigin(base).ok()) {
    server_options.allowed_origins.push_back(base);
  }
  // Listening on every interface without a public URL (a lab PC): the machine's own addresses
  // are its origins too, so colleagues may open it by IP as well as by name.
  if (settings->public_url.empty() && settings->port != 0 &&
      (settings->bind == "0.0.0.0" || settings->bind == "::")) {
    for (const std::string& address : LocalAddresses()) {
      server_options.allowed_origins.push_back("http://" + address + ":" +
                                               std::to_string(settings->port));
    }
  }
  ApiRoutesOptions routes_options;
  routes_options.version = kVersion;
  routes_options.access = access.get();
  routes_options.views = views->get();
  routes_options.state_io = state_io.get();
  routes_options.link_base = &link_base;
  routes_options.max_streams_per_user = settings->limits.max_streams_per_user;
  routes_options.max_upload_bytes = server_options.max_upload_bytes;
  auto routes = std::make_shared<ApiRoutes>(registry->get(), hub.get(), &metrics, uploads.get(),
                                            routes_options);
  auto server = net::Server::Start(
      server_options, routes,
      MakeSessionFactory(
          &session_context,
          [access](const net::WsConnectInfo& info) { return ConnectionCredential(*access, info); },
          session_options),
      logger);
  if (!server.ok()) return Fail("listen", server.status());
  // Links carry the public URL (default: where this server listens).
  link_base.Set(PublicBaseUrl(*settings, (*server)->port()));
  metrics.SetHttpCounts([server = server->get()] { return server->responses_by_status(); });

  std::printf("%s\n", ServeUrl(*settings, (*server)->port(), open_dataset).c_str());
  std::fflush(stdout);
  logger.Log(LogLevel::kInfo, "serving " + std::to_string(registry->get()->List().size()) +
                                  " dataset(s) on " + (*registry)->cache_root().string() +
                                  "; device " + (*renderer)->device().name);

  int signal = 0;
  while ((signal = WaitForStopSignal(stop_signals)) == SIGHUP) {
    // Users from a file are re-read; connections whose grant ended close at the next
    // revalidation of their session (within a second).
    ReloadUsers(*settings, **user_ids, *access, logger);
  }
  logger.Log(LogLevel::kInfo,
             std::string("stopping (") + (signal == SIGINT ? "SIGINT" : "SIGTERM") + ")");
  // In order: no new connections and sessions closed; no new data; datasets flushed, unfinished
  // streams checkpointed.
  (*server)->Shutdown();
  sessions.reset();  // Parked sessions released.
  metrics.SetHttpCounts(nullptr);
  watchers.clear();
  demo.reset();
  uploads.reset();  // Slab inserts in flight finish.
  state_io.reset();  // View links being saved are written.
  hub.reset();
  (*registry)->Close();
  logger.Log(LogLevel::kInfo, "stopped");
  return kExitOk;
}

}  // namespace octoscope::app
