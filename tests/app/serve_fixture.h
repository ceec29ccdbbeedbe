// ServeFixture: the shared set-up of the end-to-end tests of `octoscope serve` (serve_test,
// hostile_test, soak_test): the real binary on a loopback port (ServerProcess) with a known
// token, a streamed test volume of known voxels, and helpers that drive real HTTP and WebSocket
// clients (Beast) — reading events and frames, acknowledging frames as the browser does, and
// checking a lossless MIP frame against the voxels. Single-threaded use per client.
#ifndef OCTOSCOPE_TESTS_APP_SERVE_FIXTURE_H_
#define OCTOSCOPE_TESTS_APP_SERVE_FIXTURE_H_

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "app/server_process.h"
#include "app/ws_frames.h"
#include "encode/png_test_decoder.h"
#include "net/net_test_client.h"
#include "protocol/frame_header.h"

namespace octoscope::testing {

namespace serve_fixture {
namespace fs = std::filesystem;
namespace http = boost::beast::http;
using json = nlohmann::json;
using net::testing::Fetch;
using net::testing::WsClient;
using std::chrono::milliseconds;
using std::chrono::seconds;
}  // namespace serve_fixture
using namespace serve_fixture;  // NOLINT: the tests' vocabulary.

inline constexpr char kToken[] = "test-token-0123456789abcdef";

// A perspective camera on an orbit around the test volume; `i` picks the position.
inline json OrbitCamera(int i) {
  return {{"projection", "perspective"},
          {"position", {60.0 * std::cos(0.3 * i), -20.0, 60.0 * std::sin(0.3 * i)}},
          {"target", {10.0, 7.5, 20.0}}};
}

class ServeFixture : public ::testing::Test {
 protected:
  // Flags added to the server's command line (after the fixture's own).
  virtual std::vector<std::string> ExtraArgs() const { return {}; }

  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope-serve-test-" + std::to_string(getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_TRUE(server_.Start(OCTOSCOPE_BINARY, ServeArgs(), (dir_ / "server.log").string()))
        << server_.error();
  }
  // The server's command line: a fresh cache and state folder of the test, then ExtraArgs().
  std::vector<std::string> ServeArgs() const {
    std::vector<std::string> args = {"--port",      "0",
                                     "--cache",     (dir_ / "cache").string(),
                                     "--state-dir", (dir_ / "state").string(),
                                     "--token",     kToken,
                                     "--ram-mb",    "256",
                                     "--device",    "cpu"};
    for (const std::string& a : ExtraArgs()) args.push_back(a);
    return args;
  }
  // Stops the server (SIGTERM; it must exit 0) and starts it again with the same command line,
  // cache and state folder.
  bool Restart() {
    EXPECT_EQ(server_.Stop(), 0);
    const bool started =
        server_.Start(OCTOSCOPE_BINARY, ServeArgs(), (dir_ / "server.log.restarted").string());
    EXPECT_TRUE(started) << server_.error();
    return started;
  }
  void TearDown() override {
    if (server_.running()) {
      EXPECT_EQ(server_.Stop(), 0);
    }
    fs::remove_all(dir_);
  }

  std::string Auth(const std::string& target) const {
    return target + (target.find('?') == std::string::npos ? "?" : "&") + "token=" + kToken;
  }

  // Creates a stream of the test volume's shape and sends all of it; returns its id.
  std::string StreamTestVolume(const TestVolume& v, bool send = true) {
    auto created = Fetch(server_.port(), http::verb::post, Auth("/api/datasets"), {},
                         json{{"name", "test stream"},
                              {"size", {v.sx, v.sy, v.sz}},
                              {"channels", 2},
                              {"dtype", "uint16"},
                              {"spacing", {0.5, 0.5, 2.0}}}
                             .dump());
    EXPECT_EQ(created.status, 201) << created.body;
    const std::string id = json::parse(created.body).value("id", "");
    if (!send) return id;
    for (int c = 0; c < 2; ++c) {
      // Single planes first (how an acquisition sends them), then the rest in one slab.
      for (int64_t z = 0; z < 5; ++z) PutSlab(id, c, z, 1, v.Planes(c, z, 1), 200);
      PutSlab(id, c, 5, v.sz - 5, v.Planes(c, 5, v.sz - 5), 200);
    }
    return id;
  }

  net::testing::HttpResult PutSlab(const std::string& id, int c, int64_t z, int64_t depth,
                                   std::string body, int expect_status) {
    auto r = Fetch(server_.port(), http::verb::put,
                   Auth("/api/datasets/" + id + "/slabs?z=" + std::to_string(z) +
                        "&depth=" + std::to_string(depth) + "&channel=" + std::to_string(c)),
                   {{"Content-Type", "application/octet-stream"}}, std::move(body));
    EXPECT_EQ(r.status, expect_status) << r.body;
    return r;
  }

  bool ConnectWs(WsClient& ws) {
    const std::string error = ws.Connect(server_.port(), Auth("/ws"));
    EXPECT_EQ(error, "");
    return error.empty();
  }

  // Opens `id` with an orthographic z camera that maps pixel (x, y) onto voxel column (x, y),
  // channel 0 alone in MIP with `window` over [0, window_hi], lossless finals, the 3-D viewport
  // at the volume's size.
  static void OpenOrthoMip(WsClient& ws, const std::string& id, const TestVolume& v,
                           double window_hi) {
    const double cx = v.sx * 0.5 / 2, cy = v.sy * 0.5 / 2, cz = v.sz * 2.0 / 2;
    json camera = {{"projection", "ortho"},
                   {"position", {cx, cy, -100.0}},
                   {"target", {cx, cy, cz}},
                   {"up", {0, -1, 0}},
                   {"ortho_height", v.sy * 0.5}};
    json params = {{"mode", "mip"},
                   {"channels",
                    {{{"enabled", true},
                      {"color", {1, 1, 1}},
                      {"window", window_hi},
                      {"level", window_hi / 2},
                      {"gamma", 1}},
                     {{"enabled", false}}}}};
    ASSERT_TRUE(ws.Send(json{{"type", "hello"}, {"client", "serve_test"}, {"protocol", 1}}.dump()));
    ASSERT_TRUE(ReadEvent(ws, "welcome").has_value());
    ASSERT_TRUE(ws.Send(json{{"type", "quality"}, {"lossless_final", true}}.dump()));
    ASSERT_TRUE(ws.Send(
        json{{"type", "open"}, {"dataset", id}, {"state", {{"camera", camera}, {"params", params}}}}
            .dump()));
    auto opened = ReadEvent(ws, "opened");
    ASSERT_TRUE(opened.has_value());
    EXPECT_EQ((*opened)["dataset"]["id"], id);
    ASSERT_TRUE(ws.Send(
        json{{"type", "viewport"}, {"view", "3d"}, {"width", v.sx}, {"height", v.sy}, {"dpr", 1}}
            .dump()));
  }

  // Max |pixel − expected| over the image, in 1/255 steps, for channel 0 through the window.
  static int MaxMipError(const testing::DecodedPng& png, const TestVolume& v, double window_hi) {
    int worst = 0;
    for (int64_t y = 0; y < v.sy; ++y) {
      for (int64_t x = 0; x < v.sx; ++x) {
        const double t = std::clamp(v.ColumnMax(0, x, y) / window_hi, 0.0, 1.0);
        const int expected = static_cast<int>(std::lround(t * 255));
        for (int c = 0; c < 3; ++c) {
          worst = std::max(
              worst, std::abs(png.At(static_cast<int>(x), static_cast<int>(y), c) - expected));
        }
      }
    }
    return worst;
  }

  // Sends an orbit camera and reads (acknowledging) until a frame of a state newer than
  // `*version` (the newest this client saw; updated); false when none comes within `timeout`.
  // Frames of older states still on their way are skipped.
  static bool CameraGetsAFrame(WsClient& ws, int i, uint64_t* version,
                               seconds timeout = seconds(30)) {
    if (!ws.Send(json{{"type", "camera"}, {"camera", OrbitCamera(i)}}.dump())) return false;
    auto frame = ReadFrameUntil(
        ws, [&](const Frame& f) { return f.header.state_version > *version; }, timeout);
    if (frame) *version = frame->header.state_version;
    return frame.has_value();
  }

  // The dataset's JSON (GET /api/datasets/ID).
  json DatasetJson(const std::string& id) const {
    auto r = Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id));
    EXPECT_EQ(r.status, 200) << r.body;
    return r.status == 200 ? json::parse(r.body) : json();
  }

  // Reads the stored voxels of channel 0 back through the server: a fresh client's lossless
  // final orthographic MIP must equal the column maxima of `v` (within 1/255). Returns the worst
  // error (256 when no final frame came).
  int StoredMipError(const std::string& id, const TestVolume& v, double window_hi = 300) {
    WsClient ws;
    if (!ConnectWs(ws)) return 256;
    OpenOrthoMip(ws, id, v, window_hi);
    int worst = 256;
    ReadFrameUntil(ws, [&](const Frame& f) {
      if (!f.header.final) return false;
      auto png = testing::DecodeTestPng(f.image);
      if (!png.ok) return false;
      worst = MaxMipError(png, v, window_hi);
      return true;
    });
    ws.Close();
    return worst;
  }

  // The number of open WebSocket sessions (GET /api/health).
  int Sessions() const {
    auto r = Fetch(server_.port(), http::verb::get, "/api/health");
    return r.status == 200 ? json::parse(r.body).value("sessions", -1) : -1;
  }

  fs::path dir_;
  ServerProcess server_;
};

}  // namespace octoscope::testing

#endif  // OCTOSCOPE_TESTS_APP_SERVE_FIXTURE_H_
