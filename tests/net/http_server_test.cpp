// The HTTP side of net::Server, end to end: a real server on a loopback port, driven by Beast's
// HTTP client and by raw bytes for requests no well-behaved client sends.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "net/auth.h"
#include "net/net_test_client.h"
#include "net/server.h"
#include "net/test_handlers.h"

namespace octoscope::net {
namespace {

namespace fs = std::filesystem;
using testing::CapturingLogger;
using testing::Fetch;
using testing::HttpClient;
using testing::HttpResult;
using testing::RawExchange;
using testing::StatusOf;
using testing::TestApi;
using testing::WaitFor;
namespace http = testing::http;

constexpr char kToken[] = "s3cret-token-0123456789abcdef";

fs::path MakeTempDir(const std::string& name) {
  static std::atomic<int> counter{0};
  fs::path dir =
      fs::temp_directory_path() /
      ("octoscope-net-" + name + "-" + std::to_string(getpid()) + "-" + std::to_string(counter++));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void WriteFile(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
}

std::string Header(const HttpResult& r, std::string_view name) {
  auto it = r.headers.find(testing::beast::string_view(name.data(), name.size()));
  return it == r.headers.end() ? "" : std::string(it->value());
}

std::string RandomBytes(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::string s(n, '\0');
  for (char& c : s) c = static_cast<char>(rng());
  return s;
}

class HttpServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = MakeTempDir("http");
    web_ = dir_ / "web";
    WriteFile(web_ / "index.html", "<!doctype html><title>octoscope</title>");
    WriteFile(web_ / "app.js", "export const answer = 42;\n");
    WriteFile(web_ / "lib.mjs", "export default 1;\n");
    WriteFile(web_ / "style.css", "body { margin: 0 }\n");
    WriteFile(web_ / "logo.png", std::string("\x89PNG\r\n\x1a\n", 8) + "pixels");
    WriteFile(web_ / "icon.svg", "<svg xmlns=\"http://www.w3.org/2000/svg\"/>");
    WriteFile(web_ / "data.json", "{\"a\":1}");
    WriteFile(web_ / "font.woff2", "wOF2");
    WriteFile(web_ / "blob.bin", "raw");
    WriteFile(web_ / "sub" / "index.html", "<p>sub</p>");
    WriteFile(web_ / ".hidden", "hidden");
    WriteFile(dir_ / "secret.txt", "TOP-SECRET-CONTENT");
    fs::create_symlink(dir_ / "secret.txt", web_ / "link-out.txt");
  }

  void TearDown() override {
    server_.reset();
    if (HasFailure()) {
      for (const std::string& line : logger_.lines())
        std::fprintf(stderr, "log: %s\n", line.c_str());
    }
    fs::remove_all(dir_);
  }

  void Start(ServerOptions options = {}) {
    if (!options.authenticator)
      options.authenticator = std::make_shared<TokenAuthenticator>(kToken);
    options.web_root = web_;
    if (options.io_threads == 2) options.io_threads = io_threads_;
    auto factory = [](const WsConnectInfo&) -> std::unique_ptr<WsHandler> { return nullptr; };
    auto started = Server::Start(options, api_, factory, logger_);
    ASSERT_TRUE(started.ok()) << started.status().ToString();
    server_ = std::move(started).value();
    port_ = server_->port();
    ASSERT_NE(port_, 0);
  }

  std::string Token() const { return std::string("?token=") + kToken; }

  // Kept-alive connections, one from each of `sources` (local addresses; "" the default), each
  // served one request.
  std::vector<std::unique_ptr<HttpClient>> OpenConnections(
      const std::vector<std::string>& sources) {
    std::vector<std::unique_ptr<HttpClient>> open;
    for (const std::string& source : sources) {
      open.push_back(std::make_unique<HttpClient>(port_, source));
      EXPECT_EQ(open.back()->Request(http::verb::get, "/api/health").status, 200);
    }
    return open;
  }
  std::vector<std::pair<std::string, std::string>> Bearer() const {
    return {{"Authorization", std::string("Bearer ") + kToken}};
  }

  fs::path dir_, web_;
  int io_threads_ = 2;
  CapturingLogger logger_;
  std::shared_ptr<TestApi> api_ = std::make_shared<TestApi>();
  std::unique_ptr<Server> server_;
  uint16_t port_ = 0;
};

TEST_F(HttpServerTest, PortZeroPicksAFreePortAndTwoServersGetDifferentOnes) {
  Start();
  CapturingLogger other_logger;
  ServerOptions options;
  options.authenticator = std::make_shared<TokenAuthenticator>(kToken);
  auto other = Server::Start(
      options, api_, [](const WsConnectInfo&) { return std::unique_ptr<WsHandler>(); },
      other_logger);
  ASSERT_TRUE(other.ok()) << other.status().ToString();
  EXPECT_NE((*other)->port(), port_);
  // The port in use cannot be bound again.
  options.port = port_;
  auto clash = Server::Start(
      options, api_, [](const WsConnectInfo&) { return std::unique_ptr<WsHandler>(); },
      other_logger);
  ASSERT_FALSE(clash.ok());
  EXPECT_EQ(clash.status().code(), StatusCode::kUnavailable);
}

TEST_F(HttpServerTest, BadOptionsAreRefused) {
  auto factory = [](const WsConnectInfo&) { return std::unique_ptr<WsHandler>(); };
  ServerOptions options;
  EXPECT_EQ(Server::Start(options, api_, factory, logger_).status().code(),
            StatusCode::kInvalidArgument);  // No token.
  options.authenticator = std::make_shared<TokenAuthenticator>(kToken);
  options.bind_address = "localhost:80";
  EXPECT_EQ(Server::Start(options, api_, factory, logger_).status().code(),
            StatusCode::kInvalidArgument);
  options.bind_address = "127.0.0.1";
  options.io_threads = 0;
  EXPECT_EQ(Server::Start(options, api_, factory, logger_).status().code(),
            StatusCode::kInvalidArgument);
  options.io_threads = 1;
  options.web_root = dir_ / "missing";
  EXPECT_EQ(Server::Start(options, api_, factory, logger_).status().code(), StatusCode::kNotFound);
}

TEST_F(HttpServerTest, ServesStaticFilesWithMimeTypesAndCachingHeaders) {
  Start();
  struct Case {
    const char* path;
    const char* mime;
    const char* file;
  };
  const Case cases[] = {
      {"/", "text/html; charset=utf-8", "index.html"},
      {"/index.html", "text/html; charset=utf-8", "index.html"},
      {"/app.js", "text/javascript; charset=utf-8", "app.js"},
      {"/lib.mjs", "text/javascript; charset=utf-8", "lib.mjs"},
      {"/style.css", "text/css; charset=utf-8", "style.css"},
      {"/logo.png", "image/png", "logo.png"},
      {"/icon.svg", "image/svg+xml", "icon.svg"},
      {"/data.json", "application/json", "data.json"},
      {"/font.woff2", "font/woff2", "font.woff2"},
      {"/blob.bin", "application/octet-stream", "blob.bin"},
      {"/sub/", "text/html; charset=utf-8", "sub/index.html"},
      {"/%61pp.js", "text/javascript; charset=utf-8", "app.js"},  // Percent-decoded.
      {"/?token=ignored", "text/html; charset=utf-8", "index.html"},
  };
  HttpClient client(port_);  // One keep-alive connection for all of them.
  for (const Case& c : cases) {
    SCOPED_TRACE(c.path);
    HttpResult r = client.Request(http::verb::get, c.path);
    ASSERT_EQ(r.status, 200) << r.error;
    std::ifstream in(web_ / c.file, std::ios::binary);
    const std::string expected((std::istreambuf_iterator<char>(in)), {});
    EXPECT_EQ(r.body, expected);
    EXPECT_EQ(Header(r, "Content-Type"), c.mime);
    EXPECT_EQ(Header(r, "Cache-Control"), "no-cache");
    EXPECT_EQ(Header(r, "X-Content-Type-Options"), "nosniff");
    EXPECT_EQ(Header(r, "Referrer-Policy"), "no-referrer");
    EXPECT_FALSE(Header(r, "ETag").empty());
    EXPECT_TRUE(r.keep_alive);
  }
}

TEST_F(HttpServerTest, EtagRevalidationAnswers304UntilTheFileChanges) {
  Start();
  HttpResult first = Fetch(port_, http::verb::get, "/app.js");
  ASSERT_EQ(first.status, 200);
  const std::string etag = Header(first, "ETag");
  ASSERT_FALSE(etag.empty());
  HttpResult again = Fetch(port_, http::verb::get, "/app.js", {{"If-None-Match", etag}});
  EXPECT_EQ(again.status, 304);
  EXPECT_TRUE(again.body.empty());
  EXPECT_EQ(Header(again, "ETag"), etag);
  HttpResult listed =
      Fetch(port_, http::verb::get, "/app.js", {{"If-None-Match", "\"x\", W/" + etag}});
  EXPECT_EQ(listed.status, 304);
  HttpResult other = Fetch(port_, http::verb::get, "/app.js", {{"If-None-Match", "\"0-0\""}});
  EXPECT_EQ(other.status, 200);

  WriteFile(web_ / "app.js", "export const answer = 43; // changed\n");
  HttpResult changed = Fetch(port_, http::verb::get, "/app.js", {{"If-None-Match", etag}});
  EXPECT_EQ(changed.status, 200);
  EXPECT_NE(Header(changed, "ETag"), etag);
  EXPECT_EQ(changed.body, "export const answer = 43; // changed\n");
}

TEST_F(HttpServerTest, HeadAnswersHeadersWithoutBody) {
  Start();
  HttpResult r = Fetch(port_, http::verb::head, "/style.css");
  EXPECT_EQ(r.status, 200);
  EXPECT_TRUE(r.body.empty());
  EXPECT_EQ(Header(r, "Content-Length"), std::to_string(fs::file_size(web_ / "style.css")));
  EXPECT_EQ(Header(r, "Content-Type"), "text/css; charset=utf-8");
}

TEST_F(HttpServerTest, PathsOutsideTheWebRootAreRefused) {
  Start();
  const char* attacks[] = {
      "/../secret.txt",
      "/%2e%2e/secret.txt",
      "/sub/../../secret.txt",
      "/sub/%2e%2e/%2e%2e/secret.txt",
      "/link-out.txt",
      "/.hidden",
      "//secret.txt",
      "/sub%2f..%2f..%2fsecret.txt",
      "/..%5csecret.txt",
      "/index.html%00.png",
      "/sub",
      "/missing.js",
  };
  for (const char* target : attacks) {
    SCOPED_TRACE(target);
    const std::string reply = RawExchange(
        port_, std::string("GET ") + target + " HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
    const int status = StatusOf(reply);
    EXPECT_TRUE(status == 404 || status == 400) << reply;
    EXPECT_EQ(reply.find("TOP-SECRET"), std::string::npos);
    EXPECT_EQ(reply.find("hidden"), std::string::npos);
  }
  // An absolute-form target is not a path.
  EXPECT_EQ(StatusOf(RawExchange(port_, "GET http://x/index.html HTTP/1.1\r\nHost: x\r\n\r\n")),
            400);
}

TEST_F(HttpServerTest, StaticFilesAcceptOnlyGetAndHead) {
  Start();
  HttpResult r = Fetch(port_, http::verb::post, "/index.html", {}, "x");
  EXPECT_EQ(r.status, 405);
  EXPECT_EQ(Header(r, "Allow"), "GET, HEAD");
}

TEST_F(HttpServerTest, ApiAndMetricsRequireTheToken) {
  Start();
  // Without a token, with a wrong one, with a wrong scheme: 401 with a JSON error.
  const std::vector<std::vector<std::pair<std::string, std::string>>> refused = {
      {},
      {{"Authorization", "Bearer wrong"}},
      {{"Authorization", std::string("Basic ") + kToken}},
      {{"Authorization", std::string("Bearer ") + kToken + "x"}},
  };
  for (const auto& headers : refused) {
    HttpResult r = Fetch(port_, http::verb::get, "/api/echo", headers);
    EXPECT_EQ(r.status, 401);
    EXPECT_EQ(r.body, "{\"error\":\"missing or wrong token\"}");
    EXPECT_EQ(Header(r, "WWW-Authenticate"), "Bearer");
  }
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/echo?token=wrong").status, 401);
  EXPECT_EQ(Fetch(port_, http::verb::get, std::string("/api/echo?token=") + kToken + "0").status,
            401);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/metrics").status, 401);
  EXPECT_EQ(Fetch(port_, http::verb::post, "/api/health", {}, "{}").status, 401);
  EXPECT_TRUE(api_->seen().empty()) << "the handler saw an unauthorised request";

  // The token as bearer (any case of the scheme) or as query parameter.
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/echo", Bearer()).status, 200);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/echo",
                  {{"Authorization", std::string("bearer ") + kToken}})
                .status,
            200);
  HttpResult by_query =
      Fetch(port_, http::verb::get, "/api/echo?a=1&token=" + std::string(kToken) + "&b=2");
  EXPECT_EQ(by_query.status, 200);
  // The handler never sees the secret: no token parameter, no Authorization header.
  EXPECT_NE(by_query.body.find("\"query\":\"a=1&b=2\""), std::string::npos) << by_query.body;
  EXPECT_NE(by_query.body.find("\"authorization\":\"\""), std::string::npos) << by_query.body;
  HttpResult metrics = Fetch(port_, http::verb::get, "/metrics" + Token());
  EXPECT_EQ(metrics.status, 200);
  EXPECT_EQ(Header(metrics, "Content-Type"), "text/plain; version=0.0.4");
  for (const std::string& h : api_->seen_headers()) {
    EXPECT_EQ(h.find(kToken), std::string::npos) << h;
  }

  // Health needs no token.
  HttpResult health = Fetch(port_, http::verb::get, "/api/health");
  EXPECT_EQ(health.status, 200);
  EXPECT_EQ(health.body, "{\"status\":\"ok\"}");
  EXPECT_EQ(Header(health, "Cache-Control"), "no-store");

  // The token never reaches the log.
  for (const std::string& line : logger_.lines()) {
    EXPECT_EQ(line.find(kToken), std::string::npos) << line;
  }
  EXPECT_TRUE(WaitFor([&] { return logger_.Contains("GET /api/echo 200"); }));
  // Responses are counted by status for the metrics.
  std::map<int, uint64_t> by_status;
  for (const auto& [code, count] : server_->responses_by_status()) by_status[code] = count;
  EXPECT_GE(by_status[401], 3u);
  EXPECT_GE(by_status[200], 4u);
  EXPECT_EQ(by_status.count(500), 0u);
}

// An Authenticator of two users, one expired token, share links and view links.
class TableAuthenticator : public Authenticator {
 public:
  std::optional<Principal> Authenticate(std::string_view authorization,
                                        std::string_view raw_query) const override {
    const RequestCredentials c = ReadCredentials(authorization, raw_query);
    for (const std::string& t : c.tokens) {
      if (t == "alice-token-0123456789")
        return Principal{Principal::Kind::kUser, "alice", false, "", ""};
      if (t == "root-token-0123456789") return Principal{Principal::Kind::kUser, "root", true, "", ""};
    }
    if (c.share == "s123") return Principal{Principal::Kind::kShare, "", false, "s123", ""};
    if (c.view == "v456") return Principal{Principal::Kind::kView, "", false, "v456", ""};
    return std::nullopt;
  }
  std::string RefusalMessage(std::string_view authorization,
                             std::string_view raw_query) const override {
    for (const std::string& t : ReadCredentials(authorization, raw_query).tokens) {
      if (t == "old-token-0123456789") return "token expired";
    }
    return "missing or wrong token";
  }
};

TEST_F(HttpServerTest, TheAuthenticatorNamesThePrincipalAndCredentialsNeverReachHandlers) {
  ServerOptions options;
  options.authenticator = std::make_shared<TableAuthenticator>();
  Start(options);
  HttpResult alice = Fetch(port_, http::verb::get, "/api/echo?token=alice-token-0123456789&x=1");
  EXPECT_EQ(alice.status, 200);
  EXPECT_NE(alice.body.find("\"principal\":\"user:alice\""), std::string::npos) << alice.body;
  EXPECT_NE(alice.body.find("\"query\":\"x=1\""), std::string::npos) << alice.body;
  HttpResult root = Fetch(port_, http::verb::get, "/api/echo",
                          {{"Authorization", "Bearer root-token-0123456789"}});
  EXPECT_NE(root.body.find("\"principal\":\"user:root:admin\""), std::string::npos) << root.body;
  // Share and view credentials are stripped from the query like the token.
  HttpResult share = Fetch(port_, http::verb::get, "/api/echo?a=1&share=s123&view=zz&b=2");
  EXPECT_EQ(share.status, 200);
  EXPECT_NE(share.body.find("\"principal\":\"share:s123\""), std::string::npos) << share.body;
  EXPECT_NE(share.body.find("\"query\":\"a=1&b=2\""), std::string::npos) << share.body;
  HttpResult view = Fetch(port_, http::verb::get, "/api/echo?view=v456");
  EXPECT_NE(view.body.find("\"principal\":\"view:v456\""), std::string::npos) << view.body;
  // Refusals carry the Authenticator's message.
  HttpResult expired = Fetch(port_, http::verb::get, "/api/echo?token=old-token-0123456789");
  EXPECT_EQ(expired.status, 401);
  EXPECT_EQ(expired.body, "{\"error\":\"token expired\"}");
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/echo?share=nope").status, 401);
  for (const std::string& line : logger_.lines()) {
    EXPECT_EQ(line.find("s123"), std::string::npos) << line;
    EXPECT_EQ(line.find("v456"), std::string::npos) << line;
    EXPECT_EQ(line.find("alice-token"), std::string::npos) << line;
  }
}

TEST_F(HttpServerTest, ForwardedHeadersAreBelievedOnlyFromTrustedProxies) {
  const std::vector<std::pair<std::string, std::string>> forwarded = {
      {"X-Forwarded-For", "198.51.100.9, 203.0.113.7"}, {"X-Forwarded-Proto", "https"}};
  {
    ServerOptions options;
    options.trusted_proxies = {"127.0.0.0/8"};
    Start(options);
    auto headers = Bearer();
    headers.insert(headers.end(), forwarded.begin(), forwarded.end());
    HttpResult r = Fetch(port_, http::verb::get, "/api/echo", headers);
    EXPECT_NE(r.body.find("\"remote\":\"203.0.113.7\""), std::string::npos) << r.body;
    EXPECT_NE(r.body.find("\"scheme\":\"https\""), std::string::npos) << r.body;
    // The access log line is written when the response's write completes, which may be just
    // after the client has read it.
    EXPECT_TRUE(WaitFor([&] { return logger_.Contains("HTTP 203.0.113.7 GET /api/echo 200"); }));
    // Without the header: the proxy itself.
    r = Fetch(port_, http::verb::get, "/api/echo", Bearer());
    EXPECT_NE(r.body.find("\"remote\":\"127.0.0.1:"), std::string::npos) << r.body;
    EXPECT_NE(r.body.find("\"scheme\":\"http\""), std::string::npos) << r.body;
    server_.reset();
  }
  // From a peer that is not a trusted proxy the headers are ignored.
  ServerOptions options;
  options.trusted_proxies = {"10.0.0.0/8", "fd00::/8"};
  Start(options);
  auto headers = Bearer();
  headers.insert(headers.end(), forwarded.begin(), forwarded.end());
  HttpResult r = Fetch(port_, http::verb::get, "/api/echo", headers);
  EXPECT_NE(r.body.find("\"remote\":\"127.0.0.1:"), std::string::npos) << r.body;
  EXPECT_NE(r.body.find("\"scheme\":\"http\""), std::string::npos) << r.body;
  // A malformed proxy list is refused at start.
  ServerOptions bad;
  bad.authenticator = std::make_shared<TokenAuthenticator>(kToken);
  bad.trusted_proxies = {"10.0.0.0/33"};
  auto factory = [](const WsConnectInfo&) { return std::unique_ptr<WsHandler>(); };
  EXPECT_EQ(Server::Start(bad, api_, factory, logger_).status().code(),
            StatusCode::kInvalidArgument);
}

TEST_F(HttpServerTest, ViewLinkIdsInPathsAreRedactedInTheLog) {
  Start();
  const std::string id = "Vw0123456789abcdefghij";
  for (const http::verb method : {http::verb::get, http::verb::delete_, http::verb::put}) {
    EXPECT_EQ(Fetch(port_, method, "/api/views/" + id + Token()).status, 404);
  }
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/views/" + id + "/part" + Token()).status, 404);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/views/" + id).status, 401);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/echo/" + id + Token()).status, 404);
  ASSERT_TRUE(WaitFor([&] { return logger_.Contains("GET /api/echo/" + id + " 404"); }));
  EXPECT_TRUE(WaitFor([&] {
    return logger_.Contains("GET /api/views/<redacted> 404") &&
           logger_.Contains("DELETE /api/views/<redacted> 404") &&
           logger_.Contains("PUT /api/views/<redacted> 404") &&
           logger_.Contains("GET /api/views/<redacted>/part 404") &&
           logger_.Contains("GET /api/views/<redacted> 401");
  }));
  for (const std::string& line : logger_.lines()) {
    if (line.find("/api/echo/") == std::string::npos) {
      EXPECT_EQ(line.find(id), std::string::npos) << line;
    }
  }
}

TEST_F(HttpServerTest, ConnectionsOverTheTotalCapGet503UntilOneCloses) {
  ServerOptions options;
  options.max_connections = 3;
  Start(options);
  auto open = OpenConnections({"127.0.0.1", "127.0.0.2", "127.0.0.3"});
  for (const std::string source : {"127.0.0.1", "127.0.0.9"}) {
    HttpClient over(port_, source);
    HttpResult r = over.Request(http::verb::get, "/api/health");
    EXPECT_EQ(r.status, 503) << r.error;
    EXPECT_FALSE(Header(r, "Retry-After").empty());
    EXPECT_FALSE(r.keep_alive);
    EXPECT_TRUE(over.ServerClosed());
  }
  // The open ones are still served; once one closes, a new one is.
  EXPECT_EQ(open[1]->Request(http::verb::get, "/api/health").status, 200);
  open[0]->Close();
  EXPECT_TRUE(WaitFor([&] { return Fetch(port_, http::verb::get, "/api/health").status == 200; }));
  bool counted = false;
  for (const auto& [code, n] : server_->responses_by_status()) counted |= code == 503 && n >= 2;
  EXPECT_TRUE(counted);
  EXPECT_TRUE(logger_.Contains("max-connections"));
}

TEST_F(HttpServerTest, ConnectionsPerAddressAreCappedAndOtherAddressesAreServed) {
  ServerOptions options;
  options.max_connections_per_address = 2;
  Start(options);
  auto open = OpenConnections({"127.0.0.1", "127.0.0.1"});
  HttpClient over(port_, "127.0.0.1");
  HttpResult r = over.Request(http::verb::get, "/api/health");
  EXPECT_EQ(r.status, 503) << r.error;
  EXPECT_FALSE(Header(r, "Retry-After").empty());
  HttpClient other(port_, "127.0.0.2");
  EXPECT_EQ(other.Request(http::verb::get, "/api/health").status, 200);
  EXPECT_EQ(open[0]->Request(http::verb::get, "/api/health").status, 200);
  open[1]->Close();
  EXPECT_TRUE(WaitFor([&] {
    HttpClient again(port_, "127.0.0.1");
    return again.Request(http::verb::get, "/api/health").status == 200;
  }));
  EXPECT_TRUE(logger_.Contains("max-connections-per-address"));
}

TEST_F(HttpServerTest, BehindATrustedProxyTheForwardedClientIsCapped) {
  ServerOptions options;
  options.trusted_proxies = {"127.0.0.1"};
  options.max_connections_per_address = 2;
  Start(options);
  const std::vector<std::pair<std::string, std::string>> client_a = {
      {"X-Forwarded-For", "203.0.113.7"}, {"Authorization", std::string("Bearer ") + kToken}};
  const std::vector<std::pair<std::string, std::string>> client_b = {
      {"X-Forwarded-For", "198.51.100.9"}, {"Authorization", std::string("Bearer ") + kToken}};
  // The proxy's own connections count in all only: more than the cap, kept alive.
  auto proxy = OpenConnections({"", "", "", ""});
  // Two requests of client A in flight take A's places...
  std::vector<std::thread> slow;
  std::atomic<int> slow_ok{0};
  for (int i = 0; i < 2; ++i) {
    slow.emplace_back([&] {
      HttpClient c(port_);
      slow_ok += c.Request(http::verb::get, "/api/slow", client_a).status == 200;
    });
  }
  ASSERT_TRUE(WaitFor([&] { return api_->slow_started() == 2; }));
  HttpResult over = proxy[0]->Request(http::verb::get, "/api/echo", client_a);
  EXPECT_EQ(over.status, 503) << over.error;
  EXPECT_FALSE(Header(over, "Retry-After").empty());
  EXPECT_FALSE(over.keep_alive);
  // ... not B's; and the proxy's idle keep-alive connections hold nobody's place.
  EXPECT_EQ(proxy[1]->Request(http::verb::get, "/api/echo", client_b).status, 200);
  EXPECT_EQ(proxy[2]->Request(http::verb::get, "/api/echo", client_b).status, 200);
  auto served = [&](const std::vector<std::pair<std::string, std::string>>& client) {
    return WaitFor([&] {
      HttpClient c(port_);
      return c.Request(http::verb::get, "/api/echo", client).status == 200;
    });
  };
  EXPECT_TRUE(served(client_b));
  EXPECT_EQ(proxy[3]->Request(http::verb::get, "/api/echo", client_b).status, 200);
  // A's places come back when its requests are answered.
  api_->Release();
  for (auto& t : slow) t.join();
  EXPECT_EQ(slow_ok, 2);
  EXPECT_TRUE(served(client_a));
}

TEST_F(HttpServerTest, OversizedHeaderGets431AndOthersAreStillServed) {
  Start();
  // Just under the limit is fine.
  std::string fits = "GET /api/health HTTP/1.1\r\nHost: x\r\nConnection: close\r\nX-Pad: ";
  fits += std::string(8192 - fits.size() - 4 - 100, 'a') + "\r\n\r\n";
  EXPECT_EQ(StatusOf(RawExchange(port_, fits)), 200);

  // Over it: 431 before anything else is looked at (no token either), and the connection closes
  // (RawExchange returns only when the server closed it).
  std::string big =
      "GET /api/echo HTTP/1.1\r\nHost: x\r\nX-Pad: " + std::string(9000, 'a') + "\r\n\r\n";
  const std::string reply = RawExchange(port_, big);
  EXPECT_EQ(StatusOf(reply), 431) << reply.substr(0, 200);
  EXPECT_NE(reply.find("request line and headers over 8192 bytes"), std::string::npos);
  // Many header lines count as well.
  std::string many = "GET / HTTP/1.1\r\nHost: x\r\n";
  for (int i = 0; i < 1000; ++i) many += "X-" + std::to_string(i) + ": y\r\n";
  EXPECT_EQ(StatusOf(RawExchange(port_, many + "\r\n")), 431);

  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, MalformedRequestsGet400AndClose) {
  Start();
  const char* bad[] = {
      "GET\r\n\r\n",
      "GET / HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n",
      "GET / HTTP/1.1\r\nBad Header Line\r\n\r\n",
      "GET / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\nContent-Length: 6\r\n\r\nhello",
      "PUT /api/echo?token=s3cret-token-0123456789abcdef HTTP/1.1\r\nHost: x\r\n"
      "Transfer-Encoding: chunked\r\n\r\nzz\r\n",
      "\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03 tls hello",
  };
  for (const char* request : bad) {
    SCOPED_TRACE(testing::beast::string_view(request).substr(0, 20));
    const std::string reply = RawExchange(port_, request);
    EXPECT_EQ(StatusOf(reply), 400) << reply.substr(0, 200);
  }
  // A header that never completes is dropped after the read timeout (here: the client gives up
  // first; the server keeps serving).
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, JsonBodiesAreCappedAt64KiB) {
  Start();
  // Exactly the limit is accepted.
  HttpResult ok =
      Fetch(port_, http::verb::post, "/api/echo" + Token(), {}, std::string(64 << 10, 'x'));
  EXPECT_EQ(ok.status, 200);
  EXPECT_NE(ok.body.find("\"body_bytes\":65536"), std::string::npos);
  // A declared length over the limit is refused before the body is read.
  const std::string header =
      "POST /api/echo" + Token() + " HTTP/1.1\r\nHost: x\r\nContent-Length: 70000\r\n\r\n";
  std::string reply = RawExchange(port_, header);
  EXPECT_EQ(StatusOf(reply), 413) << reply;
  // A chunked body is stopped when it passes the limit.
  HttpClient client(port_);
  std::string chunked =
      "POST /api/echo" + Token() + " HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n";
  for (int i = 0; i < 20; ++i) chunked += "1000\r\n" + std::string(4096, 'y') + "\r\n";
  chunked += "0\r\n\r\n";
  client.WriteRaw(chunked);
  HttpResult over = client.ReadResponse();
  EXPECT_EQ(over.status, 413) << over.error;
  EXPECT_FALSE(over.keep_alive);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, UploadsStreamThroughTheBodyReader) {
  ServerOptions options;
  options.upload_chunk_bytes = 64 << 10;
  Start(options);
  const std::string body = RandomBytes(5 << 20, 7);
  const uint64_t expected =
      testing::Fnv1a(reinterpret_cast<const uint8_t*>(body.data()), body.size());
  const std::string expected_json =
      "{\"bytes\":" + std::to_string(body.size()) + ",\"fnv\":" + std::to_string(expected) + "}";

  HttpResult r = Fetch(port_, http::verb::put, "/api/upload" + Token(),
                       {{"Content-Type", "application/octet-stream"}}, body);
  EXPECT_EQ(r.status, 200) << r.error;
  EXPECT_EQ(r.body, expected_json);
  EXPECT_GE(api_->upload_pieces(), body.size() / (64 << 10));  // Pulled piece by piece.
  ASSERT_TRUE(api_->upload_end().has_value());
  EXPECT_TRUE(api_->upload_end()->ok()) << api_->upload_end()->ToString();

  // Chunked transfer encoding, in uneven chunks.
  std::string chunked =
      "PUT /api/upload" + Token() + " HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n";
  size_t at = 0;
  for (size_t size = 1; at < body.size(); size = size * 3 + 1) {
    const size_t n = std::min(size, body.size() - at);
    char hex[32];
    std::snprintf(hex, sizeof hex, "%zx\r\n", n);
    chunked += hex + body.substr(at, n) + "\r\n";
    at += n;
  }
  chunked += "0\r\n\r\n";
  HttpClient client(port_);
  ASSERT_FALSE(client.WriteRaw(chunked));
  HttpResult by_chunks = client.ReadResponse();
  EXPECT_EQ(by_chunks.status, 200) << by_chunks.error;
  EXPECT_EQ(by_chunks.body, expected_json);
  EXPECT_TRUE(by_chunks.keep_alive);

  // "Expect: 100-continue": the server invites the body once the handler reads it.
  HttpClient expecting(port_);
  ASSERT_FALSE(expecting.WriteRaw("PUT /api/upload" + Token() +
                                  " HTTP/1.1\r\nHost: x\r\nExpect: 100-continue\r\n"
                                  "Content-Length: " +
                                  std::to_string(body.size()) + "\r\n\r\n"));
  HttpResult interim = expecting.ReadResponse();
  EXPECT_EQ(interim.status, 100);
  ASSERT_FALSE(expecting.WriteRaw(body));
  HttpResult final_response = expecting.ReadResponse();
  EXPECT_EQ(final_response.status, 200);
  EXPECT_EQ(final_response.body, expected_json);

  // An empty body ends at once.
  HttpResult empty =
      Fetch(port_, http::verb::put, "/api/upload" + Token(), {{"Content-Length", "0"}});
  EXPECT_EQ(empty.status, 200);
  EXPECT_EQ(empty.body, "{\"bytes\":0,\"fnv\":" + std::to_string(testing::Fnv1a(nullptr, 0)) + "}");
}

TEST_F(HttpServerTest, UploadsOverTheLimitGet413) {
  ServerOptions options;
  options.max_upload_bytes = 1 << 20;
  options.upload_chunk_bytes = 64 << 10;
  Start(options);
  // Declared too long: refused before reading, the handler never runs.
  const std::string reply =
      RawExchange(port_, "PUT /api/upload" + Token() +
                             " HTTP/1.1\r\nHost: x\r\nContent-Length: 2097152\r\n\r\n");
  EXPECT_EQ(StatusOf(reply), 413) << reply;
  EXPECT_TRUE(api_->seen().empty());
  // Chunked: refused when the limit is passed while reading; the handler's reader is told.
  std::string chunked =
      "PUT /api/upload" + Token() + " HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n";
  for (int i = 0; i < 20; ++i) chunked += "10000\r\n" + std::string(65536, 'z') + "\r\n";
  chunked += "0\r\n\r\n";
  HttpClient client(port_);
  client.WriteRaw(chunked);  // May fail half-way: the server stops reading.
  HttpResult over = client.ReadResponse();
  EXPECT_EQ(over.status, 413) << over.error;
  ASSERT_TRUE(WaitFor([&] { return api_->upload_end().has_value(); }));
  EXPECT_EQ(api_->upload_end()->code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, ClientLeavingMidUploadIsCleanedUp) {
  ServerOptions options;
  options.upload_chunk_bytes = 64 << 10;
  Start(options);
  {
    HttpClient client(port_);
    ASSERT_FALSE(client.WriteRaw("PUT /api/upload" + Token() +
                                 " HTTP/1.1\r\nHost: x\r\nContent-Length: 10485760\r\n\r\n" +
                                 std::string(1 << 20, 'q')));
    ASSERT_TRUE(WaitFor([&] { return api_->upload_pieces() > 0; }));
    client.Close();
  }
  ASSERT_TRUE(WaitFor([&] { return api_->upload_end().has_value(); }));
  EXPECT_EQ(api_->upload_end()->code(), StatusCode::kUnavailable);
  EXPECT_TRUE(WaitFor([&] { return server_->open_connections() == 0; }));
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, SlowHandlersNeverBlockTheIoThread) {
  io_threads_ = 1;  // One I/O thread: a blocking handler would stall everything.
  Start();
  HttpResult slow;
  std::atomic<bool> slow_done{false};
  std::thread waiting([&] {
    slow = Fetch(port_, http::verb::get, "/api/slow" + Token());
    slow_done = true;
  });
  ASSERT_TRUE(WaitFor([&] { return api_->slow_started() == 1; }));
  // While the slow request is pending, others are served.
  for (int i = 0; i < 5; ++i) {
    EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
    EXPECT_EQ(Fetch(port_, http::verb::get, "/app.js").status, 200);
  }
  EXPECT_FALSE(slow_done);  // Still waiting for its handler.
  api_->Release();
  waiting.join();
  EXPECT_EQ(slow.status, 200) << slow.error;
  EXPECT_EQ(slow.body, "{\"slow\":true}");
}

TEST_F(HttpServerTest, HandlersThatThrowOrForgetToAnswerGive500) {
  Start();
  HttpResult dropped = Fetch(port_, http::verb::get, "/api/drop" + Token());
  EXPECT_EQ(dropped.status, 500);
  EXPECT_NE(dropped.body.find("without a response"), std::string::npos);
  HttpResult thrown = Fetch(port_, http::verb::get, "/api/throw" + Token());
  EXPECT_EQ(thrown.status, 500);
  EXPECT_NE(thrown.body.find("handler failure"), std::string::npos);
  EXPECT_TRUE(logger_.Contains("ApiHandler::Handle threw"));
  EXPECT_EQ(Fetch(port_, http::verb::get, "/api/health").status, 200);
}

TEST_F(HttpServerTest, KeepAliveServesSeveralRequestsPerConnection) {
  Start();
  HttpClient client(port_);
  for (int i = 0; i < 5; ++i) {
    HttpResult r = client.Request(http::verb::get, "/api/echo", Bearer());
    EXPECT_EQ(r.status, 200) << r.error;
    EXPECT_TRUE(r.keep_alive);
  }
  // Connection: close is honoured.
  HttpResult last = client.Request(http::verb::get, "/api/health", {{"Connection", "close"}});
  EXPECT_EQ(last.status, 200);
  EXPECT_FALSE(last.keep_alive);
  EXPECT_TRUE(client.ServerClosed());
  client.Close();  // Else the server lingers, draining, until its linger time ends.
  EXPECT_TRUE(WaitFor([&] { return server_->open_connections() == 0; }));
}

TEST_F(HttpServerTest, WebSocketPathWithoutUpgradeGets426) {
  Start();
  EXPECT_EQ(Fetch(port_, http::verb::get, "/ws" + Token()).status, 426);
}

}  // namespace
}  // namespace octoscope::net
