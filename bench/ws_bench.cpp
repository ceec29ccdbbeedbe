// Benchmark of the wire layers of `octoscope serve` (bench/ws.sh; results in docs/benchmarks.md):
//   1. client-message parsing (protocol::ParseClientMessage: strict, validated) against the
//      plainest parse of the same text (nlohmann::json::parse, no limits, no validation);
//   2. frame delivery over loopback: net::Server sending 256 KiB binary frames through a WsSink to
//      a Beast WebSocket client, against a plain TCP socket writing the same bytes.
// Usage: ws_bench [FRAMES=400]
#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "net/auth.h"
#include "net/server.h"
#include "protocol/ws_messages.h"
#include "util/logger.h"

namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
using tcp = asio::ip::tcp;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

void BenchParse() {
  const std::string messages[] = {
      R"({"type":"camera","camera":{"projection":"perspective","position":[120.5,-40,900],)"
      R"("target":[256,256,128],"up":[0,-1,0],"fov_y_degrees":30}})",
      R"({"type":"viewport","view":"3d","width":1280,"height":720,"dpr":2})",
      R"({"type":"ack","frame":12345})",
  };
  for (const std::string& text : messages) {
    constexpr int kIterations = 200000;
    size_t sink = 0;
    auto start = Clock::now();
    for (int i = 0; i < kIterations; ++i) sink += nlohmann::json::parse(text).size();
    const double baseline = Seconds(start);
    start = Clock::now();
    for (int i = 0; i < kIterations; ++i)
      sink += octoscope::protocol::ParseClientMessage(text).ok();
    const double ours = Seconds(start);
    std::printf(
        "parse %-8s %5zu B: %7.2f us/message (nlohmann::json::parse alone %5.2f us) ratio %.2f%s\n",
        nlohmann::json::parse(text)["type"].get<std::string>().c_str(), text.size(),
        ours / kIterations * 1e6, baseline / kIterations * 1e6, ours / baseline,
        sink == 0 ? " " : "");
  }
}

// Sends `frames` frames of `bytes` to the first client that says "go".
class BlastHandler : public octoscope::net::WsHandler {
 public:
  BlastHandler(int frames, size_t bytes)
      : frames_(frames), data_(std::make_shared<const std::vector<uint8_t>>(bytes, 0x42)) {}
  void OnOpen(std::shared_ptr<octoscope::net::WsSink> sink) override { sink_ = std::move(sink); }
  void OnText(std::string) override {
    for (int i = 0; i < frames_; ++i) sink_->SendBinary(data_);
  }
  void OnClose(const octoscope::net::WsCloseInfo&) override {}

 private:
  int frames_;
  std::shared_ptr<const std::vector<uint8_t>> data_;
  std::shared_ptr<octoscope::net::WsSink> sink_;
};

class NoApi : public octoscope::net::ApiHandler {
 public:
  void Handle(octoscope::net::HttpRequest, octoscope::net::HttpResponder r) override {
    r.Respond(octoscope::net::HttpResponse::Error(404, "none"));
  }
};

double WebSocketSeconds(int frames, size_t bytes) {
  octoscope::NullLogger logger;
  octoscope::net::ServerOptions options;
  options.authenticator = std::make_shared<octoscope::net::TokenAuthenticator>("bench-token");
  options.max_ws_queue_bytes = size_t{1} << 30;
  auto server = octoscope::net::Server::Start(
      options, std::make_shared<NoApi>(),
      [&](const octoscope::net::WsConnectInfo&) {
        return std::make_unique<BlastHandler>(frames, bytes);
      },
      logger);
  if (!server.ok()) {
    std::fprintf(stderr, "%s\n", server.status().ToString().c_str());
    std::exit(1);
  }
  asio::io_context ioc;
  beast::websocket::stream<tcp::socket> ws(ioc);
  ws.next_layer().connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), (*server)->port()));
  ws.handshake("127.0.0.1", "/ws?token=bench-token");
  ws.read_message_max(bytes + 1024);
  beast::flat_buffer buffer;
  const auto start = Clock::now();
  ws.write(asio::buffer(std::string("go")));
  size_t received = 0;
  for (int i = 0; i < frames; ++i) {
    received += ws.read(buffer);
    buffer.consume(buffer.size());
  }
  const double seconds = Seconds(start);
  if (received != static_cast<size_t>(frames) * bytes) std::exit(1);
  ws.close(beast::websocket::close_code::normal);
  return seconds;
}

double PlainTcpSeconds(int frames, size_t bytes) {
  asio::io_context ioc;
  tcp::acceptor acceptor(ioc, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  const std::vector<uint8_t> data(bytes, 0x42);
  std::thread writer([&] {
    tcp::socket s = acceptor.accept();
    char go[2];
    asio::read(s, asio::buffer(go));
    for (int i = 0; i < frames; ++i) asio::write(s, asio::buffer(data));
  });
  tcp::socket client(ioc);
  client.connect(acceptor.local_endpoint());
  std::vector<uint8_t> in(bytes);
  const auto start = Clock::now();
  asio::write(client, asio::buffer("go", 2));
  for (int i = 0; i < frames; ++i) asio::read(client, asio::buffer(in));
  const double seconds = Seconds(start);
  writer.join();
  return seconds;
}

}  // namespace

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 400;
  BenchParse();
  constexpr size_t kFrameBytes = 256 << 10;
  for (int run = 0; run < 3; ++run) {
    const double plain = PlainTcpSeconds(frames, kFrameBytes);
    const double ws = WebSocketSeconds(frames, kFrameBytes);
    const double mb = frames * double(kFrameBytes) / 1048576.0;
    std::printf(
        "frames %d x %zu KiB: WebSocket %.0f MiB/s (%.0f frames/s), plain TCP %.0f MiB/s, ratio "
        "%.2f\n",
        frames, kFrameBytes >> 10, mb / ws, frames / ws, mb / plain, ws / plain);
  }
  return 0;
}
