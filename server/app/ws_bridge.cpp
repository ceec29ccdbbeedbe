#include "app/ws_bridge.h"

#include <string>
#include <utility>
#include <vector>

#include "util/random_token.h"

namespace octoscope::app {
namespace {

class SinkAdapter : public session::SessionSink {
 public:
  explicit SinkAdapter(std::shared_ptr<net::WsSink> sink) : sink_(std::move(sink)) {}
  void SendText(std::string text) override { sink_->SendText(std::move(text)); }
  void SendBinary(std::vector<uint8_t> bytes) override {
    sink_->SendBinary(std::make_shared<const std::vector<uint8_t>>(std::move(bytes)));
  }
  void Close(uint16_t code, std::string reason) override { sink_->Close(code, std::move(reason)); }

 private:
  std::shared_ptr<net::WsSink> sink_;
};

class SessionHandler : public net::WsHandler {
 public:
  SessionHandler(const session::SessionContext* context, session::ViewSessionOptions options)
      : context_(context), options_(options) {}
  ~SessionHandler() override {
    if (session_ != nullptr) session_->Close();
  }

  void OnOpen(std::shared_ptr<net::WsSink> sink) override {
    auto id = RandomHex(8);
    session_ = session::ViewSession::Create(*context_, std::make_shared<SinkAdapter>(sink),
                                            id.ok() ? *id : std::string("session"), options_);
  }
  void OnText(std::string text) override {
    if (session_ != nullptr) session_->HandleText(text);
  }
  void OnClose(const net::WsCloseInfo& info) override {
    (void)info;
    if (session_ != nullptr) session_->Close();
  }

 private:
  const session::SessionContext* context_;
  const session::ViewSessionOptions options_;
  std::shared_ptr<session::ViewSession> session_;
};

}  // namespace

net::WsHandlerFactory MakeSessionFactory(const session::SessionContext* context,
                                         const session::ViewSessionOptions& options,
                                         OpenCheck may_open) {
  return [context, options,
          may_open](const net::WsConnectInfo& info) -> std::unique_ptr<net::WsHandler> {
    session::ViewSessionOptions connection = options;
    if (may_open) {
      connection.may_open = [may_open, principal = info.principal](std::string_view id) {
        return may_open(principal, id);
      };
    }
    return std::make_unique<SessionHandler>(context, connection);
  };
}

}  // namespace octoscope::app
