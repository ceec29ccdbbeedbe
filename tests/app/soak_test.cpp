// `octoscope serve` over time: hundreds of WebSocket sessions opened and dropped in every way a
// browser drops them (clean close, tab killed mid-frame, killed during a screenshot, never
// said hello) from several threads at once, with HTTP requests in between, while one client
// keeps viewing — the server's RSS (from /proc) stays flat after the warm-up and every session
// is released; slow and stalled readers only lose their own frames (never a stale one), while
// another client keeps getting every frame it asks for. The real binary on loopback, real Beast
// clients.
#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "app/serve_fixture.h"

namespace octoscope::app {
namespace {

using namespace testing::serve_fixture;  // NOLINT
using testing::Ack;
using testing::DecodeFrame;
using testing::Frame;
using testing::kToken;
using testing::ReadEvent;
using testing::ReadFrameUntil;
using testing::TestVolume;

class SoakTest : public testing::ServeFixture {};

// One session's life, in one of four ways (`pattern`).
void Cycle(uint16_t port, const std::string& id, int pattern, int i) {
  WsClient ws;
  if (!ws.Connect(port, std::string("/ws?token=") + kToken).empty()) {
    ADD_FAILURE() << "connect failed in cycle " << i;
    return;
  }
  if (pattern == 0) return;  // Connected, said nothing, gone.
  ws.Send(json{{"type", "hello"}, {"client", "soak"}, {"protocol", 1}}.dump());
  ws.Send(json{{"type", "open"}, {"dataset", id}}.dump());
  ws.Send(json{{"type", "viewport"}, {"view", i % 2 ? "3d" : "z"}, {"width", 40}, {"height", 30}}
              .dump());
  if (pattern == 1) {
    // Dropped while its first frames are being rendered.
    ws.Send(json{{"type", "interaction"}, {"active", true}}.dump());
    ws.Send(json{{"type", "camera"}, {"camera", testing::OrbitCamera(i)}}.dump());
    return;
  }
  if (pattern == 2) {
    // Dropped while a screenshot (its own render view) is in flight.
    ws.Send(
        json{{"type", "screenshot"}, {"view", i % 2 ? "3d" : "z"}, {"scale", 2}, {"id", i}}.dump());
    ws.Read(milliseconds(30));
    return;
  }
  // A whole visit: a frame received and acknowledged, then a clean close.
  for (int k = 0; k < 50; ++k) {
    auto m = ws.Read(seconds(30));
    if (!m.ok) {
      ADD_FAILURE() << "no frame in cycle " << i << ": " << m.error.message();
      return;
    }
    if (m.binary) {
      auto header = protocol::DecodeFrameHeader(
          {reinterpret_cast<const uint8_t*>(m.data.data()), m.data.size()});
      if (header.ok()) {
        ws.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump());
        break;
      }
    }
  }
  ws.Close();
}

TEST_F(SoakTest, HundredsOfSessionsComeAndGoWhileFramesFlowAndRssStaysFlat) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  // A viewer that stays all along.
  WsClient viewer;
  ASSERT_TRUE(ConnectWs(viewer));
  OpenOrthoMip(viewer, id, v, 300);
  ASSERT_TRUE(ReadFrameUntil(viewer, [](const Frame& f) { return f.header.final; }).has_value());
  ASSERT_TRUE(viewer.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  uint64_t version = 0;
  int step = 0;

  // `rounds` sessions from each of 4 threads (every pattern from every thread), plus HTTP
  // requests (good, refused, unknown) from a fifth.
  auto round = [&](int rounds) {
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&, t] {
        for (int i = 0; i < rounds; ++i) Cycle(server_.port(), id, (i + t) % 4, t * 1000 + i);
      });
    }
    threads.emplace_back([&] {
      for (int i = 0; i < rounds; ++i) {
        Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id));
        Fetch(server_.port(), http::verb::get, "/api/datasets/" + id + "?token=wrong");
        Fetch(server_.port(), http::verb::get, Auth("/api/datasets/nosuchdataset"));
      }
    });
    for (auto& t : threads) t.join();
  };
  auto settled_rss = [&] {
    // Dropped connections close asynchronously: wait until only the viewer is left.
    EXPECT_TRUE(net::testing::WaitFor([&] { return Sessions() == 1; }, seconds(30)))
        << Sessions() << " sessions";
    std::this_thread::sleep_for(milliseconds(500));
    return server_.RssKiB();
  };

  round(20);  // Warm-up: thread stacks, allocator arenas, encoder and frame buffers exist.
  const uint64_t warm = settled_rss();
  EXPECT_TRUE(CameraGetsAFrame(viewer, ++step, &version));
  round(40);  // 160 sessions.
  const uint64_t middle = settled_rss();
  EXPECT_TRUE(CameraGetsAFrame(viewer, ++step, &version));
  round(40);  // 160 more.
  const uint64_t end = settled_rss();
  EXPECT_TRUE(CameraGetsAFrame(viewer, ++step, &version));
  // Flat: the last 160 sessions grow the server by less than 4 MiB (a leak of 25 KiB per
  // session would show), all 320 after the warm-up by less than 32 MiB (allocator arenas of the
  // threads that served them may still grow in the first half: seen up to 17 MiB).
  EXPECT_LT(end, middle + 4 * 1024)
      << "RSS KiB: warm " << warm << ", middle " << middle << ", end " << end;
  EXPECT_LT(end, warm + 32 * 1024)
      << "RSS KiB: warm " << warm << ", middle " << middle << ", end " << end;
  const std::string metrics = Fetch(server_.port(), http::verb::get, Auth("/metrics")).body;
  EXPECT_NE(metrics.find("octoscope_sessions 1\n"), std::string::npos) << metrics;
  viewer.Close();
  EXPECT_TRUE(net::testing::WaitFor([&] { return Sessions() == 0; }, seconds(10)));
}

TEST_F(SoakTest, SlowAndStalledReadersLoseOnlyTheirOwnFrames) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  auto start_interacting = [&](WsClient& ws, int width, bool stall = false) {
    ASSERT_TRUE(ConnectWs(ws));
    if (stall) ws.ShrinkReceiveBuffer();
    ws.Send(json{{"type", "open"}, {"dataset", id}}.dump());
    for (const char* view : {"3d", "x", "y", "z"}) {
      ws.Send(
          json{{"type", "viewport"}, {"view", view}, {"width", width}, {"height", width}}.dump());
    }
    ws.Send(json{{"type", "interaction"}, {"active", true}}.dump());
  };
  // Two stalled clients: large frames of all four views, never read.
  std::vector<std::unique_ptr<WsClient>> stalled;
  for (int i = 0; i < 2; ++i) {
    stalled.push_back(std::make_unique<WsClient>());
    start_interacting(*stalled.back(), 256, /*stall=*/true);
  }
  // A slow reader (a bad link): takes one message every 150 ms and acknowledges frames; it must
  // never see an older state of a view after a newer one.
  std::atomic<bool> stop{false};
  std::atomic<int> slow_frames{0}, stale{0};
  WsClient slow;
  start_interacting(slow, 128);
  std::thread slow_thread([&] {
    std::map<int, uint64_t> newest;  // View -> newest state version seen.
    int step = 0;
    while (!stop) {
      slow.Send(json{{"type", "camera"}, {"camera", testing::OrbitCamera(++step)}}.dump());
      std::this_thread::sleep_for(milliseconds(150));
      auto m = slow.Read(seconds(30));
      if (!m.ok) break;
      if (!m.binary) continue;
      auto header = protocol::DecodeFrameHeader(
          {reinterpret_cast<const uint8_t*>(m.data.data()), m.data.size()});
      if (!header.ok()) continue;
      slow.Send(json{{"type", "ack"}, {"frame", header->frame_id}}.dump());
      if (header->tier == protocol::FrameTier::kScreenshot) continue;
      const int view = static_cast<int>(header->view);
      if (header->state_version < newest[view]) ++stale;
      newest[view] = std::max(newest[view], header->state_version);
      ++slow_frames;
    }
  });
  // Meanwhile the other client's every camera is answered.
  WsClient active;
  ASSERT_TRUE(ConnectWs(active));
  OpenOrthoMip(active, id, v, 300);
  ASSERT_TRUE(active.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  uint64_t version = 0;
  int answered = 0;
  for (int i = 0; i < 20; ++i) {
    for (auto& s : stalled) {
      s->Send(json{{"type", "camera"}, {"camera", testing::OrbitCamera(i)}}.dump());
    }
    answered += CameraGetsAFrame(active, i, &version, seconds(20)) ? 1 : 0;
  }
  EXPECT_EQ(answered, 20);
  // And once it stops, it gets its final frame, exact.
  ASSERT_TRUE(active.Send(json{{"type", "interaction"}, {"active", false}}.dump()));
  EXPECT_TRUE(ReadFrameUntil(active, [&](const Frame& f) {
                return f.header.final && f.header.state_version >= version;
              }).has_value());
  // The slow reader keeps going until it has seen a handful of frames (however fast the rest
  // went: the count is about progress, not about a time window).
  EXPECT_TRUE(net::testing::WaitFor([&] { return slow_frames.load() > 5; }, seconds(60)));
  stop = true;
  slow_thread.join();
  EXPECT_GT(slow_frames.load(), 5);
  EXPECT_EQ(stale.load(), 0);
  active.Close();
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/health").status, 200);
}

}  // namespace
}  // namespace octoscope::app
