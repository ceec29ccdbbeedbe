// The deploy/ files tested with the real tools: the shipped nginx sites pass `nginx -t`; Debian's
// nginx, started on loopback with a certificate made here, in front of the real `octoscope
// serve`, carries a whole WebSocket session over TLS (frames checked against the voxels) and a
// slab upload larger than nginx's default body limit, and lets the server check WebSocket pages'
// origins and cap connections per client by what nginx forwards; the systemd unit passes
// `systemd-analyze verify` and its sandbox scores low in `systemd-analyze security`;
// deploy/install.sh into a DESTDIR produces the installed layout, keeps the config and token on
// upgrade, and the installed binary serves the installed web client.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "app/server_process.h"
#include "deploy/nginx_proxy.h"
#include "deploy/tls_test_client.h"
#include "encode/png_test_decoder.h"
#include "protocol/frame_header.h"

namespace octoscope::deploy {
namespace {

namespace fs = std::filesystem;
namespace http = boost::beast::http;
using json = nlohmann::json;
using octoscope::testing::ServerProcess;
using testing::CommandResult;
using testing::FindProgram;
using testing::NginxPorts;
using testing::NginxProxy;
using testing::ReadFile;
using testing::RunCommand;
using testing::TlsHttpClient;
using testing::TlsWsClient;
using testing::WriteFile;

constexpr char kToken[] = "deploy-test-token-0123456789abcdef";
const fs::path kSource = OCTOSCOPE_SOURCE_DIR;

fs::path TestDir(std::string name) {
  std::replace(name.begin(), name.end(), '/', '-');  // Parameterised tests: "Name/Param".
  const fs::path dir = fs::temp_directory_path() /
                       ("octoscope-deploy-test-" + std::to_string(getpid()) + "-" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::string Quoted(const fs::path& path) { return "'" + path.string() + "'"; }

// A one-channel volume whose every column has a different maximum: v(x, y, z) =
// ((7x + 3y) mod 200) * 16 + z, so an orthographic MIP along z is known exactly.
struct Volume {
  static constexpr int64_t kX = 256, kY = 256, kZ = 16;
  static constexpr double kWindow = 3200;
  static uint16_t At(int64_t x, int64_t y, int64_t z) {
    return static_cast<uint16_t>(((7 * x + 3 * y) % 200) * 16 + z);
  }
  static std::string Planes() {  // All kZ planes, little-endian: 2 MiB, over nginx's default 1m.
    std::string bytes;
    bytes.reserve(kX * kY * kZ * 2);
    for (int64_t z = 0; z < kZ; ++z) {
      for (int64_t y = 0; y < kY; ++y) {
        for (int64_t x = 0; x < kX; ++x) {
          const uint16_t v = At(x, y, z);
          bytes.push_back(static_cast<char>(v & 0xff));
          bytes.push_back(static_cast<char>(v >> 8));
        }
      }
    }
    return bytes;
  }
  static int ExpectedPixel(int64_t x, int64_t y) {
    return static_cast<int>(std::lround(std::min(1.0, At(x, y, kZ - 1) / kWindow) * 255));
  }
};

// ---------------------------------------------------------------------------------------------
// nginx

struct Site {
  const char* file;    // Below deploy/nginx.
  const char* prefix;  // The path the site serves Octoscope under ("" = the root).
};

void PrintTo(const Site& site, std::ostream* out) { *out << site.file; }

std::string SiteName(const ::testing::TestParamInfo<Site>& info) {
  return info.param.prefix[0] == '\0' ? "Root" : "PathPrefix";
}

class NginxSiteTest : public ::testing::TestWithParam<Site> {
 protected:
  void SetUp() override {
    nginx_ = FindProgram("nginx");
    if (nginx_.empty() || FindProgram("openssl").empty()) {
      GTEST_SKIP() << "nginx or openssl is not installed (deploy/install_deps.sh installs both)";
    }
    dir_ = TestDir(std::string("nginx-") + SiteName({GetParam(), 0}) + "-" +
                   ::testing::UnitTest::GetInstance()->current_test_info()->name());
    ASSERT_EQ(testing::MakeCertificate(dir_), "");
    ports_ = {testing::FreePort(), testing::FreePort(), 0};
  }
  void TearDown() override {
    proxy_.Stop();
    if (server_.running()) {
      EXPECT_EQ(server_.Stop(), 0);
    }
    if (!HasFailure()) fs::remove_all(dir_);
  }

  // Renders the site for an upstream on `upstream_port`; `nginx -t` must accept it.
  void RenderAndCheck(uint16_t upstream_port) {
    ports_.upstream = upstream_port;
    ASSERT_EQ(proxy_.Render(kSource / "deploy/nginx" / GetParam().file, dir_, ports_), "");
    const CommandResult checked = proxy_.Test(nginx_);
    ASSERT_EQ(checked.status, 0) << checked.output;
    EXPECT_NE(checked.output.find("test is successful"), std::string::npos) << checked.output;
  }

  std::string Path(const std::string& path) const { return GetParam().prefix + path; }
  std::string Ca() const { return (dir_ / "cert.pem").string(); }

  std::string nginx_;
  fs::path dir_;
  NginxPorts ports_;
  NginxProxy proxy_;
  ServerProcess server_;
};

TEST_P(NginxSiteTest, NginxTAcceptsTheShippedSite) { RenderAndCheck(8080); }

// Reads WebSocket messages until a text event of `type`.
std::optional<json> ReadEvent(TlsWsClient& ws, const std::string& type) {
  for (int i = 0; i < 200; ++i) {
    auto m = ws.Read(std::chrono::seconds(30));
    if (!m.ok) return std::nullopt;
    if (m.binary) continue;
    json event = json::parse(m.data, nullptr, false);
    if (event.is_object() && event.value("type", "") == type) return event;
  }
  return std::nullopt;
}

TEST_P(NginxSiteTest, CarriesAWebSocketSessionAndASlabUploadOverTls) {
  // The server as behind a proxy: links carry the URL users open.
  const std::string public_url =
      "https://localhost:" + std::to_string(ports_.https) + GetParam().prefix + "/";
  ASSERT_TRUE(server_.Start(
      OCTOSCOPE_BINARY,
      {"--port", "0", "--cache", (dir_ / "cache").string(), "--token", kToken, "--ram-mb", "256",
       "--device", "cpu", "--state-dir", (dir_ / "state").string(), "--public-url", public_url},
      (dir_ / "server.log").string()))
      << server_.error();
  RenderAndCheck(server_.port());
  ASSERT_EQ(proxy_.Start(nginx_, ports_.https), "");
  const std::string bearer = std::string("Bearer ") + kToken;

  // Plain HTTP is only redirected to HTTPS.
  auto redirect = net::testing::Fetch(ports_.http, http::verb::get, Path("/api/health"));
  EXPECT_EQ(redirect.status, 301);
  EXPECT_EQ(std::string(redirect.headers[http::field::location]),
            "https://127.0.0.1" + Path("/api/health"));

  // The web client, health and the token check through the proxy.
  TlsHttpClient https(ports_.https, Ca());
  auto page = https.Request(http::verb::get, Path("/"));
  ASSERT_EQ(page.status, 200) << page.error << page.body;
  EXPECT_EQ(page.body, ReadFile(kSource / "web/index.html"));
  if (GetParam().prefix[0] != '\0') {
    auto bare = https.Request(http::verb::get, GetParam().prefix);
    EXPECT_EQ(bare.status, 301);
    EXPECT_EQ(std::string(bare.headers[http::field::location]).find(Path("/")) != std::string::npos,
              true);
  }
  auto health = https.Request(http::verb::get, Path("/api/health"));
  ASSERT_EQ(health.status, 200) << health.error;
  EXPECT_EQ(json::parse(health.body)["status"], "ok");
  EXPECT_EQ(https.Request(http::verb::get, Path("/api/datasets")).status, 401);

  // A stream, and one slab of 2 MiB (nginx's default limit is 1 MiB) streamed through.
  auto created = https.Request(http::verb::post, Path("/api/datasets"),
                               {{"Authorization", bearer}, {"Content-Type", "application/json"}},
                               json{{"name", "through nginx"},
                                    {"size", {Volume::kX, Volume::kY, Volume::kZ}},
                                    {"channels", 1},
                                    {"dtype", "uint16"}}
                                   .dump());
  ASSERT_EQ(created.status, 201) << created.error << created.body;
  const std::string id = json::parse(created.body)["id"];
  auto slab = https.Request(
      http::verb::put,
      Path("/api/datasets/" + id + "/slabs?z=0&depth=" + std::to_string(Volume::kZ) + "&channel=0"),
      {{"Authorization", bearer}, {"Content-Type", "application/octet-stream"}}, Volume::Planes());
  ASSERT_EQ(slab.status, 200) << slab.error << slab.body;
  EXPECT_EQ(json::parse(slab.body)["planes_inserted"], Volume::kZ);
  auto listed =
      https.Request(http::verb::get, Path("/api/datasets/" + id), {{"Authorization", bearer}});
  ASSERT_EQ(listed.status, 200);
  EXPECT_EQ(json::parse(listed.body)["planes_inserted"], Volume::kZ);

  // A WebSocket session over TLS: frames of the uploaded data.
  TlsWsClient ws(Ca());
  ASSERT_EQ(ws.Connect(ports_.https, Path("/ws?token=") + kToken), "");
  ASSERT_TRUE(ws.Send(json{{"type", "hello"}, {"client", "deploy_test"}, {"protocol", 1}}.dump()));
  ASSERT_TRUE(ReadEvent(ws, "welcome").has_value());
  ASSERT_TRUE(ws.Send(json{{"type", "quality"}, {"lossless_final", true}}.dump()));
  const double cx = Volume::kX / 2.0, cy = Volume::kY / 2.0;
  const json camera = {{"projection", "ortho"},
                       {"position", {cx, cy, -100.0}},
                       {"target", {cx, cy, Volume::kZ / 2.0}},
                       {"up", {0, -1, 0}},
                       {"ortho_height", Volume::kY}};
  const json params = {{"mode", "mip"},
                       {"channels",
                        {{{"enabled", true},
                          {"color", {1, 1, 1}},
                          {"window", Volume::kWindow},
                          {"level", Volume::kWindow / 2},
                          {"gamma", 1}}}}};
  ASSERT_TRUE(ws.Send(
      json{{"type", "open"}, {"dataset", id}, {"state", {{"camera", camera}, {"params", params}}}}
          .dump()));
  ASSERT_TRUE(ReadEvent(ws, "opened").has_value());
  ASSERT_TRUE(ws.Send(json{
      {"type", "viewport"},
      {"view", "3d"},
      {"width", Volume::kX},
      {"height", Volume::kY},
      {"dpr", 1}}.dump()));
  int frames = 0;
  std::optional<std::vector<uint8_t>> final_png;
  for (int i = 0; i < 500 && !final_png; ++i) {
    auto m = ws.Read(std::chrono::seconds(60));
    ASSERT_TRUE(m.ok) << m.error.message();
    if (!m.binary) continue;
    const std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(m.data.data()),
                                         m.data.size());
    ASSERT_EQ(m.data.substr(0, 4), "OCTF");
    auto header = protocol::DecodeFrameHeader(bytes);
    ASSERT_TRUE(header.ok()) << header.status().ToString();
    ++frames;
    ASSERT_TRUE(ws.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump()));
    if (header->final) final_png.emplace(bytes.begin() + protocol::kFrameHeaderBytes, bytes.end());
  }
  ASSERT_TRUE(final_png.has_value()) << frames << " frames, none final";
  auto png = octoscope::testing::DecodeTestPng(*final_png);
  ASSERT_TRUE(png.ok) << png.error;
  ASSERT_EQ(png.width, Volume::kX);
  ASSERT_EQ(png.height, Volume::kY);
  int worst = 0;
  for (int y = 0; y < Volume::kY; ++y) {
    for (int x = 0; x < Volume::kX; ++x) {
      for (int c = 0; c < 3; ++c) {
        worst = std::max(worst, std::abs(png.At(x, y, c) - Volume::ExpectedPixel(x, y)));
      }
    }
  }
  EXPECT_LE(worst, 1) << "the final frame through the proxy differs from the voxels";

  // A share link created through the proxy carries the public URL.
  ASSERT_TRUE(ws.Send(json{{"type", "share_create"}, {"role", "viewer"}}.dump()));
  auto share = ReadEvent(ws, "share_created");
  ASSERT_TRUE(share.has_value());
  const std::string share_token = (*share)["token"];
  EXPECT_EQ((*share)["url"], public_url + "?share=" + share_token);
  ws.Close();

  // Everything above went through nginx.
  const std::string access = proxy_.access_log();
  EXPECT_NE(access.find("\"PUT " + Path("/api/datasets/" + id + "/slabs")), std::string::npos)
      << access;
  EXPECT_NE(access.find("\"GET " + Path("/ws?token=")), std::string::npos) << access;
}

TEST_P(NginxSiteTest, BrowsersAndClientsAreCheckedByWhatTheProxyForwards) {
  // Behind the proxy (trusted): pages of the public URL may open WebSockets, others get 403; the
  // per-address connection cap counts the clients nginx names, not nginx.
  const std::string origin = "https://localhost:" + std::to_string(ports_.https);
  ASSERT_TRUE(
      server_.Start(OCTOSCOPE_BINARY,
                    {"--port", "0", "--cache", (dir_ / "cache").string(), "--token", kToken,
                     "--ram-mb", "256", "--device", "cpu", "--state-dir", (dir_ / "state").string(),
                     "--public-url", origin + GetParam().prefix + "/", "--trusted-proxy",
                     "127.0.0.1", "--max-connections-per-address", "2"},
                    (dir_ / "server.log").string()))
      << server_.error();
  RenderAndCheck(server_.port());
  ASSERT_EQ(proxy_.Start(nginx_, ports_.https), "");
  const std::string target = Path("/ws?token=") + kToken;
  auto hello = json{{"type", "hello"}, {"client", "deploy_test"}, {"protocol", 1}}.dump();
  std::vector<std::unique_ptr<TlsWsClient>> open;
  for (int i = 0; i < 2; ++i) {
    open.push_back(std::make_unique<TlsWsClient>(Ca()));
    open.back()->SetHeader("Origin", origin);
    ASSERT_EQ(open.back()->Connect(ports_.https, target), "");
    ASSERT_TRUE(open.back()->Send(hello));
    ASSERT_TRUE(ReadEvent(*open.back(), "welcome").has_value());
  }
  // A third from the same client is over its cap (2); from another client it is not.
  TlsWsClient third(Ca());
  EXPECT_NE(third.Connect(ports_.https, target), "");
  EXPECT_EQ(third.handshake_status(), 503);
  TlsWsClient other(Ca());
  other.SetHeader("Origin", origin);
  EXPECT_EQ(other.Connect(ports_.https, target, "127.0.0.2"), "");
  // A page of another site is refused before the upgrade.
  TlsWsClient foreign(Ca());
  foreign.SetHeader("Origin", "https://evil.example");
  EXPECT_NE(foreign.Connect(ports_.https, target, "127.0.0.3"), "");
  EXPECT_EQ(foreign.handshake_status(), 403);
  for (auto& ws : open) ws->Close();
  const std::string log = ReadFile(dir_ / "server.log");
  EXPECT_NE(log.find("WS 127.0.0.3 refused: a page of Origin \"https://evil.example\""),
            std::string::npos)
      << log;
}

// An upstream that answers every request with the request's headers as a JSON object, to see
// exactly what nginx forwards.
class HeaderEchoUpstream {
 public:
  HeaderEchoUpstream() : acceptor_(ioc_, {boost::asio::ip::make_address("127.0.0.1"), 0}) {
    thread_ = std::thread([this] { Serve(); });
  }
  ~HeaderEchoUpstream() {
    stop_ = true;
    boost::system::error_code ec;
    boost::asio::ip::tcp::socket poke(ioc_);
    poke.connect(acceptor_.local_endpoint(), ec);  // Wakes the blocking accept.
    thread_.join();
  }
  uint16_t port() const { return acceptor_.local_endpoint().port(); }

 private:
  void Serve() {
    while (!stop_) {
      boost::asio::ip::tcp::socket socket(ioc_);
      boost::system::error_code ec;
      acceptor_.accept(socket, ec);
      if (ec || stop_) continue;
      boost::beast::flat_buffer buffer;
      http::request<http::string_body> request;
      http::read(socket, buffer, request, ec);
      if (ec) continue;
      json headers = json::object();
      for (const auto& field : request) {
        headers[std::string(field.name_string())] = std::string(field.value());
      }
      headers["target"] = std::string(request.target());
      http::response<http::string_body> response{http::status::ok, 11};
      response.set(http::field::content_type, "application/json");
      response.body() = headers.dump();
      response.keep_alive(false);
      response.prepare_payload();
      http::write(socket, response, ec);
    }
  }

  boost::asio::io_context ioc_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

TEST_P(NginxSiteTest, ForwardsTheClientsAddressAndSchemeAndOverwritesForgedOnes) {
  HeaderEchoUpstream upstream;
  RenderAndCheck(upstream.port());
  ASSERT_EQ(proxy_.Start(nginx_, ports_.https), "");
  // The client connects from 127.0.0.2 (nginx itself talks to the upstream from 127.0.0.1) and
  // claims to be someone else.
  TlsHttpClient client(ports_.https, Ca(), "127.0.0.2");
  auto r = client.Request(http::verb::get, Path("/api/datasets?token=x"),
                          {{"X-Forwarded-For", "203.0.113.66"}, {"X-Forwarded-Proto", "http"}});
  ASSERT_EQ(r.status, 200) << r.error << r.body;
  const json seen = json::parse(r.body);
  EXPECT_EQ(seen["X-Forwarded-For"], "127.0.0.2") << seen;
  EXPECT_EQ(seen["X-Forwarded-Proto"], "https") << seen;
  EXPECT_EQ(seen["X-Forwarded-Host"], "localhost") << seen;
  EXPECT_EQ(seen["Host"], "localhost") << seen;
  EXPECT_EQ(seen["target"], "/api/datasets?token=x") << seen;  // The prefix is stripped.
  EXPECT_FALSE(seen.contains("Upgrade")) << seen;
  EXPECT_FALSE(seen.contains("Connection")) << seen;  // Kept alive upstream.
}

INSTANTIATE_TEST_SUITE_P(Sites, NginxSiteTest,
                         ::testing::Values(Site{"octoscope.conf", ""},
                                           Site{"octoscope-prefix.conf", "/octoscope"}),
                         SiteName);

// ---------------------------------------------------------------------------------------------
// systemd

// The shipped unit with ExecStart pointing at `binary` (systemd-analyze checks that it exists).
fs::path RenderUnit(const fs::path& dir, const fs::path& binary) {
  std::string unit = ReadFile(kSource / "deploy/systemd/octoscope.service");
  const std::string from = "ExecStart=/usr/local/bin/octoscope ";
  const size_t at = unit.find(from);
  if (at == std::string::npos) return {};
  unit.replace(at, from.size(), "ExecStart=" + binary.string() + " ");
  WriteFile(dir / "octoscope.service", unit);
  return dir / "octoscope.service";
}

class SystemdUnitTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (FindProgram("systemd-analyze").empty()) {
      GTEST_SKIP() << "systemd-analyze is not installed (deploy/install_deps.sh installs systemd)";
    }
    dir_ = TestDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    unit_ = RenderUnit(dir_, OCTOSCOPE_BINARY);
    ASSERT_FALSE(unit_.empty()) << "deploy/systemd/octoscope.service: no ExecStart line";
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_, unit_;
};

TEST_F(SystemdUnitTest, VerifyAcceptsTheUnit) {
  const CommandResult r = RunCommand("systemd-analyze verify " + Quoted(unit_));
  EXPECT_EQ(r.status, 0) << r.output;
  // Warnings (unknown keys, bad values) do not change the status: none may name the unit.
  EXPECT_EQ(r.output.find("octoscope.service"), std::string::npos) << r.output;
}

TEST_F(SystemdUnitTest, VerifyRejectsAMistake) {
  // The check above would notice: a misspelt key is reported.
  std::string unit = ReadFile(unit_);
  unit.replace(unit.find("ProtectClock="), 13, "ProtectClok=");
  WriteFile(unit_, unit);
  const CommandResult r = RunCommand("systemd-analyze verify " + Quoted(unit_));
  EXPECT_NE(r.output.find("ProtectClok"), std::string::npos) << r.output;
}

TEST_F(SystemdUnitTest, SandboxExposureIsLow) {
  // systemd's own rating of the sandbox, 0 (locked down) … 10 (unprotected); 2.5 at most.
  const CommandResult r =
      RunCommand("systemd-analyze security --offline=yes --threshold=25 " + Quoted(unit_));
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("Overall exposure level for octoscope.service"), std::string::npos)
      << r.output;
}

// ---------------------------------------------------------------------------------------------
// install.sh

class InstallScriptTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = TestDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    destdir_ = dir_ / "root";
  }
  void TearDown() override {
    if (server_.running()) {
      EXPECT_EQ(server_.Stop(), 0);
    }
    if (!HasFailure()) fs::remove_all(dir_);
  }
  CommandResult Install(const std::string& extra = "") const {
    return RunCommand("bash " + Quoted(kSource / "deploy/install.sh") + " --build " +
                      Quoted(fs::path(OCTOSCOPE_BINARY).parent_path()) + " --destdir " +
                      Quoted(destdir_) + " --prefix /opt/octoscope --unit-dir /lib/systemd/system" +
                      extra);
  }
  static unsigned Mode(const fs::path& path) {
    struct stat st {};
    return stat(path.c_str(), &st) == 0 ? (st.st_mode & 07777) : 0;
  }
  fs::path dir_, destdir_;
  ServerProcess server_;
};

TEST_F(InstallScriptTest, InstallsTheLayoutAndKeepsConfigAndTokenOnUpgrade) {
  const CommandResult first = Install();
  ASSERT_EQ(first.status, 0) << first.output;
  const fs::path prefix = destdir_ / "opt/octoscope";
  const fs::path etc = destdir_ / "etc/octoscope";

  // The binary (the kernels are inside it), the whole web client, the docs.
  EXPECT_EQ(Mode(prefix / "bin/octoscope"), 0755u);
  EXPECT_EQ(ReadFile(prefix / "bin/octoscope"), ReadFile(OCTOSCOPE_BINARY));
  size_t web_files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(kSource / "web")) {
    if (!entry.is_regular_file()) continue;
    const fs::path installed =
        prefix / "share/octoscope/web" / fs::relative(entry.path(), kSource / "web");
    EXPECT_EQ(ReadFile(installed), ReadFile(entry.path())) << installed;
    ++web_files;
  }
  EXPECT_GT(web_files, 3u);
  EXPECT_TRUE(fs::is_regular_file(prefix / "share/doc/octoscope/deploy.md"));
  EXPECT_TRUE(fs::is_regular_file(prefix / "share/octoscope/config.example.json"));

  // Config (the example), token (256 random bits, hex), both 0640; cache and state dirs 0750.
  EXPECT_EQ(ReadFile(etc / "config.json"), ReadFile(kSource / "deploy/config.example.json"));
  EXPECT_TRUE(json::parse(ReadFile(etc / "config.json"), nullptr, false).is_object());
  EXPECT_EQ(Mode(etc / "config.json"), 0640u);
  const std::string token = ReadFile(etc / "token");
  ASSERT_EQ(token.size(), 65u) << token;
  EXPECT_EQ(token.find_first_not_of("0123456789abcdef"), 64u);
  EXPECT_EQ(Mode(etc / "token"), 0640u);
  EXPECT_EQ(Mode(etc), 0750u);
  EXPECT_EQ(Mode(destdir_ / "var/cache/octoscope"), 0750u);
  EXPECT_EQ(Mode(destdir_ / "var/lib/octoscope"), 0750u);

  // The unit points at the installed binary and documentation.
  const std::string unit = ReadFile(destdir_ / "lib/systemd/system/octoscope.service");
  EXPECT_NE(unit.find("\nExecStart=/opt/octoscope/bin/octoscope serve --config "
                      "/etc/octoscope/config.json\n"),
            std::string::npos)
      << unit;
  EXPECT_NE(unit.find("Documentation=file:///opt/octoscope/share/doc/octoscope/deploy.md"),
            std::string::npos);

  // Upgrade: an edited config and the token are kept; no temporary files are left behind.
  WriteFile(etc / "config.json", "{\"port\": 9999}\n");
  const CommandResult second = Install();
  ASSERT_EQ(second.status, 0) << second.output;
  EXPECT_EQ(ReadFile(etc / "config.json"), "{\"port\": 9999}\n");
  EXPECT_EQ(ReadFile(etc / "token"), token);
  for (const auto& entry : fs::recursive_directory_iterator(destdir_)) {
    const std::string name = entry.path().filename().string();
    EXPECT_TRUE(name.find(".new") == std::string::npos && name != "web.old") << entry.path();
  }
}

TEST_F(InstallScriptTest, TheInstalledBinaryServesTheInstalledWebClient) {
  const CommandResult installed = Install();
  ASSERT_EQ(installed.status, 0) << installed.output;
  // Mark the installed page, so that it can be told from the checkout's.
  const fs::path index = destdir_ / "opt/octoscope/share/octoscope/web/index.html";
  const std::string page = ReadFile(index) + "<!-- installed copy -->\n";
  // The installed example config is accepted as it is (the strict parser knows every key);
  // flags override what would touch the machine's own folders.
  fs::create_directories(dir_ / "scans");
  fs::permissions(index, fs::perms::owner_write, fs::perm_options::add);
  WriteFile(index, page);
  ASSERT_TRUE(server_.Start((destdir_ / "opt/octoscope/bin/octoscope").string(),
                            {"--config", (destdir_ / "etc/octoscope/config.json").string(),
                             "--data", (dir_ / "scans").string(), "--port", "0", "--cache",
                             (dir_ / "cache").string(), "--state-dir", (dir_ / "state").string(),
                             "--token-file", (destdir_ / "etc/octoscope/token").string(),
                             "--ram-mb", "128", "--device-mb", "64", "--device", "cpu"},
                            (dir_ / "server.log").string()))
      << server_.error() << ReadFile(dir_ / "server.log");
  const std::string token = ReadFile(destdir_ / "etc/octoscope/token").substr(0, 64);
  EXPECT_EQ(server_.token(), token);
  auto served = net::testing::Fetch(server_.port(), http::verb::get, "/");
  EXPECT_EQ(served.status, 200);
  EXPECT_EQ(served.body, page);
}

TEST_F(InstallScriptTest, RefusesBadArguments) {
  CommandResult r = RunCommand("bash " + Quoted(kSource / "deploy/install.sh") + " --frobnicate");
  EXPECT_EQ(r.status, 64) << r.output;
  r = RunCommand("bash " + Quoted(kSource / "deploy/install.sh") + " --build " +
                 Quoted(dir_ / "nothing") + " --destdir " + Quoted(destdir_));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("no octoscope binary"), std::string::npos) << r.output;
  r = RunCommand("bash " + Quoted(kSource / "deploy/install.sh") + " --prefix relative/path");
  EXPECT_EQ(r.status, 2) << r.output;
}

}  // namespace
}  // namespace octoscope::deploy
