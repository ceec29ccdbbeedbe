#include "app/ws_bridge.h"

#include <string>
#include <utility>
#include <vector>

#include "protocol/ws_messages.h"
#include "session/view_store.h"

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
  SessionHandler(const session::SessionContext* context, session::ViewSessionOptions options,
                 WsCredential credential)
      : context_(context), options_(options), credential_(std::move(credential)) {}
  ~SessionHandler() override { LeaveSession(); }

  void OnOpen(std::shared_ptr<net::WsSink> sink) override {
    sink_ = std::make_shared<SinkAdapter>(std::move(sink));
    session::SessionRegistry* registry = context_->registry;
    if (credential_.kind == WsCredential::Kind::kShare) {
      auto share = registry->FindShare(credential_.credential);
      if (!share) {
        Refuse(4001, "share link revoked", "this share link is not valid (revoked or expired)");
        return;
      }
      // A signed-in user following the link is shown by name; a guest by role and number.
      Join(share->session, {share->role, credential_.user, credential_.credential});
      return;
    }
    auto created = registry->Create(*context_, options_, credential_.grant);
    if (!created.ok()) {
      Refuse(1013, created.status().message(), created.status().message());
      return;
    }
    const std::string name =
        credential_.kind == WsCredential::Kind::kUser && !credential_.user.empty()
            ? credential_.user
            : std::string("owner");
    if (!Join(*created, {protocol::Role::kOwner, name, ""})) return;
    if (credential_.kind == WsCredential::Kind::kView) OpenView(credential_.credential);
  }

  void OnText(std::string text) override {
    if (session_ == nullptr) return;
    // A reconnecting owner: `hello` with the resume key of its earlier session.
    if (credential_.kind == WsCredential::Kind::kUser &&
        text.find("\"resume\"") != std::string::npos) {
      MaybeResume(text);
    }
    if (session_ != nullptr) session_->HandleText(participant_, text);
  }

  void OnClose(const net::WsCloseInfo& info) override {
    (void)info;
    LeaveSession();
  }

 private:
  bool Join(const std::shared_ptr<session::ViewSession>& session, session::JoinOptions options) {
    const bool through_share = !options.share_token.empty();
    auto joined = session->Join(sink_, std::move(options));
    if (!joined.ok()) {
      const uint16_t code = joined.status().code() == StatusCode::kResourceExhausted ? 1013
                            : through_share                                         ? 4001
                                                                                    : 4004;
      Refuse(code, code == 4001 ? "share link revoked" : joined.status().message(),
             joined.status().message());
      return false;
    }
    session_ = session;
    participant_ = *joined;
    return true;
  }

  void Refuse(uint16_t code, const std::string& reason, const std::string& message) {
    sink_->SendText(protocol::ErrorEvent(message, "", true));
    sink_->Close(code, reason);
  }

  void LeaveSession() {
    if (session_ == nullptr) return;
    session_->Leave(participant_);
    session_.reset();
  }

  // Reads the view link off the I/O thread, then opens it in the connection's new session.
  void OpenView(const std::string& id) {
    session::ViewStore* views = context_->views;
    auto sink = sink_;
    std::weak_ptr<session::ViewSession> weak = session_;
    const std::string participant = participant_;
    LatestWinsExecutor* io =
        context_->state_io != nullptr ? context_->state_io : context_->encoders;
    io->Post([views, sink, weak, participant, id] {
      auto session = weak.lock();
      if (session == nullptr) return;
      auto link = views != nullptr
                      ? views->Load(id)
                      : Result<protocol::ViewLink>(NotFoundError("view links are not available"));
      if (!link.ok()) {
        sink->SendText(protocol::ErrorEvent(link.status().message(), "open", true));
        sink->Close(4004, "view link unavailable");
        return;
      }
      session->OpenViewLink(participant, std::move(*link));
    });
  }

  void MaybeResume(const std::string& text) {
    auto message = protocol::ParseClientMessage(text);
    if (!message.ok()) return;
    auto* hello = std::get_if<protocol::HelloMessage>(&*message);
    if (hello == nullptr || hello->resume.empty()) return;
    auto target = context_->registry->FindByResume(hello->resume);
    if (target == session_) return;
    // Only a session owned under this connection's own grant: a resume key that leaked to
    // another user takes nothing over.
    if (target != nullptr && !(target->owner_grant() == credential_.grant)) target = nullptr;
    if (target == nullptr) {
      sink_->SendText(protocol::ErrorEvent(
          "unknown resume key (the session was released); this is a new session", "hello", false));
      return;
    }
    auto previous = session_;
    const std::string previous_participant = participant_;
    previous->Leave(previous_participant);
    session_.reset();
    const std::string name = credential_.user.empty() ? std::string("owner") : credential_.user;
    if (Join(target, {protocol::Role::kOwner, name, ""})) {
      context_->registry->ReleaseIfEmpty(previous);
    }
  }

  const session::SessionContext* context_;
  const session::ViewSessionOptions options_;
  const WsCredential credential_;
  std::shared_ptr<SinkAdapter> sink_;
  std::shared_ptr<session::ViewSession> session_;
  std::string participant_;
};

}  // namespace

net::WsHandlerFactory MakeSessionFactory(const session::SessionContext* context,
                                         WsCredentialFn credential,
                                         const session::ViewSessionOptions& options) {
  return [context, credential = std::move(credential),
          options](const net::WsConnectInfo& info) -> std::unique_ptr<net::WsHandler> {
    return std::make_unique<SessionHandler>(context, options, credential(info));
  };
}

}  // namespace octoscope::app
