// `octoscope serve` end to end: the real binary on a loopback port, driven by a real HTTP and
// WebSocket client (Beast). Streams known voxels in over the HTTP API and checks the frames
// against the voxels themselves: a lossless final orthographic MIP at the volume's size equals
// the column maxima through the window within 1/255.
#include <gtest/gtest.h>
#include <turbojpeg.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "app/serve_fixture.h"
#include "encode/png_test_decoder.h"
#include "net/net_test_client.h"
#include "protocol/frame_header.h"

namespace octoscope::app {
namespace {

using namespace testing::serve_fixture;  // NOLINT
using testing::Ack;
using testing::DecodeFrame;
using testing::Frame;
using testing::ReadEvent;
using testing::ReadFrameUntil;
using testing::kToken;
using testing::TestVolume;

class ServeTest : public testing::ServeFixture {};

TEST_F(ServeTest, HealthIsOpenEverythingElseNeedsTheToken) {
  auto health = Fetch(server_.port(), http::verb::get, "/api/health");
  EXPECT_EQ(health.status, 200);
  EXPECT_EQ(json::parse(health.body)["status"], "ok");
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets").status, 401);
  EXPECT_EQ(
      Fetch(server_.port(), http::verb::get, "/api/datasets?token=wrong-token-xxxxxxxx").status,
      401);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/datasets",
                  {{"Authorization", std::string("Bearer ") + kToken}})
                .status,
            200);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, Auth("/api/datasets")).status, 200);
  auto metrics = Fetch(server_.port(), http::verb::get, Auth("/metrics"));
  EXPECT_EQ(metrics.status, 200);
  EXPECT_NE(metrics.body.find("octoscope_sessions"), std::string::npos);
  // Every response is counted, the refused ones too.
  EXPECT_NE(metrics.body.find("octoscope_http_requests_total{code=\"401\"} 2"), std::string::npos)
      << metrics.body;
  WsClient ws;
  EXPECT_NE(ws.Connect(server_.port(), "/ws"), "");
  EXPECT_EQ(ws.handshake_status(), 401);
}

TEST_F(ServeTest, StreamedVolumeRendersExactlyInFramesThatFollowTheCamera) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  auto listed =
      json::parse(Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id)).body);
  EXPECT_EQ(listed["state"], "streaming");
  EXPECT_EQ(listed["planes_inserted"], 2 * v.sz);

  WsClient ws;
  ASSERT_TRUE(ConnectWs(ws));
  const double window_hi = 300;  // Dim structure visible; the bright spots saturate.
  OpenOrthoMip(ws, id, v, window_hi);
  bool saw_interactive = false;
  auto final_frame = ReadFrameUntil(ws, [&](const Frame& f) {
    if (f.header.tier == protocol::FrameTier::kInteractive) {
      saw_interactive = true;
      // Interactive frames are JPEG that decodes.
      tjhandle tj = tjInitDecompress();
      int w = 0, h = 0, sub = 0, space = 0;
      EXPECT_EQ(tjDecompressHeader3(tj, f.image.data(), f.image.size(), &w, &h, &sub, &space), 0);
      tjDestroy(tj);
      EXPECT_EQ(f.header.format, protocol::ImageFormat::kJpeg);
    }
    return f.header.tier == protocol::FrameTier::kFinal;
  });
  ASSERT_TRUE(final_frame.has_value());
  EXPECT_TRUE(saw_interactive);
  EXPECT_TRUE(final_frame->header.final);
  EXPECT_EQ(final_frame->header.format, protocol::ImageFormat::kPng);
  auto png = testing::DecodeTestPng(final_frame->image);
  ASSERT_TRUE(png.ok) << png.error;
  ASSERT_EQ(png.width, v.sx);
  ASSERT_EQ(png.height, v.sy);
  EXPECT_LE(MaxMipError(png, v, window_hi), 1);

  // Moving the camera gives frames of a newer state, and a new final one.
  const uint64_t version = final_frame->header.state_version;
  ASSERT_TRUE(ws.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  ASSERT_TRUE(ws.Send(json{{"type", "camera"},
                           {"camera",
                            {{"projection", "perspective"},
                             {"position", {60.0, -20.0, -40.0}},
                             {"target", {10.0, 7.5, 20.0}}}}}
                          .dump()));
  auto moved = ReadFrameUntil(ws, [&](const Frame& f) { return f.header.state_version > version; });
  ASSERT_TRUE(moved.has_value());
  EXPECT_EQ(moved->header.tier, protocol::FrameTier::kInteractive);
  ASSERT_TRUE(ws.Send(json{{"type", "interaction"}, {"active", false}}.dump()));
  auto refined = ReadFrameUntil(
      ws, [&](const Frame& f) { return f.header.final && f.header.state_version > version; });
  ASSERT_TRUE(refined.has_value());
  ws.Close();
}

TEST_F(ServeTest, SlabsAppearInTheViewersFramesAsTheyArrive) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v, /*send=*/false);
  WsClient ws;
  ASSERT_TRUE(ConnectWs(ws));
  const double window_hi = 300;
  OpenOrthoMip(ws, id, v, window_hi);
  // Nothing sent yet: the final frame is black.
  auto empty = ReadFrameUntil(ws, [](const Frame& f) { return f.header.final; });
  ASSERT_TRUE(empty.has_value());
  auto black = testing::DecodeTestPng(empty->image);
  ASSERT_TRUE(black.ok);
  EXPECT_EQ(*std::max_element(black.pixels.begin(), black.pixels.end(),
                              [&](int a, int b) { return a < b; }),
            255);  // Alpha only.
  // Every plane of channel 0, one at a time (without waiting for insertion): the viewer sees the
  // whole volume within a few frames of the last plane.
  for (int64_t z = 0; z < v.sz; ++z) {
    auto r = Fetch(
        server_.port(), http::verb::put,
        Auth("/api/datasets/" + id + "/slabs?z=" + std::to_string(z) + "&depth=1&channel=0&wait=0"),
        {{"Content-Type", "application/octet-stream"}}, v.Planes(0, z, 1));
    ASSERT_EQ(r.status, 200) << r.body;
  }
  auto full = ReadFrameUntil(ws, [&](const Frame& f) {
    if (!f.header.final) return false;
    auto png = testing::DecodeTestPng(f.image);
    return png.ok && MaxMipError(png, v, window_hi) <= 1;
  });
  EXPECT_TRUE(full.has_value()) << "the streamed planes never showed up exactly";
  auto event = ReadEvent(ws, "dataset", nullptr, seconds(5));
  if (event) {
    EXPECT_EQ((*event)["dataset"]["id"], id);
  }
}

TEST_F(ServeTest, BadInputGetsClearErrorsAndOthersKeepBeingServed) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient good;
  ASSERT_TRUE(ConnectWs(good));
  OpenOrthoMip(good, id, v, 300);
  ASSERT_TRUE(ReadFrameUntil(good, [](const Frame& f) { return f.header.final; }).has_value());

  // Malformed and invalid messages: an error event each, the connection stays usable.
  WsClient bad;
  ASSERT_TRUE(ConnectWs(bad));
  ASSERT_TRUE(bad.Send("{not json"));
  auto error = ReadEvent(bad, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_FALSE((*error)["fatal"].get<bool>());
  ASSERT_TRUE(bad.Send(R"({"type":"viewport","view":"3d","width":100,"height":100,"colour":1})"));
  error = ReadEvent(bad, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_NE((*error)["message"].get<std::string>().find("colour"), std::string::npos);
  ASSERT_TRUE(bad.Send(R"({"type":"open","dataset":"nosuchdataset"})"));
  ASSERT_TRUE(ReadEvent(bad, "error").has_value());
  ASSERT_TRUE(bad.Send(R"({"type":"ping","t":42})"));
  auto pong = ReadEvent(bad, "pong");
  ASSERT_TRUE(pong.has_value());
  EXPECT_EQ((*pong)["t"], 42);
  // Too many malformed messages: closed with 1008.
  for (int i = 0; i < 25; ++i) bad.Send("[]");
  EXPECT_EQ(bad.ReadUntilClose(), 1008);
  // A message over 64 KiB: the connection is closed (with 1009 when the close frame reaches the
  // client before its own unfinished write fails).
  WsClient big;
  ASSERT_TRUE(ConnectWs(big));
  big.Send(std::string(70 << 10, ' '));
  const int code = big.ReadUntilClose();
  EXPECT_TRUE(code == 1009 || code == 0) << code;
  EXPECT_FALSE(big.Send(R"({"type":"ping","t":1})") && big.Read(seconds(2)).ok);

  // Bad slabs: wrong size, unknown dataset, bad query; after finish: 409.
  PutSlab(id, 0, 0, 1, std::string(10, 'x'), 400);
  EXPECT_EQ(Fetch(server_.port(), http::verb::put,
                  Auth("/api/datasets/nosuchdataset/slabs?z=0&depth=1&channel=0"), {}, "x")
                .status,
            404);
  PutSlab(id, 5, 0, 1, v.Planes(0, 0, 1), 400);     // Channel out of range.
  PutSlab(id, 0, v.sz, 1, v.Planes(0, 0, 1), 400);  // Beyond the volume.
  EXPECT_EQ(
      Fetch(server_.port(), http::verb::post, Auth("/api/datasets"), {}, "{\"size\":[1]}").status,
      400);
  EXPECT_EQ(Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish")).status,
            200);
  PutSlab(id, 0, 0, 1, v.Planes(0, 0, 1), 409);

  // The good client was served throughout: a camera change still gets a frame.
  ASSERT_TRUE(good.Send(json{{"type", "camera"},
                             {"camera",
                              {{"projection", "perspective"},
                               {"position", {60.0, -20.0, -40.0}},
                               {"target", {10.0, 7.5, 20.0}}}}}
                            .dump()));
  EXPECT_TRUE(ReadFrameUntil(good, [](const Frame& f) { return f.header.final; }).has_value());
}

TEST_F(ServeTest, AFinishedStreamIsACacheThatRenderOpens) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  auto finished = Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish"));
  ASSERT_EQ(finished.status, 200) << finished.body;
  const json dataset = json::parse(finished.body);
  EXPECT_EQ(dataset["state"], "ready");
  const std::string cache = dataset["cache"];
  EXPECT_EQ(server_.Stop(), 0);
  const std::string out = (dir_ / "finished.png").string();
  const std::string command = std::string(OCTOSCOPE_BINARY) + " render '" + cache + "' --out '" +
                              out + "' --size 40x30 --view z --mode mip --refine --device cpu " +
                              "> /dev/null 2>&1";
  EXPECT_EQ(std::system(command.c_str()), 0);
  EXPECT_TRUE(fs::exists(out));
}

TEST_F(ServeTest, TwoHundredConnectionsComeAndGoWithoutGrowingTheServer) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  auto cycle = [&](int n) {
    for (int i = 0; i < n; ++i) {
      WsClient ws;
      ASSERT_TRUE(ConnectWs(ws));
      ws.Send(json{{"type", "open"}, {"dataset", id}}.dump());
      ws.Send(json{{"type", "viewport"}, {"view", "z"}, {"width", 40}, {"height", 30}}.dump());
      if (i % 2 == 0) ws.Close();  // Half close cleanly, half just drop the connection.
    }
  };
  cycle(20);  // Warm-up: the dataset's mirror, caches and thread stacks exist afterwards.
  std::this_thread::sleep_for(seconds(1));
  const uint64_t before = server_.RssKiB();
  cycle(200);
  std::this_thread::sleep_for(seconds(2));
  const uint64_t after = server_.RssKiB();
  EXPECT_LT(after, before + 16 * 1024) << "RSS " << before << " KiB -> " << after << " KiB";
  auto health = json::parse(Fetch(server_.port(), http::verb::get, "/api/health").body);
  EXPECT_LE(health["sessions"].get<int>(), 1);  // The last dropped connections may still close.
}

TEST_F(ServeTest, AClientThatNeverReadsDoesNotStopAnother) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  // The stalled client asks for large frames and never reads or acknowledges.
  WsClient stalled;
  ASSERT_TRUE(ConnectWs(stalled));
  stalled.Send(json{{"type", "open"}, {"dataset", id}}.dump());
  stalled.Send(json{{"type", "viewport"}, {"view", "3d"}, {"width", 512}, {"height", 512}}.dump());
  stalled.Send(json{{"type", "interaction"}, {"active", true}}.dump());
  // The other keeps moving its camera and gets a frame for each of several camera states.
  WsClient active;
  ASSERT_TRUE(ConnectWs(active));
  OpenOrthoMip(active, id, v, 300);
  ASSERT_TRUE(active.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  int answered = 0;
  for (int i = 0; i < 10; ++i) {
    ASSERT_TRUE(active.Send(json{{"type", "camera"},
                                 {"camera",
                                  {{"projection", "perspective"},
                                   {"position", {60.0 - 5 * i, -20.0, -40.0}},
                                   {"target", {10.0, 7.5, 20.0}}}}}
                                .dump()));
    // The stalled client's camera moves too: its frames pile up only in its own mailbox.
    stalled.Send(json{{"type", "camera"},
                      {"camera",
                       {{"projection", "perspective"},
                        {"position", {60.0 + 5 * i, -20.0, -40.0}},
                        {"target", {10.0, 7.5, 20.0}}}}}
                     .dump());
    if (ReadFrameUntil(
            active, [](const Frame&) { return true; }, seconds(20)))
      ++answered;
  }
  EXPECT_EQ(answered, 10);
}

}  // namespace
}  // namespace octoscope::app
