// Sharing end to end (docs/protocol.md, "Sharing"): the real `octoscope serve` binary on a
// loopback port, an owner, viewers and controllers as real WebSocket clients. Live join with
// roles, state following, revocation, per-participant frame sizes from one render (checked
// against an area average of the larger frame), a stalled participant, view links across a
// server restart, corrupt view files, and the session limits.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "app/server_process.h"
#include "app/ws_frames.h"
#include "encode/png_test_decoder.h"
#include "net/net_test_client.h"
#include "protocol/frame_header.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
namespace http = boost::beast::http;
using net::testing::Fetch;
using net::testing::WsClient;
using std::chrono::seconds;
using testing::Frame;
using testing::ReadEvent;
using testing::ReadFrameUntil;
using testing::ServerProcess;
using testing::TestVolume;

constexpr char kToken[] = "share-test-token-0123456789";

json OrthoCamera(const TestVolume& v, double x_offset = 0) {
  const double cx = v.sx * 0.5 / 2, cy = v.sy * 0.5 / 2, cz = v.sz * 2.0 / 2;
  return {{"projection", "ortho"},
          {"position", {cx + x_offset, cy, -100.0}},
          {"target", {cx + x_offset, cy, cz}},
          {"up", {0, -1, 0}},
          {"ortho_height", v.sy * 0.5}};
}

json MipParams(double window_hi) {
  return {{"mode", "mip"},
          {"channels",
           {{{"enabled", true},
             {"color", {1, 1, 1}},
             {"window", window_hi},
             {"level", window_hi / 2},
             {"gamma", 1}},
            {{"enabled", false}}}}};
}

json Hello(const std::string& name = "") {
  json hello = {{"type", "hello"}, {"client", "share_test"}, {"protocol", 1}};
  if (!name.empty()) hello["name"] = name;
  return hello;
}

json Viewport(int w, int h) {
  return {{"type", "viewport"}, {"view", "3d"}, {"width", w}, {"height", h}, {"dpr", 1}};
}

json CameraMessage(const TestVolume& v, double x_offset) {
  return {{"type", "camera"}, {"camera", OrthoCamera(v, x_offset)}};
}

// Sum of a counter over all its label sets in a Prometheus text page.
double MetricSum(const std::string& page, const std::string& name, const std::string& labels) {
  double sum = 0;
  std::istringstream in(page);
  std::string line;
  while (std::getline(in, line)) {
    if (!line.starts_with(name + "{") && !line.starts_with(name + " ")) continue;
    if (!labels.empty() && line.find(labels) == std::string::npos) continue;
    sum += std::stod(line.substr(line.rfind(' ') + 1));
  }
  return sum;
}

class ShareTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("octoscope-share-test-" + std::to_string(getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "state");
  }
  void TearDown() override {
    if (server_.running()) {
      EXPECT_EQ(server_.Stop(), 0);
    }
    fs::remove_all(dir_);
  }

  bool StartServer(std::vector<std::string> extra = {}) {
    std::vector<std::string> args = {"--port",   "0",    "--cache",     (dir_ / "cache").string(),
                                     "--token",  kToken, "--ram-mb",    "256",
                                     "--device", "cpu",  "--state-dir", (dir_ / "state").string()};
    args.insert(args.end(), extra.begin(), extra.end());
    const bool started = server_.Start(OCTOSCOPE_BINARY, args, (dir_ / "server.log").string());
    EXPECT_TRUE(started) << server_.error();
    return started;
  }

  std::string Auth(const std::string& target) const {
    return target + (target.find('?') == std::string::npos ? "?" : "&") + "token=" + kToken;
  }

  std::string StreamTestVolume(const TestVolume& v) {
    auto created = Fetch(server_.port(), http::verb::post, Auth("/api/datasets"), {},
                         json{{"name", "share stream"},
                              {"size", {v.sx, v.sy, v.sz}},
                              {"channels", 2},
                              {"dtype", "uint16"},
                              {"spacing", {0.5, 0.5, 2.0}}}
                             .dump());
    EXPECT_EQ(created.status, 201) << created.body;
    const std::string id = json::parse(created.body).value("id", "");
    for (int c = 0; c < 2; ++c) {
      auto r = Fetch(server_.port(), http::verb::put,
                     Auth("/api/datasets/" + id + "/slabs?z=0&depth=" + std::to_string(v.sz) +
                          "&channel=" + std::to_string(c)),
                     {{"Content-Type", "application/octet-stream"}}, v.Planes(c, 0, v.sz));
      EXPECT_EQ(r.status, 200) << r.body;
    }
    return id;
  }

  // A user connection: hello, welcome; returns the welcome event.
  json ConnectOwner(WsClient& ws, const std::string& name = "alice") {
    EXPECT_EQ(ws.Connect(server_.port(), Auth("/ws")), "");
    ws.Send(Hello(name).dump());
    auto welcome = ReadEvent(ws, "welcome");
    EXPECT_TRUE(welcome.has_value());
    return welcome.value_or(json::object());
  }

  // A share-link connection: `/ws?share=TOKEN` (no user token); "" or the handshake failure.
  std::string ConnectShare(WsClient& ws, const std::string& token) {
    return ws.Connect(server_.port(), "/ws?share=" + token);
  }

  // Owner: opens `id` as an orthographic MIP, lossless finals, the 3-D viewport w x h.
  void OpenOrthoMip(WsClient& ws, const std::string& id, const TestVolume& v, int w, int h) {
    ws.Send(json{{"type", "quality"}, {"lossless_final", true}}.dump());
    ws.Send(json{{"type", "open"},
                 {"dataset", id},
                 {"state", {{"camera", OrthoCamera(v)}, {"params", MipParams(300)}}}}
                .dump());
    auto opened = ReadEvent(ws, "opened");
    ASSERT_TRUE(opened.has_value());
    ws.Send(Viewport(w, h).dump());
  }

  // The owner opens `id` (OpenOrthoMip at 40 x 30) and creates a `role` link; its token.
  std::string OpenAndShare(WsClient& owner, const std::string& id, const TestVolume& v,
                           const std::string& role) {
    ConnectOwner(owner);
    OpenOrthoMip(owner, id, v, 40, 30);
    return CreateShare(owner, role).value("token", "");
  }

  // A guest joins through share link `token`: hello, then the session's `opened`.
  void JoinAsGuest(WsClient& guest, const std::string& token, const std::string& name) {
    ASSERT_EQ(ConnectShare(guest, token), "");
    guest.Send(Hello(name).dump());
    ASSERT_TRUE(ReadEvent(guest, "opened").has_value());
  }

  json CreateShare(WsClient& owner, const std::string& role) {
    owner.Send(json{{"type", "share_create"}, {"role", role}}.dump());
    auto created = ReadEvent(owner, "share_created");
    EXPECT_TRUE(created.has_value());
    return created.value_or(json::object());
  }

  fs::path dir_;
  ServerProcess server_;
};

TEST_F(ShareTest, ViewerFollowsCannotDriveUntilPromotedAndRevocationDisconnects) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  const json welcome = ConnectOwner(owner);
  EXPECT_EQ(welcome["role"], "owner");
  EXPECT_EQ(welcome["resume"].get<std::string>().size(), 32u);
  const std::string owner_id = welcome["participant"];
  OpenOrthoMip(owner, id, v, 40, 30);
  auto first = ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; });
  ASSERT_TRUE(first.has_value());

  // Share links: 128-bit tokens, URLs on the server's address.
  const json viewer_link = CreateShare(owner, "viewer");
  const std::string viewer_token = viewer_link["token"];
  EXPECT_TRUE(std::regex_match(viewer_token, std::regex("[0-9a-f]{32}"))) << viewer_token;
  EXPECT_EQ(viewer_link["role"], "viewer");
  EXPECT_TRUE(viewer_link["expires"].is_null());
  EXPECT_EQ(viewer_link["url"].get<std::string>(),
            "http://127.0.0.1:" + std::to_string(server_.port()) + "/?share=" + viewer_token);
  const json controller_link = CreateShare(owner, "controller");
  EXPECT_NE(controller_link["token"], viewer_token);

  // The viewer joins: welcome (viewer), opened with the session's state, participants.
  WsClient viewer;
  ASSERT_EQ(ConnectShare(viewer, viewer_token), "");
  viewer.Send(Hello("bob").dump());
  auto viewer_welcome = ReadEvent(viewer, "welcome");
  ASSERT_TRUE(viewer_welcome.has_value());
  EXPECT_EQ((*viewer_welcome)["role"], "viewer");
  EXPECT_FALSE(viewer_welcome->contains("resume"));
  EXPECT_EQ((*viewer_welcome)["session"], welcome["session"]);
  const std::string viewer_id = (*viewer_welcome)["participant"];
  auto viewer_opened = ReadEvent(viewer, "opened");
  ASSERT_TRUE(viewer_opened.has_value());
  EXPECT_EQ((*viewer_opened)["dataset"]["id"], id);
  EXPECT_EQ((*viewer_opened)["version"].get<uint64_t>(), first->header.state_version);
  auto participants = ReadEvent(viewer, "participants");
  ASSERT_TRUE(participants.has_value());
  ASSERT_EQ((*participants)["participants"].size(), 2u) << participants->dump();
  EXPECT_EQ((*participants)["participants"][0]["id"], owner_id);
  EXPECT_EQ((*participants)["participants"][0]["name"], "alice");
  EXPECT_EQ((*participants)["participants"][0]["role"], "owner");
  EXPECT_EQ((*participants)["participants"][0]["you"], false);
  EXPECT_EQ((*participants)["participants"][1]["name"], "bob");
  EXPECT_EQ((*participants)["participants"][1]["role"], "viewer");
  EXPECT_EQ((*participants)["participants"][1]["you"], true);
  EXPECT_EQ((*participants)["participants"][1]["driving"], false);
  viewer.Send(Viewport(40, 30).dump());
  auto viewer_first = ReadFrameUntil(viewer, [](const Frame& f) { return f.header.final; });
  ASSERT_TRUE(viewer_first.has_value());
  EXPECT_EQ(viewer_first->header.state_version, first->header.state_version);

  // The owner moves the camera: the viewer is told the new state and gets its frames.
  owner.Send(CameraMessage(v, 1.0).dump());
  auto followed = ReadEvent(viewer, "state");
  ASSERT_TRUE(followed.has_value());
  EXPECT_EQ((*followed)["by"], owner_id);
  const uint64_t moved_version = (*followed)["version"];
  EXPECT_GT(moved_version, first->header.state_version);
  EXPECT_DOUBLE_EQ((*followed)["state"]["camera"]["position"][0].get<double>(),
                   v.sx * 0.5 / 2 + 1.0);
  auto viewer_moved = ReadFrameUntil(
      viewer, [&](const Frame& f) { return f.header.state_version >= moved_version; });
  ASSERT_TRUE(viewer_moved.has_value());
  EXPECT_EQ(viewer_moved->header.state_version, moved_version);
  auto driving = ReadEvent(viewer, "participants");
  ASSERT_TRUE(driving.has_value());

  // The viewer tries to drive: refused (non-fatal), nothing changes.
  viewer.Send(CameraMessage(v, 5.0).dump());
  auto refused = ReadEvent(viewer, "error");
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ((*refused)["message"], "viewers cannot drive the view");
  EXPECT_EQ((*refused)["request"], "camera");
  EXPECT_EQ((*refused)["fatal"], false);
  viewer.Send(json{{"type", "share_create"}, {"role", "viewer"}}.dump());
  refused = ReadEvent(viewer, "error");
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE((*refused)["message"].get<std::string>().find("only the owner"), std::string::npos);
  // Still the owner's state: a ping round trip through the owner sees no state event.
  owner.Send(json{{"type", "ping"}, {"t", 7}}.dump());
  for (;;) {
    auto m = owner.Read(seconds(20));
    ASSERT_TRUE(m.ok);
    if (m.binary) {
      auto frame = testing::DecodeFrame(m.data);
      ASSERT_TRUE(frame.has_value());
      testing::Ack(owner, frame->header.frame_id);
      EXPECT_LE(frame->header.state_version, moved_version);
      continue;
    }
    const json event = json::parse(m.data);
    ASSERT_NE(event["type"], "state") << "a viewer's camera changed the state";
    if (event["type"] == "pong") break;
  }

  // Promoted to controller, the same participant drives.
  owner.Send(json{{"type", "participant_role"}, {"participant", viewer_id}, {"role", "controller"}}
                 .dump());
  bool promoted = false;
  for (int i = 0; i < 10 && !promoted; ++i) {
    auto event = ReadEvent(viewer, "participants");
    ASSERT_TRUE(event.has_value());
    for (const auto& p : (*event)["participants"]) {
      promoted |= p["id"] == viewer_id && p["role"] == "controller";
    }
  }
  ASSERT_TRUE(promoted);
  viewer.Send(CameraMessage(v, 2.0).dump());
  auto driven = ReadEvent(owner, "state");
  ASSERT_TRUE(driven.has_value());
  EXPECT_EQ((*driven)["by"], viewer_id);
  const uint64_t driven_version = (*driven)["version"];
  EXPECT_GT(driven_version, moved_version);
  // Right after the state event, everyone learns who drives.
  auto drivers = ReadEvent(owner, "participants");
  ASSERT_TRUE(drivers.has_value());
  for (const auto& p : (*drivers)["participants"]) {
    EXPECT_EQ(p["driving"], p["id"] == viewer_id) << drivers->dump();
    EXPECT_EQ(p["you"], p["id"] == owner_id);
  }
  ASSERT_TRUE(ReadFrameUntil(owner, [&](const Frame& f) {
                return f.header.state_version == driven_version;
              }).has_value());

  // A controller joins through the other link and is listed; the owner sees who drives.
  WsClient controller;
  ASSERT_EQ(ConnectShare(controller, controller_link["token"]), "");
  controller.Send(Hello("carol").dump());
  auto controller_welcome = ReadEvent(controller, "welcome");
  ASSERT_TRUE(controller_welcome.has_value());
  EXPECT_EQ((*controller_welcome)["role"], "controller");
  auto listed = ReadEvent(controller, "participants");
  ASSERT_TRUE(listed.has_value());
  ASSERT_EQ((*listed)["participants"].size(), 3u);
  EXPECT_EQ((*listed)["participants"][2]["name"], "carol");
  EXPECT_EQ((*listed)["participants"][2]["role"], "controller");
  EXPECT_EQ((*listed)["participants"][2]["you"], true);

  // Revoking the viewer link closes bob's connection (4001); the link is refused afterwards.
  owner.Send(json{{"type", "share_revoke"}, {"token", viewer_token}}.dump());
  EXPECT_EQ(viewer.ReadUntilClose(), 4001);
  auto shares = ReadEvent(owner, "shares");
  ASSERT_TRUE(shares.has_value());
  ASSERT_EQ((*shares)["shares"].size(), 1u);
  EXPECT_EQ((*shares)["shares"][0]["token"], controller_link["token"]);
  WsClient again;
  EXPECT_NE(ConnectShare(again, viewer_token), "");
  EXPECT_EQ(again.handshake_status(), 401);
  // A live link reads datasets and nothing else.
  const std::string share = "?share=" + controller_link["token"].get<std::string>();
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets" + share).status, 200);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/metrics" + share).status, 403);
  EXPECT_EQ(Fetch(server_.port(), http::verb::post, "/api/datasets" + share, {}, "{}").status, 403);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets?share=" + viewer_token).status,
            401);
  // The controller was not affected.
  controller.Send(json{{"type", "ping"}, {"t", 1}}.dump());
  EXPECT_TRUE(ReadEvent(controller, "pong").has_value());
}

TEST_F(ShareTest, ParticipantsGetTheirOwnSizesFromOneRender) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  ConnectOwner(owner);
  OpenOrthoMip(owner, id, v, 80, 60);
  ASSERT_TRUE(ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; }).has_value());
  const json link = CreateShare(owner, "viewer");
  WsClient viewer;
  ASSERT_EQ(ConnectShare(viewer, link["token"]), "");
  viewer.Send(Hello().dump());
  ASSERT_TRUE(ReadEvent(viewer, "opened").has_value());
  viewer.Send(json{{"type", "quality"}, {"lossless_final", true}}.dump());
  viewer.Send(Viewport(40, 30).dump());  // The same aspect, half the size.
  ASSERT_TRUE(ReadFrameUntil(viewer, [](const Frame& f) { return f.header.final; }).has_value());
  // Quiet: every final of the current state has gone out (the owner's too).
  ASSERT_TRUE(ReadFrameUntil(
                  owner, [](const Frame& f) { return f.header.final; }, seconds(10))
                  .has_value());

  const std::string before = Fetch(server_.port(), http::verb::get, Auth("/metrics")).body;
  owner.Send(CameraMessage(v, 0.75).dump());
  auto big = ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; });
  auto small = ReadFrameUntil(viewer, [](const Frame& f) { return f.header.final; });
  ASSERT_TRUE(big.has_value() && small.has_value());
  EXPECT_EQ(big->header.state_version, small->header.state_version);
  EXPECT_EQ(big->header.width, 80);
  EXPECT_EQ(big->header.height, 60);
  EXPECT_EQ(small->header.width, 40);
  EXPECT_EQ(small->header.height, 30);
  // One final render served both.
  const std::string after = Fetch(server_.port(), http::verb::get, Auth("/metrics")).body;
  const std::string final_count = "octoscope_render_ms_count";
  EXPECT_EQ(MetricSum(after, final_count, "tier=\"final\"") -
                MetricSum(before, final_count, "tier=\"final\""),
            1)
      << after;
  EXPECT_EQ(MetricSum(after, "octoscope_frames_sent_total", "tier=\"final\"") -
                MetricSum(before, "octoscope_frames_sent_total", "tier=\"final\""),
            2);

  // The small frame is the big one area-averaged (2 x 2 boxes), within rounding.
  auto big_png = testing::DecodeTestPng(big->image);
  auto small_png = testing::DecodeTestPng(small->image);
  ASSERT_TRUE(big_png.ok && small_png.ok);
  int worst = 0;
  double total = 0;
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 40; ++x) {
      for (int c = 0; c < 3; ++c) {
        const double mean =
            (big_png.At(2 * x, 2 * y, c) + big_png.At(2 * x + 1, 2 * y, c) +
             big_png.At(2 * x, 2 * y + 1, c) + big_png.At(2 * x + 1, 2 * y + 1, c)) /
            4.0;
        const int error =
            static_cast<int>(std::ceil(std::abs(small_png.At(x, y, c) - mean) - 1e-9));
        worst = std::max(worst, error);
        total += small_png.At(x, y, c);
      }
    }
  }
  EXPECT_LE(worst, 1);
  EXPECT_GT(total, 0) << "the frames are black: nothing was compared";
}

TEST_F(ShareTest, AStalledParticipantDoesNotStopTheOthers) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  ConnectOwner(owner);
  OpenOrthoMip(owner, id, v, 40, 30);
  ASSERT_TRUE(ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; }).has_value());
  const json link = CreateShare(owner, "viewer");
  // The stalled viewer shares the owner's render group (same aspect, larger) and never reads.
  WsClient stalled;
  ASSERT_EQ(ConnectShare(stalled, link["token"]), "");
  stalled.ShrinkReceiveBuffer();
  stalled.Send(Hello().dump());
  stalled.Send(Viewport(400, 300).dump());
  owner.Send(json{{"type", "interaction"}, {"active", true}}.dump());
  int answered = 0;
  uint64_t last_version = 0;
  for (int i = 0; i < 10; ++i) {
    owner.Send(CameraMessage(v, 0.1 * (i + 1)).dump());
    auto frame = ReadFrameUntil(
        owner, [&](const Frame& f) { return f.header.state_version > last_version; }, seconds(30));
    if (!frame) continue;
    ++answered;
    EXPECT_GE(frame->header.state_version, last_version);  // Never an older state.
    last_version = frame->header.state_version;
  }
  EXPECT_EQ(answered, 10);
  owner.Send(json{{"type", "interaction"}, {"active", false}}.dump());
  EXPECT_TRUE(ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; }).has_value());
}

TEST_F(ShareTest, ViewLinksSurviveARestartAndOpenExactlyTheSavedState) {
  // A dataset in a --data folder keeps its id across restarts.
  const fs::path data = dir_ / "data";
  fs::create_directories(data);
  const std::string demo = std::string(OCTOSCOPE_BINARY) + " demo --out '" +
                           (data / "embryo").string() + "' --size 48,40,24 > /dev/null 2>&1";
  ASSERT_EQ(std::system(demo.c_str()), 0);
  ASSERT_TRUE(StartServer({"--data", data.string()}));
  auto listed = json::parse(Fetch(server_.port(), http::verb::get, Auth("/api/datasets")).body);
  ASSERT_TRUE(listed.is_array() && !listed.empty()) << listed.dump();
  const std::string id = listed[0]["id"];

  WsClient owner;
  ConnectOwner(owner);
  const json camera = {{"projection", "perspective"},
                       {"position", {80.0, -30.0, -50.0}},
                       {"target", {10.0, 9.0, 20.0}},
                       {"up", {0, 0, 1}},
                       {"fov_y_degrees", 40}};
  owner.Send(json{{"type", "open"},
                  {"dataset", id},
                  {"state",
                   {{"camera", camera},
                    {"slices", {{"position_um", {3.0, 4.0, 5.0}}}},
                    {"layout", {{"maximized", "y"}}}}}}
                 .dump());
  auto opened = ReadEvent(owner, "opened");
  ASSERT_TRUE(opened.has_value());
  owner.Send(json{{"type", "params"}, {"params", {{"mode", "dvr"}}}}.dump());
  owner.Send(json{{"type", "view_save"}}.dump());
  auto saved = ReadEvent(owner, "view_saved");
  ASSERT_TRUE(saved.has_value());
  const std::string view = (*saved)["id"];
  EXPECT_TRUE(std::regex_match(view, std::regex("[A-Za-z0-9_-]{22}"))) << view;
  EXPECT_EQ((*saved)["url"].get<std::string>(),
            "http://127.0.0.1:" + std::to_string(server_.port()) + "/?view=" + view);
  // The saved state is the session's state after the params change.
  owner.Send(json{{"type", "slices"}, {"position_um", {3.0, 4.0, 5.0}}}.dump());
  auto state = ReadEvent(owner, "state", nullptr, seconds(5));  // None expected: no clamp.
  (void)state;
  const fs::path file = dir_ / "state" / "views" / (view + ".json");
  ASSERT_TRUE(fs::exists(file));
  struct stat st {};
  ASSERT_EQ(::stat(file.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  auto rest = Fetch(server_.port(), http::verb::get, Auth("/api/views/" + view));
  ASSERT_EQ(rest.status, 200) << rest.body;
  const json document = json::parse(rest.body);
  EXPECT_EQ(document["dataset"], id);
  EXPECT_EQ(document["state"]["params"]["mode"], "dvr");
  EXPECT_EQ(document["state"]["layout"]["maximized"], "y");
  owner.Close();

  // Restart with the same state folder: the link opens a new session with exactly that state.
  ASSERT_EQ(server_.Stop(), 0);
  ASSERT_TRUE(StartServer({"--data", data.string()}));
  WsClient fork;
  ASSERT_EQ(fork.Connect(server_.port(), "/ws?view=" + view), "");
  fork.Send(Hello().dump());
  auto welcome = ReadEvent(fork, "welcome");
  ASSERT_TRUE(welcome.has_value());
  EXPECT_EQ((*welcome)["role"], "owner");
  auto forked = ReadEvent(fork, "opened");
  ASSERT_TRUE(forked.has_value());
  EXPECT_EQ((*forked)["dataset"]["id"], id);
  EXPECT_EQ((*forked)["state"], document["state"]);
  // It renders.
  fork.Send(Viewport(48, 40).dump());
  EXPECT_TRUE(ReadFrameUntil(fork, [](const Frame& f) { return f.header.final; }).has_value());
  // The REST document is unchanged by the fork's later changes.
  fork.Send(json{{"type", "params"}, {"params", {{"mode", "mip"}}}}.dump());
  fork.Send(json{{"type", "ping"}, {"t", 1}}.dump());
  ASSERT_TRUE(ReadEvent(fork, "pong").has_value());
  EXPECT_EQ(json::parse(Fetch(server_.port(), http::verb::get, Auth("/api/views/" + view)).body),
            document);
}

TEST_F(ShareTest, ViewLinkIdsNeverReachTheLog) {
  // Whoever has a view link's id opens the view: the access log names the route, not the id.
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  ConnectOwner(owner);
  OpenOrthoMip(owner, id, v, 40, 30);
  owner.Send(json{{"type", "view_save"}}.dump());
  auto saved = ReadEvent(owner, "view_saved");
  ASSERT_TRUE(saved.has_value());
  const std::string view = (*saved)["id"];
  owner.Close();
  const uint16_t port = server_.port();
  EXPECT_EQ(Fetch(port, http::verb::get, Auth("/api/views/" + view)).status, 200);
  EXPECT_EQ(Fetch(port, http::verb::get, "/api/views/" + view + "?view=" + view).status, 200);
  WsClient fork;
  ASSERT_EQ(fork.Connect(port, "/ws?view=" + view), "");
  fork.Send(Hello().dump());
  EXPECT_TRUE(ReadEvent(fork, "welcome").has_value());
  fork.Close();
  EXPECT_EQ(Fetch(port, http::verb::get, Auth("/api/views/" + view + "/more")).status, 404);
  // Last: DELETE removes the link.
  for (const http::verb method : {http::verb::put, http::verb::post, http::verb::delete_}) {
    EXPECT_NE(Fetch(port, method, Auth("/api/views/" + view)).status, 0);
  }
  ASSERT_EQ(server_.Stop(), 0);  // Every line written.
  std::ifstream in(dir_ / "server.log");
  const std::string log((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(log.find(view), std::string::npos) << log;
  for (const char* method : {"GET", "DELETE", "PUT", "POST"}) {
    EXPECT_NE(log.find(std::string(method) + " /api/views/<redacted> "), std::string::npos)
        << method << "\n"
        << log;
  }
  EXPECT_NE(log.find("GET /api/views/<redacted>/more 404"), std::string::npos) << log;
}

TEST_F(ShareTest, ACorruptViewFileIsAClearErrorNotACrash) {
  const std::string bad = "AAAAAAAAAAAAAAAAAAAAAA";
  const std::string wrong = "BBBBBBBBBBBBBBBBBBBBBB";
  fs::create_directories(dir_ / "state" / "views");
  std::ofstream(dir_ / "state" / "views" / (bad + ".json")) << "{\"version\":1,\"dataset\":";
  std::ofstream(dir_ / "state" / "views" / (wrong + ".json"))
      << R"({"version":1,"dataset":"x","state":{"camera":{}},"extra":1})";
  ASSERT_TRUE(StartServer());
  for (const std::string& id : {bad, wrong}) {
    auto rest = Fetch(server_.port(), http::verb::get, Auth("/api/views/" + id));
    EXPECT_EQ(rest.status, 500) << rest.body;
    EXPECT_NE(rest.body.find("is not a valid view document"), std::string::npos) << rest.body;
    EXPECT_NE(rest.body.find(id), std::string::npos) << rest.body;
    // As a credential it opens nothing: refused at the upgrade, saying why.
    WsClient ws;
    EXPECT_NE(ws.Connect(server_.port(), "/ws?view=" + id), "");
    EXPECT_EQ(ws.handshake_status(), 401);
    EXPECT_NE(ws.handshake_body().find("is not a valid view document"), std::string::npos)
        << ws.handshake_body();
    // Opened by a user in a session, the document's problem is the error.
    WsClient user;
    ASSERT_EQ(user.Connect(server_.port(), Auth("/ws")), "");
    user.Send(Hello().dump());
    ASSERT_TRUE(ReadEvent(user, "welcome").has_value());
    user.Send(json{{"type", "open"}, {"view", id}}.dump());
    auto error = ReadEvent(user, "error");
    ASSERT_TRUE(error.has_value());
    EXPECT_NE((*error)["message"].get<std::string>().find("not a valid view document"),
              std::string::npos);
    EXPECT_EQ((*error)["fatal"], false);
  }
  EXPECT_EQ(
      Fetch(server_.port(), http::verb::get, Auth("/api/views/CCCCCCCCCCCCCCCCCCCCCC")).status,
      404);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, Auth("/api/views/../../etc")).status, 404);
  EXPECT_TRUE(server_.running());
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/health").status, 200);
}

TEST_F(ShareTest, SessionAndParticipantLimitsCloseWith1013) {
  ASSERT_TRUE(StartServer({"--max-sessions", "1", "--max-participants", "2"}));
  WsClient first;
  ConnectOwner(first);
  WsClient second;
  ASSERT_EQ(second.Connect(server_.port(), Auth("/ws")), "");
  auto error = ReadEvent(second, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ((*error)["message"], "too many sessions");
  EXPECT_EQ((*error)["fatal"], true);
  EXPECT_EQ(second.ReadUntilClose(), 1013);

  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  first.Send(json{{"type", "open"}, {"dataset", id}}.dump());
  ASSERT_TRUE(ReadEvent(first, "opened").has_value());
  const json link = CreateShare(first, "viewer");
  WsClient joined;
  ASSERT_EQ(ConnectShare(joined, link["token"]), "");
  joined.Send(Hello().dump());
  ASSERT_TRUE(ReadEvent(joined, "welcome").has_value());
  WsClient full;
  ASSERT_EQ(ConnectShare(full, link["token"]), "");
  error = ReadEvent(full, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ((*error)["message"], "session full");
  EXPECT_EQ(full.ReadUntilClose(), 1013);

  // A session whose owner left is kept (parked) for the owner's reconnect; a new session takes
  // its place only when it is needed.
  joined.Close();
  first.Close();
  // Once the server has seen both leave, no session has a participant.
  const auto deadline = std::chrono::steady_clock::now() + seconds(20);
  int active = -1;
  while (std::chrono::steady_clock::now() < deadline) {
    active = json::parse(Fetch(server_.port(), http::verb::get, "/api/health").body)["sessions"];
    if (active == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ(active, 0);
  WsClient third;
  ConnectOwner(third);
  third.Send(json{{"type", "ping"}, {"t", 3}}.dump());
  EXPECT_TRUE(ReadEvent(third, "pong").has_value());
}

TEST_F(ShareTest, TheOwnerReattachesWithItsResumeKey) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  std::string resume, session;
  uint64_t version = 0;
  {
    WsClient owner;
    const json welcome = ConnectOwner(owner);
    resume = welcome["resume"];
    session = welcome["session"];
    OpenOrthoMip(owner, id, v, 40, 30);
    owner.Send(CameraMessage(v, 1.5).dump());
    auto frame = ReadFrameUntil(owner, [](const Frame& f) { return f.header.final; });
    ASSERT_TRUE(frame.has_value());
    version = frame->header.state_version;
    // Dropped without a close handshake, as a lost network would.
  }
  WsClient again;
  ASSERT_EQ(again.Connect(server_.port(), Auth("/ws")), "");
  again.Send(json{{"type", "hello"}, {"protocol", 1}, {"resume", resume}}.dump());
  auto welcome = ReadEvent(again, "welcome");
  ASSERT_TRUE(welcome.has_value());
  EXPECT_EQ((*welcome)["session"], session);
  EXPECT_EQ((*welcome)["role"], "owner");
  EXPECT_EQ((*welcome)["resume"], resume);
  auto opened = ReadEvent(again, "opened");
  ASSERT_TRUE(opened.has_value());
  EXPECT_EQ((*opened)["version"].get<uint64_t>(), version);
  EXPECT_DOUBLE_EQ((*opened)["state"]["camera"]["position"][0].get<double>(), v.sx * 0.5 / 2 + 1.5);
  // An unknown key: a non-fatal error and a fresh session.
  WsClient stranger;
  ASSERT_EQ(stranger.Connect(server_.port(), Auth("/ws")), "");
  stranger.Send(json{{"type", "hello"}, {"protocol", 1}, {"resume", std::string(32, 'a')}}.dump());
  auto error = ReadEvent(stranger, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ((*error)["fatal"], false);
  auto fresh = ReadEvent(stranger, "welcome");
  ASSERT_TRUE(fresh.has_value());
  EXPECT_NE((*fresh)["session"], session);
}

TEST_F(ShareTest, AViewLinkMadeThroughAShareLinkLivesAndDiesWithIt) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  const std::string share = OpenAndShare(owner, id, v, "viewer");
  // A guest who joined through the link saves the view.
  WsClient guest;
  JoinAsGuest(guest, share, "guest");
  guest.Send(json{{"type", "view_save"}}.dump());
  auto saved = ReadEvent(guest, "view_saved");
  ASSERT_TRUE(saved.has_value());
  const std::string view = (*saved)["id"];
  // While the share link lives, the view link opens — a session that cannot be shared on.
  WsClient fork;
  ASSERT_EQ(fork.Connect(server_.port(), "/ws?view=" + view), "");
  fork.Send(Hello().dump());
  ASSERT_TRUE(ReadEvent(fork, "opened").has_value());
  fork.Send(json{{"type", "share_create"}, {"role", "controller"}}.dump());
  auto refused = ReadEvent(fork, "error");
  ASSERT_TRUE(refused.has_value());
  EXPECT_NE((*refused)["message"].get<std::string>().find("cannot be shared further"),
            std::string::npos)
      << refused->dump();
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/views/" + view + "?view=" + view).status,
            200);
  // The share link is revoked: everything resting on it ends.
  owner.Send(json{{"type", "share_revoke"}, {"token", share}}.dump());
  EXPECT_EQ(guest.ReadUntilClose(), 4001);
  EXPECT_EQ(fork.ReadUntilClose(), 4005);
  WsClient again;
  EXPECT_NE(again.Connect(server_.port(), "/ws?view=" + view), "");
  EXPECT_EQ(again.handshake_status(), 401);
  EXPECT_NE(again.handshake_body().find("share link"), std::string::npos)
      << again.handshake_body();
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/views/" + view + "?view=" + view).status,
            401);
  // The owner still sees it in the list of its view links, marked as not opening.
  auto listed = Fetch(server_.port(), http::verb::get, Auth("/api/views"));
  ASSERT_EQ(listed.status, 200) << listed.body;
  const json list = json::parse(listed.body);
  ASSERT_EQ(list.size(), 1u) << list.dump();
  EXPECT_EQ(list[0]["id"], view);
  EXPECT_EQ(list[0]["made_through"], "share");
  EXPECT_EQ(list[0]["valid"], false);
  // And across a restart (share links do not survive one) it stays dead.
  owner.Close();
  ASSERT_EQ(server_.Stop(), 0);
  ASSERT_TRUE(StartServer());
  WsClient after;
  EXPECT_NE(after.Connect(server_.port(), "/ws?view=" + view), "");
  EXPECT_EQ(after.handshake_status(), 401);
}

TEST_F(ShareTest, AShareLinkAdmitsToTheDatasetItWasMadeForOnly) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string a = StreamTestVolume(v);
  const std::string b = StreamTestVolume(v);
  WsClient owner;
  const std::string share = OpenAndShare(owner, a, v, "controller");
  WsClient controller;
  JoinAsGuest(controller, share, "carol");
  // Another dataset the owner may see is, through the link, like one that does not exist.
  controller.Send(json{{"type", "open"}, {"dataset", b}}.dump());
  auto refused = ReadEvent(controller, "error");
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ((*refused)["message"], "no dataset '" + b + "'");
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets/" + b + "?share=" + share).status,
            404);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets/" + a + "?share=" + share).status,
            200);
  const json listed = json::parse(
      Fetch(server_.port(), http::verb::get, "/api/datasets?share=" + share).body);
  ASSERT_EQ(listed.size(), 1u);
  EXPECT_EQ(listed[0]["id"], a);
  // Its own dataset it may open again (e.g. with another state).
  controller.Send(json{{"type", "open"}, {"dataset", a}}.dump());
  auto reopened = ReadEvent(controller, "opened");
  ASSERT_TRUE(reopened.has_value());
  EXPECT_EQ((*reopened)["dataset"]["id"], a);
  // The owner moves the session to another dataset: the link (made for a) ends with it.
  owner.Send(json{{"type", "open"}, {"dataset", b}}.dump());
  EXPECT_EQ(controller.ReadUntilClose(), 4001);
  WsClient late;
  EXPECT_NE(ConnectShare(late, share), "");
  EXPECT_EQ(late.handshake_status(), 401);
  // The owner is told (after the `shares` of the link's creation).
  std::optional<json> shares;
  do {
    shares = ReadEvent(owner, "shares");
    ASSERT_TRUE(shares.has_value());
  } while (!(*shares)["shares"].empty());
}

TEST_F(ShareTest, OwnersListExpireAndDeleteTheirViewLinks) {
  ASSERT_TRUE(StartServer());
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient owner;
  ConnectOwner(owner);
  OpenOrthoMip(owner, id, v, 40, 30);
  owner.Send(json{{"type", "view_save"}, {"ttl_s", 3600}}.dump());
  auto expiring = ReadEvent(owner, "view_saved");
  ASSERT_TRUE(expiring.has_value());
  ASSERT_TRUE((*expiring)["expires"].is_string()) << expiring->dump();
  owner.Send(json{{"type", "view_save"}}.dump());
  auto forever = ReadEvent(owner, "view_saved");
  ASSERT_TRUE(forever.has_value());
  EXPECT_TRUE((*forever)["expires"].is_null());
  auto listed = Fetch(server_.port(), http::verb::get, Auth("/api/views"));
  ASSERT_EQ(listed.status, 200) << listed.body;
  json list = json::parse(listed.body);
  ASSERT_EQ(list.size(), 2u) << list.dump();
  for (const json& entry : list) {
    EXPECT_EQ(entry["dataset"], id);
    EXPECT_EQ(entry["dataset_name"], "share stream");
    EXPECT_EQ(entry["made_through"], "user");
    EXPECT_EQ(entry["owner"], "admin");
    EXPECT_EQ(entry["valid"], true);
    EXPECT_EQ(entry["url"], "http://127.0.0.1:" + std::to_string(server_.port()) +
                                "/?view=" + entry["id"].get<std::string>());
    if (entry["id"] == (*expiring)["id"]) {
      EXPECT_EQ(entry["expires"], (*expiring)["expires"]);
    }
  }
  // Deleted: it no longer opens, nor is it listed or read.
  const std::string gone = (*forever)["id"];
  EXPECT_EQ(Fetch(server_.port(), http::verb::delete_, Auth("/api/views/" + gone)).status, 204);
  EXPECT_EQ(Fetch(server_.port(), http::verb::delete_, Auth("/api/views/" + gone)).status, 404);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, Auth("/api/views/" + gone)).status, 404);
  WsClient dead;
  EXPECT_NE(dead.Connect(server_.port(), "/ws?view=" + gone), "");
  EXPECT_EQ(dead.handshake_status(), 401);
  list = json::parse(Fetch(server_.port(), http::verb::get, Auth("/api/views")).body);
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0]["id"], (*expiring)["id"]);
  EXPECT_FALSE(fs::exists(dir_ / "state" / "views" / (gone + ".json")));
  // A share link lists and deletes nothing.
  const std::string share = CreateShare(owner, "viewer")["token"];
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/views?share=" + share).status, 403);
  EXPECT_EQ(Fetch(server_.port(), http::verb::delete_,
                  "/api/views/" + list[0]["id"].get<std::string>() + "?share=" + share)
                .status,
            403);
}

}  // namespace
}  // namespace octoscope::app
