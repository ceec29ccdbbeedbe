// Streams outlive idle releases and restarts (issue 28), end to end with the real binary on a
// loopback port: a stream a session stopped viewing is released after --idle-timeout-s and keeps
// accepting slabs (200, never 409 "finished"); after a SIGTERM restart with the same --cache and
// --state-dir every stream is listed again as it was (id, name, shape, spacing, channel names,
// state, planes received, histogram, creator), an unfinished one takes further slabs (a plane sent
// again replaces the earlier one, histogram exact) and finishes, a finished one opens from its
// complete cache. Stored planes are read back through a lossless final frame.
#include <gtest/gtest.h>

#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "app/serve_fixture.h"

namespace octoscope::testing {
namespace {

constexpr char kAlice[] = "alice-token-0123456789abcdef";

class StreamLifetimeTest : public ServeFixture {
 protected:
  void SetUp() override {
    users_ = fs::temp_directory_path() /
             ("octoscope-stream-users-" + std::to_string(getpid()) + "-" +
              ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".json");
    std::ofstream(users_) << json::array({{{"name", "alice"}, {"token", kAlice}}}).dump();
    ServeFixture::SetUp();
  }
  void TearDown() override {
    ServeFixture::TearDown();
    fs::remove(users_);
  }
  std::vector<std::string> ExtraArgs() const override {
    return {"--idle-timeout-s", "1", "--users-file", users_.string()};
  }

  // The value of metric line `name` (labels included), or -1.
  double Metric(const std::string& name) const {
    auto r = Fetch(server_.port(), http::verb::get, Auth("/metrics"));
    const size_t at = r.body.find("\n" + name + " ");
    if (at == std::string::npos) return -1;
    return std::stod(r.body.substr(at + name.size() + 2));
  }

  json Histogram(const std::string& id) const {
    auto r = Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id + "/histogram"));
    EXPECT_EQ(r.status, 200) << r.body;
    return r.status == 200 ? json::parse(r.body) : json();
  }

  // Sends a hello and opens `id` on `ws`, waiting for "opened".
  static void OpenDataset(WsClient& ws, const std::string& id) {
    ASSERT_TRUE(ws.Send(json{{"type", "open"}, {"dataset", id}}.dump()));
    auto opened = ReadEvent(ws, "opened");
    ASSERT_TRUE(opened.has_value());
    EXPECT_EQ((*opened)["dataset"]["id"], id);
  }

  fs::path users_;
};

// What must survive a restart unchanged.
json Identity(const json& d) {
  return {{"id", d["id"]},
          {"name", d["name"]},
          {"size", d["size"]},
          {"channels", d["channels"]},
          {"channel_names", d["channel_names"]},
          {"dtype", d["dtype"]},
          {"spacing", d["spacing"]},
          {"state", d["state"]},
          {"planes_total", d["planes_total"]},
          {"planes_received", d["planes_received"]},
          {"missing_planes", d["missing_planes"]}};
}

TEST_F(StreamLifetimeTest, IdleReleaseAndRestartKeepAStreamOpenUntilItsOwnerFinishesIt) {
  const TestVolume v;  // 40 x 30 x 20, 2 channels: 40 planes.
  const std::string id = StreamTestVolume(v, /*send=*/false);
  ASSERT_FALSE(id.empty());
  // A second stream, created by alice, that stays unfinished throughout.
  auto created =
      Fetch(server_.port(), http::verb::post, "/api/datasets?token=" + std::string(kAlice), {},
            R"({"name":"alice run","size":[8,8,4],"channels":1,"dtype":"uint8",
                              "channel_names":["dapi"],"spacing":[0.25,0.25,1.5]})");
  ASSERT_EQ(created.status, 201) << created.body;
  const std::string other = json::parse(created.body)["id"];
  PutSlab(id, 0, 0, 1, v.Planes(0, 0, 1), 200);

  // A session views the stream, then opens the other dataset: after the idle timeout the stream
  // is released (closed: no RAM, no device share)...
  WsClient ws;
  ASSERT_TRUE(ConnectWs(ws));
  ASSERT_TRUE(ws.Send(json{{"type", "hello"}, {"client", "stream_test"}, {"protocol", 1}}.dump()));
  ASSERT_TRUE(ReadEvent(ws, "welcome").has_value());
  OpenDataset(ws, id);
  OpenDataset(ws, other);
  const std::string open_metric = "octoscope_dataset_open{dataset=\"" + id + "\"}";
  double open = 1;
  for (int i = 0; i < 100 && open != 0; ++i) {
    std::this_thread::sleep_for(milliseconds(100));
    open = Metric(open_metric);
  }
  ASSERT_EQ(open, 0);
  EXPECT_GE(Metric("octoscope_dataset_releases_total"), 1);
  EXPECT_EQ(DatasetJson(id)["state"], "streaming");

  // ... and keeps accepting slabs and replacements, the histogram exact.
  for (int64_t z = 1; z < 11; ++z) PutSlab(id, 0, z, 1, v.Planes(0, z, 1), 200);
  PutSlab(id, 1, 0, 5, v.Planes(1, 0, 5), 200);
  PutSlab(id, 0, 3, 1, std::string(v.sx * v.sy * 2, '\xff'), 200);  // 65535 everywhere...
  EXPECT_EQ(Histogram(id)["channels"][0]["max"], 65535);
  PutSlab(id, 0, 3, 1, v.Planes(0, 3, 1), 200);  // ... then the right plane again.
  json before = DatasetJson(id);
  EXPECT_EQ(before["state"], "streaming");
  EXPECT_EQ(before["planes_received"], 16);
  const json histogram = Histogram(id);
  EXPECT_EQ(histogram["channels"][0]["count"], 11 * v.sx * v.sy);
  EXPECT_EQ(histogram["channels"][1]["count"], 5 * v.sx * v.sy);
  EXPECT_EQ(histogram["channels"][0]["max"], 3000);  // The spot at z = 5; 65535 is gone.
  ws.Close();

  // A restart lists both streams again exactly as they were, creator included.
  ASSERT_TRUE(Restart());
  const json after = DatasetJson(id);
  EXPECT_EQ(Identity(after), Identity(before));
  EXPECT_EQ(Histogram(id), histogram);
  auto alice = Fetch(server_.port(), http::verb::get,
                     "/api/datasets/" + other + "?token=" + std::string(kAlice));
  ASSERT_EQ(alice.status, 200) << alice.body;
  EXPECT_EQ(json::parse(alice.body)["name"], "alice run");
  EXPECT_EQ(json::parse(alice.body)["channel_names"], json::array({"dapi"}));
  EXPECT_EQ(json::parse(alice.body)["spacing"], json::array({0.25, 0.25, 1.5}));
  EXPECT_EQ(json::parse(alice.body)["state"], "streaming");
  // Alice sees her stream, not the admin's.
  EXPECT_EQ(Fetch(server_.port(), http::verb::get,
                  "/api/datasets/" + id + "?token=" + std::string(kAlice))
                .status,
            404);

  // The unfinished stream takes the rest of channel 0 and a replacement, then finishes; the
  // planes sent before the restart read back exactly.
  PutSlab(id, 0, 11, v.sz - 11, v.Planes(0, 11, v.sz - 11), 200);
  PutSlab(id, 0, 5, 1, std::string(v.sx * v.sy * 2, '\0'), 200);
  PutSlab(id, 0, 5, 1, v.Planes(0, 5, 1), 200);
  const json full = Histogram(id);
  EXPECT_EQ(full["channels"][0]["count"], v.sz * v.sx * v.sy);
  EXPECT_EQ(full["channels"][0]["max"], 4000);
  EXPECT_EQ(full["channels"][0]["min"], 0);
  EXPECT_EQ(StoredMipError(id, v), 0);
  auto finished =
      Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish"), {}, "");
  ASSERT_EQ(finished.status, 200) << finished.body;
  EXPECT_EQ(json::parse(finished.body)["state"], "ready");
  EXPECT_EQ(json::parse(finished.body)["missing_planes"], 2 * v.sz - v.sz - 5);
  PutSlab(id, 1, 6, 1, v.Planes(1, 6, 1), 409);

  // Another restart: the finished stream is listed as ready and opens from its complete cache;
  // the unfinished one is still streaming.
  const json done = DatasetJson(id);
  ASSERT_TRUE(Restart());
  EXPECT_EQ(Identity(DatasetJson(id)), Identity(done));
  EXPECT_EQ(Histogram(id), full);
  EXPECT_EQ(StoredMipError(id, v), 0);
  EXPECT_EQ(DatasetJson(other)["state"], "streaming");
  PutSlab(id, 1, 6, 1, v.Planes(1, 6, 1), 409);
}

// SIGKILL: no shutdown, no checkpoint. The stream comes back at its last checkpoint (the one
// its quiet time made), with what arrived later gone — the replaced plane its old self again —
// and a warning naming the planes to send again; sent again, every voxel is right.
TEST_F(StreamLifetimeTest, AKilledServerResumesAStreamFromItsLastCheckpoint) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v, /*send=*/false);
  ASSERT_FALSE(id.empty());
  for (int c = 0; c < 2; ++c) PutSlab(id, c, 0, 10, v.Planes(c, 0, 10), 200);
  // Quiet for longer than the stream's checkpoint_quiet (2 s): checkpointed.
  std::this_thread::sleep_for(milliseconds(3000));
  PutSlab(id, 0, 10, 5, v.Planes(0, 10, 5), 200);
  PutSlab(id, 0, 3, 1, std::string(v.sx * v.sy * 2, '\xff'), 200);
  EXPECT_EQ(DatasetJson(id)["planes_received"], 25);
  server_.Kill();
  ASSERT_TRUE(server_.Start(OCTOSCOPE_BINARY, ServeArgs(), (dir_ / "server.log.killed").string()))
      << server_.error();

  const json d = DatasetJson(id);
  EXPECT_EQ(d["state"], "streaming");
  EXPECT_EQ(d["planes_received"], 20);
  ASSERT_EQ(d["warnings"].size(), 1u) << d.dump();
  EXPECT_NE(d["warnings"][0].get<std::string>().find(
                "send again every plane not stored: channel 0: z 10-19; channel 1: z 10-19"),
            std::string::npos)
      << d.dump();
  const json histogram = Histogram(id);
  EXPECT_EQ(histogram["channels"][0]["count"], 10 * v.sx * v.sy);
  EXPECT_EQ(histogram["channels"][0]["max"], 3000);  // 65535 is gone with what came after.
  PutSlab(id, 0, 10, v.sz - 10, v.Planes(0, 10, v.sz - 10), 200);
  EXPECT_EQ(StoredMipError(id, v), 0);
  auto finished =
      Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish"), {}, "");
  ASSERT_EQ(finished.status, 200) << finished.body;
  EXPECT_EQ(json::parse(finished.body)["missing_planes"], v.sz - 10);
}

class DemoReleaseTest : public ServeFixture {
 protected:
  std::vector<std::string> ExtraArgs() const override {
    return {"--demo", "--demo-size", "64,64,16", "--demo-rate", "4", "--idle-timeout-s", "1"};
  }
};

// The demo streams on while nobody views it: an idle release never stops or finishes it.
TEST_F(DemoReleaseTest, AnIdleReleaseNeverStopsTheDemo) {
  const std::string demo = server_.dataset();
  ASSERT_FALSE(demo.empty());
  const TestVolume v;
  const std::string other = StreamTestVolume(v, /*send=*/false);
  WsClient ws;
  ASSERT_TRUE(ConnectWs(ws));
  ASSERT_TRUE(ws.Send(json{{"type", "hello"}, {"client", "demo_test"}, {"protocol", 1}}.dump()));
  ASSERT_TRUE(ReadEvent(ws, "welcome").has_value());
  for (const std::string& id : {demo, other}) {
    ASSERT_TRUE(ws.Send(json{{"type", "open"}, {"dataset", id}}.dump()));
    ASSERT_TRUE(ReadEvent(ws, "opened").has_value());
  }
  json d;
  for (int i = 0; i < 300; ++i) {
    d = DatasetJson(demo);
    if (d["state"] != "streaming") break;
    std::this_thread::sleep_for(milliseconds(50));
  }
  EXPECT_EQ(d["state"], "ready") << d.dump();
  EXPECT_EQ(d["missing_planes"], 0) << d.dump();
  EXPECT_EQ(d["planes_received"], 16 * 3);
}

}  // namespace
}  // namespace octoscope::testing
