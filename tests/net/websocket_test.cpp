// The WebSocket side of net::Server, end to end: a real server on a loopback port driven by
// Beast's WebSocket client. Token at the upgrade, message caps, close codes, a client that never
// reads, sends from foreign threads, sinks outliving their connection, graceful shutdown, and
// connect/disconnect cycles.
#include <gtest/gtest.h>

#include <atomic>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "net/auth.h"
#include "net/net_test_client.h"
#include "net/server.h"
#include "net/test_handlers.h"
#include "protocol/ws_messages.h"

namespace octoscope::net {
namespace {

using testing::CapturingLogger;
using testing::EchoHandler;
using testing::ResidentBytes;
using testing::TestApi;
using testing::WaitFor;
using testing::WsClient;
using testing::WsRecorder;

constexpr char kToken[] = "ws-token-0123456789abcdef0123";

// Answers like the session layer will: client messages parsed by protocol/, errors as error
// events naming the request, pings with pongs.
class ProtocolHandler : public WsHandler {
 public:
  explicit ProtocolHandler(std::shared_ptr<std::atomic<int>> errors) : errors_(std::move(errors)) {}
  void OnOpen(std::shared_ptr<WsSink> sink) override { sink_ = std::move(sink); }
  void OnText(std::string text) override {
    std::string type;
    Result<protocol::ClientMessage> message = protocol::ParseClientMessage(text, &type);
    if (!message.ok()) {
      ++*errors_;
      sink_->SendText(protocol::ErrorEvent(message.status().message(), type, false));
      return;
    }
    if (const auto* ping = std::get_if<protocol::PingMessage>(&*message)) {
      sink_->SendText(protocol::PongEvent(ping->t));
    }
  }
  void OnClose(const WsCloseInfo&) override {}

 private:
  std::shared_ptr<std::atomic<int>> errors_;
  std::shared_ptr<WsSink> sink_;
};

class WebSocketTest : public ::testing::Test {
 protected:
  void TearDown() override {
    server_.reset();
    if (HasFailure()) {
      for (const std::string& line : logger_.lines())
        std::fprintf(stderr, "log: %s\n", line.c_str());
    }
  }

  void Start(ServerOptions options = {}) {
    options.authenticator = std::make_shared<TokenAuthenticator>(kToken);
    auto factory = [this](const WsConnectInfo& info) -> std::unique_ptr<WsHandler> {
      ++factory_calls_;
      if (info.query == "refuse") return nullptr;
      if (info.query.starts_with("protocol")) return std::make_unique<ProtocolHandler>(errors_);
      return std::make_unique<EchoHandler>(recorder_, info.query);
    };
    auto started = Server::Start(options, std::make_shared<TestApi>(), factory, logger_);
    ASSERT_TRUE(started.ok()) << started.status().ToString();
    server_ = std::move(started).value();
    port_ = server_->port();
  }

  // "/ws?token=...&name" (the query the handler sees is "name").
  static std::string Target(const std::string& name) {
    return std::string("/ws?token=") + kToken + (name.empty() ? "" : "&" + name);
  }

  CapturingLogger logger_;
  std::shared_ptr<WsRecorder> recorder_ = std::make_shared<WsRecorder>();
  std::shared_ptr<std::atomic<int>> errors_ = std::make_shared<std::atomic<int>>(0);
  std::atomic<int> factory_calls_{0};
  std::unique_ptr<Server> server_;
  uint16_t port_ = 0;
};

TEST_F(WebSocketTest, TokenIsCheckedAtTheUpgrade) {
  Start();
  for (const std::string& target : {std::string("/ws"), std::string("/ws?token=wrong"),
                                    std::string("/ws?token=") + kToken + "x",
                                    std::string("/ws?token=") + std::string(kToken).substr(1)}) {
    WsClient client;
    EXPECT_NE(client.Connect(port_, target), "") << target;
    EXPECT_EQ(client.handshake_status(), 401) << target;
  }
  {
    WsClient wrong_bearer;
    EXPECT_NE(wrong_bearer.Connect(port_, "/ws", "Bearer nope"), "");
    EXPECT_EQ(wrong_bearer.handshake_status(), 401);
  }
  EXPECT_EQ(factory_calls_, 0);  // Refused before any handler exists.

  // Accepted as query parameter and as bearer header; the handler never sees the token.
  WsClient by_query;
  ASSERT_EQ(by_query.Connect(port_, Target("a=1")), "");
  WsClient by_header;
  ASSERT_EQ(by_header.Connect(port_, "/ws?b=2", std::string("Bearer ") + kToken), "");
  ASSERT_TRUE(by_query.Send("hello"));
  EXPECT_EQ(by_query.Read().data, "hello");
  ASSERT_TRUE(by_header.Send("there"));
  EXPECT_EQ(by_header.Read().data, "there");
  EXPECT_TRUE(WaitFor([&] { return recorder_->opens() == 2; }));
  EXPECT_NE(recorder_->sink("a=1"), nullptr);
  EXPECT_NE(recorder_->sink("b=2"), nullptr);
  for (const std::string& line : logger_.lines()) EXPECT_EQ(line.find(kToken), std::string::npos);

  // Another path is no WebSocket endpoint.
  WsClient elsewhere;
  EXPECT_NE(elsewhere.Connect(port_, std::string("/api/ws?token=") + kToken), "");
  EXPECT_EQ(elsewhere.handshake_status(), 404);
}

// Opens a WebSocket at Target("") with the given upgrade headers; "" or the handshake error.
std::string ConnectWith(WsClient& client, uint16_t port,
                        const std::vector<std::pair<std::string, std::string>>& headers) {
  for (const auto& [name, value] : headers) client.SetHeader(name, value);
  return client.Connect(port, std::string("/ws?token=") + kToken);
}

TEST_F(WebSocketTest, UpgradesFromForeignOriginsGet403BeforeAnyHandler) {
  ServerOptions options;
  options.allowed_origins = {"https://viewer.lab.example", "https://scope.lab.example/octoscope/"};
  Start(options);
  const std::string port = std::to_string(port_);
  const std::string next_port = std::to_string(port_ + 1);
  // The server's own address (loopback under any of its names), the allowed origins, and native
  // clients, which send no Origin.
  const std::vector<std::string> allowed = {
      "http://127.0.0.1:" + port,      "http://localhost:" + port,   "http://[::1]:" + port,
      "HTTP://LocalHost:" + port,      "https://viewer.lab.example", "https://scope.lab.example",
      "https://viewer.lab.example:443"};
  for (const std::string& origin : allowed) {
    WsClient client;
    EXPECT_EQ(ConnectWith(client, port_, {{"Origin", origin}}), "") << origin;
  }
  WsClient native;
  EXPECT_EQ(ConnectWith(native, port_, {}), "");
  EXPECT_TRUE(WaitFor([&] { return factory_calls_ == static_cast<int>(allowed.size()) + 1; }));
  const std::vector<std::string> refused = {"https://evil.example",
                                            "null",
                                            "",
                                            "http://127.0.0.1:" + next_port,
                                            "https://127.0.0.1:" + port,
                                            "http://127.0.0.2:" + port,
                                            "http://viewer.lab.example",
                                            "https://viewer.lab.example:8443",
                                            "https://viewer.lab.example.evil.example",
                                            "https://viewer.lab.example https://evil.example",
                                            "https://evil.example/https://viewer.lab.example"};
  for (const std::string& origin : refused) {
    WsClient client;
    EXPECT_NE(ConnectWith(client, port_, {{"Origin", origin}}), "") << origin;
    EXPECT_EQ(client.handshake_status(), 403) << origin;
  }
  EXPECT_EQ(factory_calls_, static_cast<int>(allowed.size()) + 1);  // None for the refused.
  EXPECT_TRUE(logger_.Contains("https://evil.example"));
}

TEST_F(WebSocketTest, BehindATrustedProxyTheForwardedOriginIsTheServers) {
  ServerOptions options;
  options.trusted_proxies = {"127.0.0.1"};
  Start(options);
  const std::vector<std::pair<std::string, std::string>> forwarded = {
      {"X-Forwarded-For", "203.0.113.7"},
      {"X-Forwarded-Proto", "https"},
      {"X-Forwarded-Host", "scope.lab.example"}};
  auto with_origin = [&](const std::string& origin) {
    auto headers = forwarded;
    headers.emplace_back("Origin", origin);
    return headers;
  };
  {
    WsClient client;
    EXPECT_EQ(ConnectWith(client, port_, with_origin("https://scope.lab.example")), "");
  }
  for (const std::string origin :
       {"https://evil.example", "http://scope.lab.example", "https://scope.lab.example:8443"}) {
    WsClient client;
    EXPECT_NE(ConnectWith(client, port_, with_origin(origin)), "") << origin;
    EXPECT_EQ(client.handshake_status(), 403) << origin;
  }
  {
    // Without X-Forwarded-Host, the Host the proxy passed on (with its port).
    WsClient client;
    EXPECT_EQ(ConnectWith(client, port_,
                          {{"X-Forwarded-Proto", "https"},
                           {"Host", "scope.lab.example:8443"},
                           {"Origin", "https://scope.lab.example:8443"}}),
              "");
  }
  server_.reset();
  // The same headers from a peer that is not a trusted proxy are the client's own claim.
  Start();
  WsClient client;
  EXPECT_NE(ConnectWith(client, port_, with_origin("https://scope.lab.example")), "");
  EXPECT_EQ(client.handshake_status(), 403);
}

TEST_F(WebSocketTest, UpgradesOverTheForwardedClientsCapGet503BeforeTheUpgrade) {
  ServerOptions options;
  options.trusted_proxies = {"127.0.0.1"};
  options.max_connections_per_address = 2;
  Start(options);
  const std::vector<std::pair<std::string, std::string>> client_a = {
      {"X-Forwarded-For", "203.0.113.7"}};
  const std::vector<std::pair<std::string, std::string>> client_b = {
      {"X-Forwarded-For", "198.51.100.9"}};
  auto first = std::make_unique<WsClient>();
  ASSERT_EQ(ConnectWith(*first, port_, client_a), "");
  WsClient second;
  ASSERT_EQ(ConnectWith(second, port_, client_a), "");
  WsClient third;
  EXPECT_NE(ConnectWith(third, port_, client_a), "");
  EXPECT_EQ(third.handshake_status(), 503);
  EXPECT_EQ(factory_calls_, 2);
  // Another client through the same proxy, and the proxy's own connections, are served.
  WsClient other;
  EXPECT_EQ(ConnectWith(other, port_, client_b), "");
  WsClient proxy_itself;
  EXPECT_EQ(ConnectWith(proxy_itself, port_, {}), "");
  ASSERT_TRUE(second.Send("still here"));
  EXPECT_EQ(second.Read().data, "still here");
  // Once one of the client's WebSockets closes, it may open another.
  first->Close();
  first.reset();
  EXPECT_TRUE(WaitFor([&] {
    WsClient again;
    return ConnectWith(again, port_, client_a).empty();
  }));
}

TEST_F(WebSocketTest, OversizedUpgradeHeaderIsRefusedBeforeTheToken) {
  Start();
  WsClient client;
  const std::string target = "/ws?pad=" + std::string(9000, 'p');
  EXPECT_NE(client.Connect(port_, target), "");
  EXPECT_EQ(factory_calls_, 0);
  // Others are served.
  WsClient ok;
  EXPECT_EQ(ok.Connect(port_, Target("")), "");
}

TEST_F(WebSocketTest, MessagesOverTheCapCloseWith1009) {
  Start();
  WsClient client;
  ASSERT_EQ(client.Connect(port_, Target("big")), "");
  // Exactly the cap is a message like any other.
  const std::string at_cap(64 << 10, 'm');
  ASSERT_TRUE(client.Send(at_cap));
  WsClient::Message echo = client.Read();
  ASSERT_TRUE(echo.ok) << echo.error.message();
  EXPECT_EQ(echo.data.size(), at_cap.size());
  // One byte more closes the connection with 1009, before the handler sees it.
  client.Send(at_cap + "!");
  EXPECT_EQ(client.ReadUntilClose(), 1009);
  EXPECT_TRUE(WaitFor([&] { return recorder_->closed("big").has_value(); }));
  EXPECT_EQ(recorder_->closed("big")->code, kCloseTooBig);

  // Others keep being served.
  WsClient other;
  ASSERT_EQ(other.Connect(port_, Target("other")), "");
  ASSERT_TRUE(other.Send("still here"));
  EXPECT_EQ(other.Read().data, "still here");
}

TEST_F(WebSocketTest, BinaryMessagesFromClientsCloseWith1003) {
  Start();
  WsClient client;
  ASSERT_EQ(client.Connect(port_, Target("bin")), "");
  ASSERT_TRUE(client.Send("abc", /*binary=*/true));
  EXPECT_EQ(client.ReadUntilClose(), 1003);
}

TEST_F(WebSocketTest, MalformedJsonGetsAnErrorEventAndEveryoneKeepsBeingServed) {
  Start();
  WsClient bad, good;
  ASSERT_EQ(bad.Connect(port_, Target("protocol-bad")), "");
  ASSERT_EQ(good.Connect(port_, Target("protocol-good")), "");
  const std::pair<std::string, std::string> cases[] = {
      {"{not json", ""},
      {R"({"type":"viewport","view":"3d","width":9000,"height":1})", "viewport"},
      {R"({"type":"ping","t":1,"extra":true})", "ping"},
      {R"({"type":"nope"})", ""},
  };
  for (const auto& [text, request] : cases) {
    ASSERT_TRUE(bad.Send(text));
    WsClient::Message reply = bad.Read();
    ASSERT_TRUE(reply.ok) << reply.error.message();
    EXPECT_FALSE(reply.binary);
    const nlohmann::json event = nlohmann::json::parse(reply.data);
    EXPECT_EQ(event["type"], "error");
    EXPECT_EQ(event["fatal"], false);
    EXPECT_EQ(event.value("request", ""), request) << reply.data;
    EXPECT_FALSE(event["message"].get<std::string>().empty());
    // The same connection goes on, and so does the other one.
    ASSERT_TRUE(bad.Send(R"({"type":"ping","t":7})"));
    EXPECT_EQ(nlohmann::json::parse(bad.Read().data),
              nlohmann::json::parse(R"({"type":"pong","t":7.0})"));
    ASSERT_TRUE(good.Send(R"({"type":"ping","t":8})"));
    EXPECT_EQ(nlohmann::json::parse(good.Read().data)["t"], 8.0);
  }
  EXPECT_EQ(*errors_, 4);
}

TEST_F(WebSocketTest, HandlerCloseCodesAndFailures) {
  Start();
  {
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("c1")), "");
    ASSERT_TRUE(client.Send("close:4001"));
    EXPECT_EQ(client.ReadUntilClose(), 4001);
  }
  {
    // 1005 may not be sent: the server substitutes 1011 and logs it.
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("c2")), "");
    ASSERT_TRUE(client.Send("close:1005"));
    EXPECT_EQ(client.ReadUntilClose(), 1011);
  }
  {
    // A handler that throws: 1011, the server goes on.
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("c3")), "");
    ASSERT_TRUE(client.Send("throw"));
    EXPECT_EQ(client.ReadUntilClose(), 1011);
    EXPECT_TRUE(logger_.Contains("WsHandler::OnText threw"));
  }
  {
    // A factory that has no session to give: 1013.
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("refuse")), "");
    EXPECT_EQ(client.ReadUntilClose(), 1013);
  }
  {
    // The client closes: the handler learns the code.
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("c4")), "");
    client.Close(4321);
    EXPECT_TRUE(WaitFor([&] { return recorder_->closed("c4").has_value(); }));
    EXPECT_EQ(recorder_->closed("c4")->code, 4321);
    EXPECT_FALSE(recorder_->closed("c4")->initiated_by_server);
  }
  EXPECT_TRUE(WaitFor([&] { return server_->open_websockets() == 0; }));
}

TEST_F(WebSocketTest, SendsFromForeignThreadsArriveInOrderWithCompletions) {
  Start();
  WsClient client;
  ASSERT_EQ(client.Connect(port_, Target("threads")), "");
  ASSERT_TRUE(WaitFor([&] { return recorder_->sink("threads") != nullptr; }));
  std::shared_ptr<WsSink> sink = recorder_->sink("threads");
  constexpr int kThreads = 4, kPerThread = 200;
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < kPerThread; ++i) {
        auto data = std::make_shared<std::vector<uint8_t>>(3 + (i % 64) * 100, uint8_t(t));
        (*data)[1] = static_cast<uint8_t>(i & 0xFF);
        (*data)[2] = static_cast<uint8_t>(i >> 8);
        sink->SendBinary(std::move(data), [r = recorder_](bool sent) { r->Done(sent); });
      }
    });
  }
  std::vector<int> next(kThreads, 0);
  for (int n = 0; n < kThreads * kPerThread; ++n) {
    WsClient::Message m = client.Read();
    ASSERT_TRUE(m.ok) << m.error.message();
    ASSERT_TRUE(m.binary);
    const int t = static_cast<uint8_t>(m.data[0]);
    const int i = static_cast<uint8_t>(m.data[1]) | (static_cast<uint8_t>(m.data[2]) << 8);
    ASSERT_LT(t, kThreads);
    EXPECT_EQ(i, next[t]++) << "thread " << t;  // Each thread's messages in its order.
    EXPECT_EQ(m.data.size(), 3u + (i % 64) * 100);
  }
  for (std::thread& th : threads) th.join();
  EXPECT_TRUE(WaitFor([&] { return recorder_->sent() == kThreads * kPerThread; }));
  EXPECT_EQ(recorder_->unsent(), 0);
  EXPECT_TRUE(WaitFor([&] { return sink->queued_messages() == 0 && sink->queued_bytes() == 0; }));
}

TEST_F(WebSocketTest, AClientThatNeverReadsSlowsNobodyAndIsDroppedAtTheQueueCap) {
  ServerOptions options;
  options.max_ws_queue_bytes = 16 << 20;
  Start(options);
  WsClient stalled;
  ASSERT_EQ(stalled.Connect(port_, Target("stalled")), "");
  stalled.ShrinkReceiveBuffer();
  ASSERT_TRUE(WaitFor([&] { return recorder_->sink("stalled") != nullptr; }));
  std::shared_ptr<WsSink> sink = recorder_->sink("stalled");

  // Frames pile up in the stalled client's queue (the socket buffers fill, then the queue).
  const size_t frame_bytes = 256 << 10;
  auto frame = std::make_shared<const std::vector<uint8_t>>(frame_bytes, 0x5A);
  int offered = 0;
  while (sink->queued_bytes() < (8u << 20)) {
    sink->SendBinary(frame, [r = recorder_](bool sent) { r->Done(sent); });
    ++offered;
    ASSERT_LT(offered, 10000) << "the stalled client's queue never filled";
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }

  // Meanwhile another client gets every answer, with the stalled one still connected.
  WsClient active;
  ASSERT_EQ(active.Connect(port_, Target("active")), "");
  for (int i = 0; i < 200; ++i) {
    const std::string text = "round trip " + std::to_string(i);
    ASSERT_TRUE(active.Send(text));
    WsClient::Message m = active.Read();
    ASSERT_TRUE(m.ok) << i << ": " << m.error.message();
    EXPECT_EQ(m.data, text);
  }
  EXPECT_TRUE(sink->is_open());
  EXPECT_GE(sink->queued_bytes(), 8u << 20);  // It really was stalled all along.

  // Passing the cap drops the stalled connection; every queued frame completes unsent and the
  // memory is released.
  while (sink->is_open() && offered < 10000) {
    sink->SendBinary(frame, [r = recorder_](bool sent) { r->Done(sent); });
    ++offered;
  }
  EXPECT_TRUE(WaitFor([&] { return recorder_->closed("stalled").has_value(); }));
  EXPECT_EQ(recorder_->closed("stalled")->code, kCloseAbnormal);
  EXPECT_NE(recorder_->closed("stalled")->reason.find("client not reading"), std::string::npos);
  EXPECT_TRUE(WaitFor([&] { return recorder_->sent() + recorder_->unsent() == offered; }));
  EXPECT_GT(recorder_->unsent(), 0);
  EXPECT_EQ(sink->queued_bytes(), 0u);
  EXPECT_EQ(sink->queued_messages(), 0u);
  // The active client is still served.
  ASSERT_TRUE(active.Send("after"));
  EXPECT_EQ(active.Read().data, "after");
}

TEST_F(WebSocketTest, SinksOutliveTheirConnectionAndTheServer) {
  Start();
  std::shared_ptr<WsSink> sink;
  {
    WsClient client;
    ASSERT_EQ(client.Connect(port_, Target("gone")), "");
    ASSERT_TRUE(WaitFor([&] { return recorder_->sink("gone") != nullptr; }));
    sink = recorder_->sink("gone");
    EXPECT_TRUE(sink->is_open());
    client.Close();
  }
  ASSERT_TRUE(WaitFor([&] { return recorder_->closed("gone").has_value(); }));
  EXPECT_FALSE(sink->is_open());
  std::atomic<int> unsent{0};
  sink->SendText("late");
  sink->SendBinary(std::make_shared<std::vector<uint8_t>>(10), [&](bool sent) {
    if (!sent) ++unsent;
  });
  sink->Close(1000, "late close");
  EXPECT_EQ(unsent, 1);
  server_.reset();
  sink->SendBinary(std::make_shared<std::vector<uint8_t>>(10), [&](bool sent) {
    if (!sent) ++unsent;
  });
  sink->SendText("after the server");
  sink->Close(1000, "");
  EXPECT_EQ(unsent, 2);
  EXPECT_EQ(sink->queued_bytes(), 0u);
}

TEST_F(WebSocketTest, ShutdownClosesWith1001AfterQueuedMessages) {
  Start();
  WsClient client;
  ASSERT_EQ(client.Connect(port_, Target("shutdown")), "");
  ASSERT_TRUE(WaitFor([&] { return recorder_->sink("shutdown") != nullptr; }));
  std::shared_ptr<WsSink> sink = recorder_->sink("shutdown");
  constexpr int kMessages = 2000;
  for (int i = 0; i < kMessages; ++i) sink->SendText("queued " + std::to_string(i));
  std::thread stopper([&] { server_->Shutdown(); });
  size_t received = 0;
  const int code = client.ReadUntilClose(&received);
  stopper.join();
  EXPECT_EQ(code, 1001);
  EXPECT_EQ(received, static_cast<size_t>(kMessages));  // Nothing queued was lost.
  ASSERT_TRUE(recorder_->closed("shutdown").has_value());
  EXPECT_EQ(recorder_->closed("shutdown")->code, kCloseGoingAway);
  EXPECT_EQ(server_->open_websockets(), 0u);
  // New connections are refused once stopped.
  WsClient late;
  EXPECT_NE(late.Connect(port_, Target("late")), "");
}

TEST_F(WebSocketTest, TwoHundredConnectDisconnectCyclesLeaveNothingBehind) {
  Start();
  auto cycle = [&](int i) {
    WsClient client;
    const std::string name = "cycle" + std::to_string(i % 7);
    ASSERT_EQ(client.Connect(port_, Target(name)), "");
    ASSERT_TRUE(client.Send("ping " + std::to_string(i)));
    ASSERT_EQ(client.Read().data, "ping " + std::to_string(i));
    if (i % 3 == 0) {
      client.Close();  // Clean close handshake.
    }                  // Otherwise the socket just goes away (abrupt disconnect).
  };
  for (int i = 0; i < 20; ++i) cycle(i);  // Warm-up: allocator pools, thread stacks.
  ASSERT_TRUE(WaitFor([&] { return server_->open_websockets() == 0; }));
  recorder_->Clear();
  const uint64_t rss_before = ResidentBytes();
  for (int i = 0; i < 200; ++i) cycle(i);
  ASSERT_TRUE(WaitFor([&] { return server_->open_websockets() == 0; }));
  ASSERT_TRUE(WaitFor([&] { return server_->open_connections() == 0; }));
  EXPECT_TRUE(WaitFor([&] { return recorder_->close_count() == 220; }));
  EXPECT_EQ(recorder_->opens(), 220);
  recorder_->Clear();
  const uint64_t rss_after = ResidentBytes();
  std::printf("RSS before %.1f MiB, after 200 cycles %.1f MiB\n", rss_before / 1048576.0,
              rss_after / 1048576.0);
  // Flat: far below what 200 leaked connections (buffers, handlers, sockets) would hold.
  EXPECT_LT(rss_after, rss_before + (4u << 20));
}

}  // namespace
}  // namespace octoscope::net
