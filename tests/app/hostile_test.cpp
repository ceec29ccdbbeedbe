// `octoscope serve` against hostile clients: the real binary on loopback, real Beast clients.
// Wrong credentials learn nothing; malformed, oversized and binary messages close only their
// own connection (close codes of docs/protocol.md) while a well-behaved client keeps getting
// frames; malformed uploads (wrong sizes, lying Content-Length, chunked bodies over the limit,
// garbage TIFF, TIFFs decoding to more than the upload limit) and uploads abandoned halfway are
// refused without touching the planes already stored — read back through a lossless frame of the
// real renderer; concurrent uploads to one dataset all land; 64 concurrent maximum-size uploads
// stay within the documented RAM bound (the others get 429 with Retry-After before their bodies
// are read); WebSockets from foreign pages get 403 and clients over their connection cap 503,
// while others are served. (Load over time: soak_test.cpp.)
#include <gtest/gtest.h>

#include <atomic>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <latch>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "app/serve_fixture.h"
#include "io/tiff_fixture.h"

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

class HostileTest : public testing::ServeFixture {
 protected:
  // A small upload limit, so that "over the limit" is cheap to send.
  std::vector<std::string> ExtraArgs() const override { return {"--max-upload-mb", "1"}; }

  std::string SlabTarget(const std::string& id, int c, int64_t z, int64_t depth,
                         const std::string& extra = "") const {
    return Auth("/api/datasets/" + id + "/slabs?z=" + std::to_string(z) +
                "&depth=" + std::to_string(depth) + "&channel=" + std::to_string(c) + extra);
  }

  // A request's head for a slab upload with the given framing headers.
  std::string SlabHead(const std::string& id, int c, int64_t z, int64_t depth,
                       const std::string& framing,
                       const std::string& type = "application/octet-stream") const {
    return "PUT " + SlabTarget(id, c, z, depth) +
           " HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: " + type + "\r\n" + framing + "\r\n";
  }

  // The test volume's planes [z0, z0 + depth) of channel `c` as a TIFF file (written by the
  // independent libtiff fixture), or with `value` instead of the voxels when given.
  std::string TiffPlanes(const TestVolume& v, int c, int z0, int depth,
                         std::optional<uint16_t> value = std::nullopt) {
    testing::TiffFixtureSpec spec;
    spec.width = static_cast<uint32_t>(v.sx);
    spec.height = static_cast<uint32_t>(v.sy);
    spec.pages = depth;
    const fs::path path = dir_ / ("planes-" + std::to_string(tiff_files_++) + ".tif");
    EXPECT_TRUE(testing::WriteTiffFixture(path, spec, [&](uint32_t x, uint32_t y, int page, int) {
      return value ? *value : v.data[c][((z0 + page) * v.sy + y) * v.sx + x];
    }));
    const auto bytes = testing::ReadAll(path);
    return std::string(bytes.begin(), bytes.end());
  }

  int tiff_files_ = 0;
};

// The value of a response header, "" when absent.
std::string HeaderOf(const net::testing::HttpResult& r, std::string_view name) {
  const auto it = r.headers.find(boost::beast::string_view(name.data(), name.size()));
  return it == r.headers.end() ? "" : std::string(it->value());
}

// Every dataset-scoped route, with the method it takes and a body.
struct Route {
  http::verb method;
  std::string target;
  std::string body;
};

TEST_F(HostileTest, WrongTokensGet401AndLearnNothing) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  const std::string bright(static_cast<size_t>(v.sx * v.sy * 2), '\xff');
  const std::vector<Route> routes = {
      {http::verb::get, "/api/datasets", ""},
      {http::verb::get, "/api/datasets/" + id, ""},
      {http::verb::get, "/api/datasets/" + id + "/histogram", ""},
      {http::verb::get, "/api/datasets/nosuchdataset", ""},
      {http::verb::get, "/metrics", ""},
      {http::verb::post, "/api/datasets", R"({"name":"x","size":[4,4,4],"channels":1})"},
      {http::verb::put, "/api/datasets/" + id + "/slabs?z=0&depth=1&channel=0", bright},
      {http::verb::post, "/api/datasets/" + id + "/finish", ""},
  };
  std::string upper = kToken;
  for (char& ch : upper) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  const std::string token = kToken;
  const std::vector<std::string> wrong = {
      "",                                              // No credential at all.
      "x",         token.substr(0, token.size() - 1),  // A prefix of the right one.
      token + "0",                                     // The right one and more.
      upper,       token.substr(1) + token[0],        std::string(2000, 'a'),
  };
  std::string first_body;
  for (const std::string& w : wrong) {
    for (const Route& route : routes) {
      const std::string sep = route.target.find('?') == std::string::npos ? "?" : "&";
      const std::vector<net::testing::HttpResult> answers = {
          Fetch(server_.port(), route.method,
                w.empty() ? route.target : route.target + sep + "token=" + w, {}, route.body),
          Fetch(server_.port(), route.method, route.target, {{"Authorization", "Bearer " + w}},
                route.body)};
      for (const auto& r : answers) {
        EXPECT_EQ(r.status, 401) << route.target << " with '" << w.substr(0, 40) << "'";
        EXPECT_EQ(r.headers["WWW-Authenticate"], "Bearer");
        // The same answer everywhere: nothing tells an existing dataset from a missing one.
        if (first_body.empty()) first_body = r.body;
        EXPECT_EQ(r.body, first_body) << route.target;
      }
    }
    WsClient ws;
    EXPECT_NE(ws.Connect(server_.port(), w.empty() ? "/ws" : "/ws?token=" + w), "");
    EXPECT_EQ(ws.handshake_status(), 401);
    WsClient bearer;
    EXPECT_NE(bearer.Connect(server_.port(), "/ws", "Bearer " + w), "");
    EXPECT_EQ(bearer.handshake_status(), 401);
  }
  EXPECT_EQ(first_body.find(id), std::string::npos) << first_body;
  EXPECT_EQ(first_body.find("test stream"), std::string::npos) << first_body;
  // Nothing the refused requests asked for happened: no slab stored, no stream created or
  // finished.
  const json dataset = DatasetJson(id);
  EXPECT_EQ(dataset["state"], "streaming");
  EXPECT_EQ(json::parse(Fetch(server_.port(), http::verb::get, Auth("/api/datasets")).body).size(),
            1u);
  EXPECT_LE(StoredMipError(id, v), 1);
  // Neither the right token nor the wrong ones are written to the log.
  std::ifstream log(dir_ / "server.log");
  const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text.find(kToken), std::string::npos);
  EXPECT_EQ(text.find(token.substr(0, token.size() - 1)), std::string::npos);
  EXPECT_EQ(text.find("aaaaaaaaaaaaaaaa"), std::string::npos);
}

TEST_F(HostileTest, HostileMessagesCloseOnlyTheSenderWhileOthersKeepGettingFrames) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  WsClient good;
  ASSERT_TRUE(ConnectWs(good));
  OpenOrthoMip(good, id, v, 300);
  ASSERT_TRUE(ReadFrameUntil(good, [](const Frame& f) { return f.header.final; }).has_value());
  ASSERT_TRUE(good.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  uint64_t version = 0;
  int step = 0;

  // Slow-loris connections that send half a request line and stall stay open all along.
  std::vector<std::unique_ptr<net::testing::HttpClient>> lorises;
  for (int i = 0; i < 8; ++i) {
    lorises.push_back(std::make_unique<net::testing::HttpClient>(server_.port()));
    lorises.back()->WriteRaw("GET /api/datasets HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ");
  }

  // A binary message: closed with 1003.
  {
    WsClient bad;
    ASSERT_TRUE(ConnectWs(bad));
    ASSERT_TRUE(bad.Send(std::string("\x01\x02\x03", 3), /*binary=*/true));
    EXPECT_EQ(bad.ReadUntilClose(), 1003);
  }
  EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));

  // Text that is not UTF-8: refused (an error event, or the WebSocket layer's 1007).
  {
    WsClient bad;
    ASSERT_TRUE(ConnectWs(bad));
    ASSERT_TRUE(bad.Send("{\"type\":\"hello\",\"client\":\"\xff\xfe\",\"protocol\":1}"));
    auto m = bad.Read(seconds(10));
    if (m.ok) {
      ASSERT_FALSE(m.binary);
      const json event = json::parse(m.data);
      EXPECT_EQ(event["type"], "error");
    } else {
      EXPECT_EQ(m.error, boost::beast::websocket::error::closed);
      EXPECT_EQ(bad.stream().reason().code, 1007);
    }
  }
  EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));

  // Parseable but hostile: each gets a non-fatal error naming the problem, and the connection
  // keeps working (a ping is answered afterwards).
  {
    WsClient bad;
    ASSERT_TRUE(ConnectWs(bad));
    std::string deep = "{\"type\":\"ping\",\"t\":1,\"x\":";
    for (int i = 0; i < 40; ++i) deep += "[";
    for (int i = 0; i < 40; ++i) deep += "]";
    deep += "}";
    const std::vector<std::pair<std::string, std::string>> cases = {
        {deep, "nest"},
        {R"({"type":"ping","t":1,"t":2})", "\"t\""},
        {json{{"type", "hello"}, {"client", std::string(5000, 'c')}, {"protocol", 1}}.dump(),
         "4096"},
        {R"({"type":"ping","t":1e999})", "t"},
        {R"({"type":"viewport","view":"3d","width":-1,"height":10})", "width"},
        {R"({"type":"viewport","view":"3d","width":8193,"height":10})", "width"},
        {R"({"type":"viewport","view":"4d","width":10,"height":10})", "view"},
        {R"({"type":"open","dataset":"../../etc/passwd"})", "dataset"},
        {R"({"type":"open","dataset":"nosuchdataset"})", "nosuchdataset"},
        {R"({"type":"camera","camera":{"projection":"ortho"}})", "camera"},
        {R"({"type":"screenshot","view":"3d","scale":3,"id":1})", "scale"},
        {R"({"type":"screenshot","view":"3d","scale":1,"id":1})", "open"},
        {R"({"type":"ack","frame":0})", "frame"},
        {R"({"type":"quality","jpeg_final":101})", "jpeg_final"},
        {"\"just a string\"", ""},
        {"null", ""},
    };
    for (const auto& [text, needle] : cases) {
      ASSERT_TRUE(bad.Send(text)) << text.substr(0, 80);
      auto error = ReadEvent(bad, "error", nullptr, seconds(10));
      ASSERT_TRUE(error.has_value()) << text.substr(0, 80);
      EXPECT_FALSE((*error)["fatal"].get<bool>()) << text.substr(0, 80);
      EXPECT_NE((*error)["message"].get<std::string>().find(needle), std::string::npos)
          << text.substr(0, 80) << " -> " << (*error)["message"];
    }
    // Acknowledgements of frames never sent are harmless.
    for (int i = 1; i <= 50; ++i) bad.Send(json{{"type", "ack"}, {"frame", i * 1000}}.dump());
    // A message of exactly 64 KiB is accepted (the limit is inclusive).
    std::string padded = R"({"type":"ping","t":7})";
    padded.insert(1, std::string((64 << 10) - padded.size(), ' '));
    ASSERT_EQ(padded.size(), size_t{64} << 10);
    ASSERT_TRUE(bad.Send(padded));
    auto pong = ReadEvent(bad, "pong", nullptr, seconds(10));
    ASSERT_TRUE(pong.has_value());
    EXPECT_EQ((*pong)["t"], 7);
    // The same connection can still view the dataset.
    ASSERT_TRUE(bad.Send(json{{"type", "open"}, {"dataset", id}}.dump()));
    ASSERT_TRUE(ReadEvent(bad, "opened").has_value());
    bad.Close();
  }
  EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));

  // One byte over 64 KiB: closed with 1009 (the client may see only the connection end when its
  // own write is cut short); the good client does not notice.
  {
    WsClient bad;
    ASSERT_TRUE(ConnectWs(bad));
    std::string over = R"({"type":"ping","t":7})";
    over.insert(1, std::string((64 << 10) + 1 - over.size(), ' '));
    bad.Send(over);
    const int code = bad.ReadUntilClose();
    EXPECT_TRUE(code == 1009 || code == 0) << code;
  }
  EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));

  // A connection that stops mid-frame (half a WebSocket frame header, then silence) and one
  // that sends a frame claiming 2^62 bytes: neither holds anything but its own socket.
  {
    WsClient partial;
    ASSERT_TRUE(ConnectWs(partial));
    const unsigned char half[] = {0x81, 0xfe};  // FIN text, masked, 16-bit length follows...
    boost::asio::write(boost::beast::get_lowest_layer(partial.stream()).socket(),
                       boost::asio::buffer(half, sizeof half));
    WsClient huge;
    ASSERT_TRUE(ConnectWs(huge));
    const unsigned char claim[] = {0x81, 0xff, 0x40, 0, 0, 0, 0, 0, 0, 0, 1, 2, 3, 4};
    boost::asio::write(boost::beast::get_lowest_layer(huge.stream()).socket(),
                       boost::asio::buffer(claim, sizeof claim));
    EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));
    const int code = huge.ReadUntilClose(nullptr, seconds(10));
    EXPECT_TRUE(code == 1009 || code == 0) << code;
    EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));
  }

  // Many malformed messages in a burst from several connections at once: each closed with 1008.
  {
    std::vector<std::unique_ptr<WsClient>> floods;
    for (int i = 0; i < 4; ++i) {
      floods.push_back(std::make_unique<WsClient>());
      ASSERT_TRUE(ConnectWs(*floods.back()));
      for (int k = 0; k < 30; ++k) floods.back()->Send("{]");
    }
    for (auto& f : floods) EXPECT_EQ(f->ReadUntilClose(), 1008);
  }
  EXPECT_TRUE(CameraGetsAFrame(good, ++step, &version));

  // The stalled request lines are still only theirs: the server answers everybody else.
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, "/api/health").status, 200);
  EXPECT_EQ(Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id)).status, 200);
  good.Close();
}

TEST_F(HostileTest, MalformedUploadsAreRefusedAndStoredPlanesStayIntact) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  const json before = DatasetJson(id);
  ASSERT_LE(StoredMipError(id, v), 1);
  const size_t plane = static_cast<size_t>(v.sx * v.sy * 2);
  const std::string bright(plane * 4, '\xff');  // Four planes of 65535: would show at once.
  const uint16_t port = server_.port();

  // Raw bodies one byte short or one byte long (not the size the query implies: 400).
  EXPECT_EQ(Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 4),
                  {{"Content-Type", "application/octet-stream"}}, bright.substr(1))
                .status,
            400);
  EXPECT_EQ(Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 4),
                  {{"Content-Type", "application/octet-stream"}}, bright + "x")
                .status,
            400);
  // A Content-Length smaller than the body: the slab is short (400) and the rest of the body is
  // not taken for a request.
  {
    const std::string head =
        SlabHead(id, 0, 0, 4, "Content-Length: " + std::to_string(bright.size() - 100) + "\r\n");
    const std::string reply = net::testing::RawExchange(port, head + bright, seconds(10));
    EXPECT_EQ(net::testing::StatusOf(reply), 400) << reply.substr(0, 200);
    EXPECT_EQ(reply.find("HTTP/1.1 200"), std::string::npos) << reply;
  }
  // A Content-Length larger than the body, then the client goes away.
  {
    net::testing::HttpClient liar(port);
    liar.WriteRaw(
        SlabHead(id, 0, 0, 4, "Content-Length: " + std::to_string(bright.size() + 4096) + "\r\n") +
        bright);
    liar.Close();
  }
  // Chunked raw body longer than the slab: 413 as soon as it passes the slab's size.
  {
    std::string chunked;
    for (int i = 0; i < 5; ++i) {
      char size[16];
      std::snprintf(size, sizeof size, "%zx\r\n", plane);
      chunked += size + std::string(plane, '\xff') + "\r\n";
    }
    chunked += "0\r\n\r\n";
    const std::string reply = net::testing::RawExchange(
        port, SlabHead(id, 0, 0, 4, "Transfer-Encoding: chunked\r\n") + chunked, seconds(10));
    EXPECT_EQ(net::testing::StatusOf(reply), 413) << reply.substr(0, 200);
  }
  // A chunked TIFF body over --max-upload-mb (1 MiB), and a declared one.
  {
    net::testing::HttpClient client(port);
    http::request<http::string_body> req{http::verb::put, SlabTarget(id, 0, 0, 1), 11};
    req.set(http::field::host, "127.0.0.1");
    req.set(http::field::content_type, "image/tiff");
    req.chunked(true);
    req.body() = "II*" + std::string(3 << 20, '\0');
    EXPECT_EQ(client.Send(req).status, 413);
  }
  {
    const std::string reply = net::testing::RawExchange(
        port,
        SlabHead(id, 0, 0, 1, "Content-Length: " + std::to_string(2 << 20) + "\r\n", "image/tiff"),
        seconds(10));
    EXPECT_EQ(net::testing::StatusOf(reply), 413) << reply.substr(0, 200);
  }
  // Garbage and wrong TIFFs: 400 with a message; an unknown body type: 415.
  std::string garbage = "II*\0" + std::string(4000, '\0');
  for (size_t i = 8; i < garbage.size(); ++i) garbage[i] = static_cast<char>(i * 131 % 251);
  const std::string tiff = TiffPlanes(v, 0, 0, 4, uint16_t{65535});
  const std::vector<std::pair<std::string, std::string>> bad_tiffs = {
      {"garbage", garbage},
      {"truncated", tiff.substr(0, tiff.size() / 2)},
      {"empty", ""},
      {"three pages for four planes", TiffPlanes(v, 0, 0, 3, uint16_t{65535})},
      {"not a TIFF", bright},
  };
  for (const auto& [what, body] : bad_tiffs) {
    auto r = Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 4), {{"Content-Type", "image/tiff"}},
                   body);
    EXPECT_EQ(r.status, 400) << what << ": " << r.body;
    EXPECT_FALSE(json::parse(r.body, nullptr, false).value("error", "").empty()) << what;
  }
  {
    testing::TiffFixtureSpec spec;  // The wrong plane size.
    spec.width = 30;
    spec.height = 40;
    ASSERT_TRUE(testing::WriteTiffFixture(dir_ / "wrong.tif", spec));
    const auto bytes = testing::ReadAll(dir_ / "wrong.tif");
    auto r = Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 1), {{"Content-Type", "image/tiff"}},
                   std::string(bytes.begin(), bytes.end()));
    EXPECT_EQ(r.status, 400) << r.body;
  }
  EXPECT_EQ(Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 4), {{"Content-Type", "text/plain"}},
                  bright)
                .status,
            415);
  // Queries that are not plain in-range decimal integers, each parameter once.
  for (const std::string query :
       {"z=-1&depth=1&channel=0", "z=1e1&depth=1&channel=0", "z=0&depth=0&channel=0",
        "z=0&depth=1&channel=64", "z=65535&depth=2&channel=0", "z=0&z=1&depth=1&channel=0",
        "z=0&depth=1&channel=0&colour=1", "z= 0&depth=1&channel=0",
        "z=99999999999999999999&depth=1&channel=0"}) {
    auto r = Fetch(port, http::verb::put, Auth("/api/datasets/" + id + "/slabs?" + query),
                   {{"Content-Type", "application/octet-stream"}}, bright.substr(0, plane));
    EXPECT_EQ(r.status, 400) << query << ": " << r.body;
  }

  // Nothing of it was stored: the counts and the voxels are those of the good uploads.
  const json after = DatasetJson(id);
  EXPECT_EQ(after["planes_received"], before["planes_received"]);
  EXPECT_EQ(after["planes_inserted"], before["planes_inserted"]);
  EXPECT_EQ(after["state"], "streaming");
  EXPECT_LE(StoredMipError(id, v), 1);
  // And the dataset still takes good slabs (a valid TIFF of the same planes).
  EXPECT_EQ(Fetch(port, http::verb::put, SlabTarget(id, 0, 0, 4), {{"Content-Type", "image/tiff"}},
                  TiffPlanes(v, 0, 0, 4))
                .status,
            200);
  EXPECT_LE(StoredMipError(id, v), 1);
}

TEST_F(HostileTest, AClientLeavingMidUploadLeavesTheStoredPlanesIntact) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);
  // A viewer stays connected throughout.
  WsClient viewer;
  ASSERT_TRUE(ConnectWs(viewer));
  OpenOrthoMip(viewer, id, v, 300);
  ASSERT_TRUE(ReadFrameUntil(viewer, [](const Frame& f) { return f.header.final; }).has_value());
  const json before = DatasetJson(id);
  const size_t plane = static_cast<size_t>(v.sx * v.sy * 2);
  const std::string bright(plane * v.sz, '\xff');  // Would replace every plane of channel 0.

  // Raw and TIFF bodies, cut off at several points (head only, a few bytes, most of it).
  const std::string tiff = TiffPlanes(v, 0, 0, static_cast<int>(v.sz), uint16_t{65535});
  for (const bool is_tiff : {false, true}) {
    const std::string& body = is_tiff ? tiff : bright;
    for (const size_t cut : {size_t{0}, size_t{7}, body.size() / 2, body.size() - 1}) {
      net::testing::HttpClient client(server_.port());
      ASSERT_FALSE(client.WriteRaw(
          SlabHead(id, 0, 0, v.sz, "Content-Length: " + std::to_string(body.size()) + "\r\n",
                   is_tiff ? "image/tiff" : "application/octet-stream") +
          body.substr(0, cut)));
      client.Close();
    }
  }
  // Several abandoned at once, from parallel connections.
  {
    std::vector<std::thread> threads;
    for (int t = 0; t < 6; ++t) {
      threads.emplace_back([&, t] {
        net::testing::HttpClient client(server_.port());
        client.WriteRaw(SlabHead(id, t % 2, 0, v.sz,
                                 "Content-Length: " + std::to_string(bright.size()) + "\r\n") +
                        bright.substr(0, bright.size() * (t + 1) / 8));
        client.Close();
      });
    }
    for (auto& t : threads) t.join();
  }
  // The viewer is still served; the stored planes are intact, as the counts say and a fresh
  // client's lossless frame shows.
  uint64_t version = 0;
  ASSERT_TRUE(viewer.Send(json{{"type", "interaction"}, {"active", true}}.dump()));
  EXPECT_TRUE(CameraGetsAFrame(viewer, 1, &version));
  const json after = DatasetJson(id);
  EXPECT_EQ(after["planes_received"], before["planes_received"]);
  EXPECT_EQ(after["planes_inserted"], before["planes_inserted"]);
  EXPECT_LE(StoredMipError(id, v), 1);
  // The same slab sent completely afterwards is taken (the abandoned ones left no lock behind).
  EXPECT_EQ(Fetch(server_.port(), http::verb::put, SlabTarget(id, 0, 0, v.sz),
                  {{"Content-Type", "application/octet-stream"}}, v.Planes(0, 0, v.sz))
                .status,
            200);
  EXPECT_LE(StoredMipError(id, v), 1);
  viewer.Close();
}

TEST_F(HostileTest, ConcurrentUploadsToOneDatasetAllLand) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v, /*send=*/false);
  // Every plane of both channels once, some twice (the same voxels), some as TIFF, from 10
  // connections at once (more than the 8 concurrent uploads the server takes: 429 = retry).
  struct Upload {
    int c;
    int z;
    bool tiff;
  };
  std::vector<Upload> uploads;
  for (int z = 0; z < v.sz; ++z) {
    for (int c = 0; c < 2; ++c) uploads.push_back({c, z, (z + c) % 3 == 0});
  }
  for (int z = 0; z < v.sz; z += 4) uploads.push_back({0, z, z % 8 == 0});
  std::vector<std::string> bodies;
  for (const Upload& u : uploads) {
    bodies.push_back(u.tiff ? TiffPlanes(v, u.c, u.z, 1) : v.Planes(u.c, u.z, 1));
  }
  std::atomic<size_t> next{0};
  std::atomic<int> ok{0}, retried{0}, failed{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 10; ++t) {
    threads.emplace_back([&] {
      for (size_t i; (i = next.fetch_add(1)) < uploads.size();) {
        const Upload& u = uploads[i];
        for (int attempt = 0; attempt < 200; ++attempt) {
          auto r = Fetch(server_.port(), http::verb::put, SlabTarget(id, u.c, u.z, 1),
                         {{"Content-Type", u.tiff ? "image/tiff" : "application/octet-stream"}},
                         bodies[i]);
          if (r.status == 429) {
            ++retried;
            std::this_thread::sleep_for(milliseconds(10));
            continue;
          }
          (r.status == 200 ? ok : failed)++;
          break;
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(ok.load(), static_cast<int>(uploads.size()));
  EXPECT_EQ(failed.load(), 0);
  const json dataset = DatasetJson(id);
  EXPECT_EQ(dataset["planes_inserted"], 2 * v.sz);
  EXPECT_LE(StoredMipError(id, v), 1);
  // Channel 1 (noise over the whole range) through its own window: its maxima are exact too.
  auto histogram = json::parse(
      Fetch(server_.port(), http::verb::get, Auth("/api/datasets/" + id + "/histogram")).body);
  ASSERT_EQ(histogram["channels"].size(), 2u);
  uint16_t max1 = 0;
  for (uint16_t x : v.data[1]) max1 = std::max(max1, x);
  EXPECT_EQ(histogram["channels"][1]["max"], max1);
  auto finished = Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish"));
  ASSERT_EQ(finished.status, 200) << finished.body;
  EXPECT_EQ(json::parse(finished.body)["state"], "ready");
  EXPECT_LE(StoredMipError(id, v), 1);
}

// Small per-principal limits, so that reaching them is cheap.
class LimitsTest : public HostileTest {
 protected:
  std::vector<std::string> ExtraArgs() const override {
    return {"--max-sessions-per-user",    "2", "--max-streams-per-user",   "1",
            "--view-links-per-minute",    "2", "--max-view-links-per-user", "3",
            "--max-screenshots-in-flight", "1", "--max-messages-per-second", "20"};
  }
};

TEST_F(LimitsTest, OnePrincipalCannotTakeWhatEveryoneShares) {
  const TestVolume v;
  const std::string id = StreamTestVolume(v);  // Finished below: it does not count as open.
  ASSERT_EQ(Fetch(server_.port(), http::verb::post, Auth("/api/datasets/" + id + "/finish")).status,
            200);
  // Streams: one unfinished stream per user; the next is 429 with Retry-After.
  EXPECT_FALSE(StreamTestVolume(v, /*send=*/false).empty());
  auto refused = Fetch(server_.port(), http::verb::post, Auth("/api/datasets"), {},
                       R"({"size":[8,8,4],"channels":1,"dtype":"uint16"})");
  EXPECT_EQ(refused.status, 429) << refused.body;
  EXPECT_NE(refused.body.find("unfinished streams"), std::string::npos) << refused.body;
  EXPECT_FALSE(refused.headers["Retry-After"].empty());

  // Sessions: two per user; the third connection is refused with 1013.
  WsClient first, second, third;
  ASSERT_TRUE(ConnectWs(first));
  OpenOrthoMip(first, id, v, 300);
  ASSERT_TRUE(ConnectWs(second));
  ASSERT_TRUE(second.Send(json{{"type", "hello"}, {"protocol", 1}}.dump()));
  ASSERT_TRUE(ReadEvent(second, "welcome").has_value());
  ASSERT_TRUE(ConnectWs(third));
  auto error = ReadEvent(third, "error");
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ((*error)["message"], "too many sessions for this user");
  EXPECT_EQ((*error)["fatal"], true);
  EXPECT_EQ(third.ReadUntilClose(), 1013);

  // View links: two a minute.
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(first.Send(json{{"type", "view_save"}}.dump()));
  int saved = 0;
  std::string limit_error;
  for (int i = 0; i < 3; ++i) {
    std::optional<json> event;
    for (;;) {
      auto m = first.Read(seconds(30));
      ASSERT_TRUE(m.ok);
      if (m.binary) {
        testing::Ack(first, DecodeFrame(m.data)->header.frame_id);
        continue;
      }
      event = json::parse(m.data);
      if ((*event)["type"] == "view_saved" || (*event)["type"] == "error") break;
    }
    if ((*event)["type"] == "view_saved") {
      ++saved;
    } else {
      limit_error = (*event)["message"];
    }
  }
  EXPECT_EQ(saved, 2);
  EXPECT_NE(limit_error.find("too many view links saved in a minute"), std::string::npos)
      << limit_error;

  // Screenshots: one in flight per participant.
  ASSERT_TRUE(first.Send(json{{"type", "screenshot"}, {"view", "3d"}, {"scale", 2}, {"id", 1}}.dump()));
  ASSERT_TRUE(first.Send(json{{"type", "screenshot"}, {"view", "3d"}, {"scale", 2}, {"id", 2}}.dump()));
  auto shot_error = ReadEvent(first, "error");
  ASSERT_TRUE(shot_error.has_value());
  EXPECT_EQ((*shot_error)["request"], "screenshot");
  EXPECT_NE((*shot_error)["message"].get<std::string>().find("too many screenshots"),
            std::string::npos);
  EXPECT_TRUE(ReadFrameUntil(first, [](const Frame& f) {
                return f.header.tier == protocol::FrameTier::kScreenshot;
              }).has_value());

  // A message flood: dropped beyond the rate (one error), the connection and the others fine;
  // hellos beyond their own rate do not make the server re-send the participant list.
  for (int i = 0; i < 200; ++i) {
    ASSERT_TRUE(second.Send(json{{"type", "ping"}, {"t", i}}.dump()));
  }
  ASSERT_TRUE(second.Send(json{{"type", "ack"}, {"frame", 1}}.dump()));
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));  // The bucket refills.
  ASSERT_TRUE(second.Send(json{{"type", "ping"}, {"t", -1}}.dump()));
  int pongs = 0, errors = 0;
  for (;;) {
    auto m = second.Read(seconds(30));
    ASSERT_TRUE(m.ok);
    const json event = json::parse(m.data);
    if (event["type"] == "pong" && event["t"] == -1) break;
    pongs += event["type"] == "pong";
    errors += event["type"] == "error";
  }
  EXPECT_GE(pongs, 40);  // The burst (twice the rate) and what refilled meanwhile.
  EXPECT_LT(pongs, 100);
  EXPECT_EQ(errors, 1);
  uint64_t version = 0;
  EXPECT_TRUE(CameraGetsAFrame(first, 1, &version));
}

TEST_F(HostileTest, ATiffSlabMayNotDecodeToMoreThanTheUploadLimit) {
  // Planes of 2 MiB: one is over --max-upload-mb (1), as a raw body (413 from the HTTP layer) and
  // as a small deflated TIFF alike.
  auto created = Fetch(
      server_.port(), http::verb::post, Auth("/api/datasets"), {},
      json{
          {"name", "large planes"}, {"size", {1024, 1024, 4}}, {"channels", 1}, {"dtype", "uint16"}}
          .dump());
  ASSERT_EQ(created.status, 201) << created.body;
  const std::string id = json::parse(created.body)["id"];
  testing::TiffFixtureSpec spec;
  spec.width = 1024;
  spec.height = 1024;
  spec.compression = 8;  // Deflate: a constant plane is a few KiB.
  spec.rows_per_strip = 64;
  ASSERT_TRUE(testing::WriteTiffFixture(dir_ / "large.tif", spec,
                                        [](uint32_t, uint32_t, int, int) { return 500.0; }));
  const auto bytes = testing::ReadAll(dir_ / "large.tif");
  ASSERT_LT(bytes.size(), size_t{1} << 20);
  auto r = Fetch(server_.port(), http::verb::put, SlabTarget(id, 0, 0, 1),
                 {{"Content-Type", "image/tiff"}}, std::string(bytes.begin(), bytes.end()));
  EXPECT_EQ(r.status, 413) << r.body;
  EXPECT_EQ(Fetch(server_.port(), http::verb::put, SlabTarget(id, 0, 0, 1),
                  {{"Content-Type", "application/octet-stream"}}, std::string(2 << 20, '\0'))
                .status,
            413);
  EXPECT_EQ(DatasetJson(id)["planes_received"], 0);
}

// docs/api.md: uploads hold at most 8 x --max-upload-mb of slab bodies in RAM.
class UploadMemoryTest : public testing::ServeFixture {
 protected:
  static constexpr int kUploadMb = 32;
  std::vector<std::string> ExtraArgs() const override {
    return {"--max-upload-mb", std::to_string(kUploadMb), "--ram-mb", "64"};
  }
};

TEST_F(UploadMemoryTest, SixtyFourConcurrentMaximumSizeUploadsStayWithinTheDocumentedBound) {
  // 512 x 512 uint16 planes: 64 of them are one maximum-size slab (32 MiB). Every slab is
  // constant, so inserting it is cheap: what the server holds is the bodies.
  constexpr int64_t kX = 512, kY = 512, kDepth = 64;
  constexpr int kUploads = 64;
  const uint64_t slab_bytes = uint64_t{kUploadMb} << 20;
  ASSERT_EQ(static_cast<uint64_t>(kX * kY * kDepth * 2), slab_bytes);
  auto created = Fetch(server_.port(), http::verb::post, Auth("/api/datasets"), {},
                       json{{"name", "upload memory"},
                            {"size", {kX, kY, kDepth * (kUploads + 1)}},
                            {"channels", 1},
                            {"dtype", "uint16"}}
                           .dump());
  ASSERT_EQ(created.status, 201) << created.body;
  const std::string id = json::parse(created.body)["id"];
  std::string body(slab_bytes, '\0');
  for (size_t i = 0; i < body.size(); i += 2) {  // 1000, little-endian.
    body[i] = static_cast<char>(0xe8);
    body[i + 1] = 3;
  }
  // One slab alone first (the ingest's and the octree's buffers); the peak is measured from here.
  PutSlab(id, 0, kDepth * kUploads, kDepth, body, 200);
  server_.ResetPeakRss();  // Where allowed; else the peak since the start (at least as high).
  const uint64_t baseline_kib = server_.RssKiB();

  struct Outcome {
    int status = 0;
    std::string retry_after;
    std::string error;
  };
  std::vector<Outcome> outcomes(kUploads);
  std::latch start(kUploads);
  std::vector<std::thread> threads;
  for (int i = 0; i < kUploads; ++i) {
    threads.emplace_back([&, i] {
      net::testing::HttpClient client(server_.port());
      // Half ask for "100 Continue" (curl does for large bodies); the others send at once.
      const bool expect = i % 2 == 1;
      const std::string target =
          Auth("/api/datasets/" + id + "/slabs?z=" + std::to_string(kDepth * i) +
               "&depth=" + std::to_string(kDepth) + "&channel=0");
      const std::string head = "PUT " + target +
                               " HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                               "Content-Type: application/octet-stream\r\nContent-Length: " +
                               std::to_string(body.size()) + "\r\n" +
                               (expect ? "Expect: 100-continue\r\n" : "") + "\r\n";
      start.arrive_and_wait();
      net::testing::HttpResult r;
      if (client.WriteRaw(head)) {
        r.error = "head not written";
      } else if (expect) {
        r = client.ReadResponse();
        if (r.status == 100) {
          client.WriteRaw(body);
          r = client.ReadResponse();
        }
      } else {
        client.WriteRaw(body);  // Fails when the server answered early and closed.
        r = client.ReadResponse();
      }
      outcomes[i] = {r.status, HeaderOf(r, "Retry-After"), r.error};
    });
  }
  for (auto& t : threads) t.join();
  const uint64_t peak_kib = server_.PeakRssKiB();

  int landed = 0, refused = 0;
  for (int i = 0; i < kUploads; ++i) {
    const Outcome& o = outcomes[i];
    if (o.status == 200) {
      ++landed;
    } else {
      EXPECT_EQ(o.status, 429) << "upload " << i << ": " << o.error;
      EXPECT_FALSE(o.retry_after.empty()) << "upload " << i;
      ++refused;
    }
  }
  const uint64_t grown_mib = (peak_kib - std::min(peak_kib, baseline_kib)) >> 10;
  std::printf(
      "64 concurrent %d MiB uploads: %d landed, %d got 429; RSS %llu MiB before, peak "
      "%llu MiB (+%llu MiB; bound 8 x %d MiB of bodies)\n",
      kUploadMb, landed, refused, static_cast<unsigned long long>(baseline_kib >> 10),
      static_cast<unsigned long long>(peak_kib >> 10), static_cast<unsigned long long>(grown_mib),
      kUploadMb);
  EXPECT_GE(landed, 1);
  EXPECT_GE(refused, 1);
  // The bodies (8 x 32 MiB) plus room for the inserts' own work (each of the two upload workers
  // stages a slab: 2 x 32 MiB) and the I/O buffers. Admitted after reading, it was 1.1-1.2 GiB.
  EXPECT_LE(grown_mib, 8u * kUploadMb + 2u * kUploadMb + 32u);
  // Every admitted slab landed, and nothing else.
  const json dataset = DatasetJson(id);
  EXPECT_EQ(dataset["planes_received"], (landed + 1) * kDepth);
  EXPECT_EQ(dataset["planes_inserted"], (landed + 1) * kDepth);
}

// Browsers send the Origin of the page that opens a WebSocket: the server's own pages (its public
// URL, its listening address) and --allowed-origins may open one; other pages get 403 before the
// upgrade; native clients send no Origin.
class OriginTest : public testing::ServeFixture {
 protected:
  std::vector<std::string> ExtraArgs() const override {
    return {"--public-url", "https://scope.lab.example/octoscope/", "--allowed-origins",
            "https://viewer.lab.example, https://other.lab.example:8443"};
  }
};

TEST_F(OriginTest, WebSocketsFromForeignPagesAreRefusedBeforeTheUpgrade) {
  const std::string port = std::to_string(server_.port());
  for (const std::string& origin :
       {std::string(), std::string("https://scope.lab.example"),
        std::string("https://viewer.lab.example"), std::string("https://other.lab.example:8443"),
        "http://127.0.0.1:" + port, "http://localhost:" + port}) {
    WsClient ws;
    if (!origin.empty()) ws.SetHeader("Origin", origin);
    ASSERT_TRUE(ConnectWs(ws)) << origin;
    ASSERT_TRUE(
        ws.Send(json{{"type", "hello"}, {"client", "hostile_test"}, {"protocol", 1}}.dump()));
    EXPECT_TRUE(ReadEvent(ws, "welcome").has_value()) << origin;
    ws.Close();
  }
  for (const std::string& origin :
       {std::string("https://evil.example"), std::string("http://scope.lab.example"),
        std::string("https://other.lab.example"), std::string("null"),
        "http://127.0.0.1:" + std::to_string(server_.port() + 1)}) {
    WsClient ws;
    ws.SetHeader("Origin", origin);
    EXPECT_NE(ws.Connect(server_.port(), Auth("/ws")), "") << origin;
    EXPECT_EQ(ws.handshake_status(), 403) << origin;
  }
  EXPECT_TRUE(net::testing::WaitFor([&] { return Sessions() == 0; }));
}

// The connection caps, here from the --config file: a client over its cap gets 503 with
// Retry-After at once, a WebSocket upgrade too; other clients are served.
class ConnectionCapTest : public testing::ServeFixture {
 protected:
  std::vector<std::string> ExtraArgs() const override {
    const fs::path config = dir_ / "caps.json";
    std::ofstream(config) << R"({"max-connections": 100, "max-connections-per-address": 3})";
    return {"--config", config.string()};
  }
};

TEST_F(ConnectionCapTest, AClientOverItsCapGets503AndOthersAreServed) {
  const uint16_t port = server_.port();
  std::vector<std::unique_ptr<net::testing::HttpClient>> open;
  for (int i = 0; i < 3; ++i) {
    open.push_back(std::make_unique<net::testing::HttpClient>(port, "127.0.0.1"));
    EXPECT_EQ(open.back()->Request(http::verb::get, "/api/health").status, 200);
  }
  net::testing::HttpClient over(port, "127.0.0.1");
  const auto refused = over.Request(http::verb::get, Auth("/api/datasets"));
  EXPECT_EQ(refused.status, 503) << refused.error;
  EXPECT_FALSE(HeaderOf(refused, "Retry-After").empty());
  WsClient ws;
  EXPECT_NE(ws.Connect(port, Auth("/ws")), "");
  EXPECT_EQ(ws.handshake_status(), 503);
  net::testing::HttpClient other(port, "127.0.0.2");
  EXPECT_EQ(other.Request(http::verb::get, Auth("/api/datasets")).status, 200);
  EXPECT_EQ(open[0]->Request(http::verb::get, Auth("/api/datasets")).status, 200);
  open.clear();
  EXPECT_TRUE(net::testing::WaitFor(
      [&] { return Fetch(port, http::verb::get, "/api/health").status == 200; }));
}

}  // namespace
}  // namespace octoscope::app
