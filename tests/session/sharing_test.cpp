// Sharing without rendering (docs/protocol.md "Sharing"): participants and roles of a
// ViewSession, share links and resume keys in the SessionRegistry, the session limit and idle
// release — through real sessions whose sinks record what their clients would receive.
#include <gtest/gtest.h>

#include <atomic>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "session/session_registry.h"
#include "session/view_session.h"
#include "util/latest_wins_executor.h"
#include "util/timer_queue.h"

namespace octoscope::session {
namespace {

using json = nlohmann::json;
using protocol::Role;

class RecordingSink : public SessionSink {
 public:
  void SendText(std::string text) override {
    std::lock_guard<std::mutex> lock(mu_);
    events_.push_back(json::parse(text));
  }
  void SendBinary(std::vector<uint8_t>) override {}
  void Close(uint16_t code, std::string reason) override {
    std::lock_guard<std::mutex> lock(mu_);
    close_code_ = code;
    close_reason_ = std::move(reason);
  }
  // The last event of `type` (null when none).
  json Last(const std::string& type) const {
    std::lock_guard<std::mutex> lock(mu_);
    for (auto it = events_.rbegin(); it != events_.rend(); ++it) {
      if ((*it)["type"] == type) return *it;
    }
    return nullptr;
  }
  int Count(const std::string& type) const {
    std::lock_guard<std::mutex> lock(mu_);
    int n = 0;
    for (const auto& e : events_) n += e["type"] == type;
    return n;
  }
  int close_code() const {
    std::lock_guard<std::mutex> lock(mu_);
    return close_code_;
  }

 private:
  mutable std::mutex mu_;
  std::vector<json> events_;
  int close_code_ = 0;
  std::string close_reason_;
};

class SharingTest : public ::testing::Test {
 protected:
  SharingTest() : encoders_(1), registry_(&timers_, Limits()) {
    context_.encoders = &encoders_;
    context_.timers = &timers_;
    context_.registry = &registry_;
    context_.server_version = "test";
    context_.max_participants = 3;
    link_base_.Set("https://scope.example/octoscope/");
    context_.link_base = &link_base_;
  }
  static SessionLimits Limits() {
    SessionLimits limits;
    limits.max_sessions = 2;
    limits.idle_timeout = std::chrono::milliseconds(200);
    return limits;
  }
  std::string Hello(ViewSession& session, const std::string& participant, const std::string& name) {
    session.HandleText(participant,
                       json{{"type", "hello"}, {"protocol", 1}, {"name", name}}.dump());
    return participant;
  }

  TimerQueue timers_;
  LatestWinsExecutor encoders_;
  SessionRegistry registry_;
  LinkBase link_base_;
  SessionContext context_;
};

TEST_F(SharingTest, RolesLinksPromotionAndRevocation) {
  auto created = registry_.Create(context_);
  ASSERT_TRUE(created.ok());
  auto session = *created;
  auto owner_sink = std::make_shared<RecordingSink>();
  auto owner = session->Join(owner_sink, {Role::kOwner, "alice", ""});
  ASSERT_TRUE(owner.ok());
  Hello(*session, *owner, "alice");
  const json welcome = owner_sink->Last("welcome");
  EXPECT_EQ(welcome["role"], "owner");
  EXPECT_EQ(welcome["resume"], session->resume_key());
  EXPECT_EQ(registry_.FindByResume(session->resume_key()), session);
  EXPECT_EQ(registry_.FindByResume(std::string(32, '0')), nullptr);

  session->HandleText(*owner, R"({"type":"share_create","role":"viewer","ttl_s":3600})");
  const json share = owner_sink->Last("share_created");
  ASSERT_FALSE(share.is_null());
  const std::string token = share["token"];
  EXPECT_EQ(share["url"], "https://scope.example/octoscope/?share=" + token);
  EXPECT_TRUE(share["expires"].is_string());
  auto found = registry_.FindShare(token);
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(found->session, session);
  EXPECT_EQ(found->role, Role::kViewer);
  EXPECT_FALSE(registry_.FindShare(token.substr(0, 31) + "x").has_value());

  auto viewer_sink = std::make_shared<RecordingSink>();
  auto viewer = session->Join(viewer_sink, {found->role, "", token});
  ASSERT_TRUE(viewer.ok());
  Hello(*session, *viewer, "bob");
  EXPECT_EQ(viewer_sink->Last("welcome")["role"], "viewer");
  EXPECT_FALSE(viewer_sink->Last("welcome").contains("resume"));
  const json listed = owner_sink->Last("participants");
  ASSERT_EQ(listed["participants"].size(), 2u);
  EXPECT_EQ(listed["participants"][1]["name"], "bob");
  EXPECT_EQ(listed["participants"][0]["you"], true);

  // A viewer cannot drive, nor use the owner's messages.
  for (const char* message :
       {R"({"type":"interaction","active":true})", R"({"type":"slices","position_um":[1,2,3]})",
        R"({"type":"open","dataset":"d"})"}) {
    session->HandleText(*viewer, message);
    EXPECT_EQ(viewer_sink->Last("error")["message"], "viewers cannot drive the view");
    EXPECT_EQ(viewer_sink->Last("error")["fatal"], false);
  }
  session->HandleText(*viewer, R"({"type":"kick","participant":"p1"})");
  EXPECT_EQ(viewer_sink->Last("error")["message"], "only the owner may send kick");
  // Promoted, it may (here: it is told no dataset is open, not that it may not drive).
  session->HandleText(
      *owner,
      json{{"type", "participant_role"}, {"participant", *viewer}, {"role", "controller"}}.dump());
  EXPECT_EQ(owner_sink->Last("participants")["participants"][1]["role"], "controller");
  session->HandleText(*viewer, R"({"type":"slices","position_um":[1,2,3]})");
  EXPECT_NE(viewer_sink->Last("error")["message"], "viewers cannot drive the view");
  // The owner's role is fixed.
  session->HandleText(
      *owner,
      json{{"type", "participant_role"}, {"participant", *owner}, {"role", "viewer"}}.dump());
  EXPECT_EQ(owner_sink->Last("error")["message"], "the owner's role cannot change");

  // Revoked: those who joined through the link are closed with 4001, the link is gone.
  session->HandleText(*owner, json{{"type", "share_revoke"}, {"token", token}}.dump());
  EXPECT_EQ(viewer_sink->close_code(), 4001);
  EXPECT_FALSE(registry_.FindShare(token).has_value());
  EXPECT_EQ(session->participant_count(), 1u);
  EXPECT_EQ(owner_sink->Last("shares")["shares"].size(), 0u);
  EXPECT_EQ(owner_sink->Last("participants")["participants"].size(), 1u);
  session->HandleText(*owner, json{{"type", "share_revoke"}, {"token", token}}.dump());
  EXPECT_EQ(owner_sink->Last("error")["message"], "no such share link in this session");
}

TEST_F(SharingTest, KickFullSessionsAndTheOwnersReattachment) {
  auto session = *registry_.Create(context_);
  auto owner_sink = std::make_shared<RecordingSink>();
  auto owner = *session->Join(owner_sink, {Role::kOwner, "alice", ""});
  auto a = std::make_shared<RecordingSink>();
  auto b = std::make_shared<RecordingSink>();
  auto pa = *session->Join(a, {Role::kViewer, "", ""});
  ASSERT_TRUE(session->Join(b, {Role::kController, "", ""}).ok());
  auto refused = session->Join(std::make_shared<RecordingSink>(), {Role::kViewer, "", ""});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(refused.status().message(), "session full");
  session->HandleText(owner, json{{"type", "kick"}, {"participant", pa}}.dump());
  EXPECT_EQ(a->close_code(), 4003);
  EXPECT_EQ(session->participant_count(), 2u);
  // The owner reattaches from a new connection: the old one is closed with 4002.
  auto again = std::make_shared<RecordingSink>();
  auto reattached = session->Join(again, {Role::kOwner, "alice", ""});
  ASSERT_TRUE(reattached.ok());
  EXPECT_EQ(owner_sink->close_code(), 4002);
  Hello(*session, *reattached, "alice");
  EXPECT_EQ(again->Last("welcome")["resume"], session->resume_key());
  EXPECT_EQ(again->Last("welcome")["session"], session->id());
}

TEST_F(SharingTest, TheSessionLimitParksAndReleases) {
  auto first = *registry_.Create(context_);
  auto second = *registry_.Create(context_);
  auto s1 = std::make_shared<RecordingSink>();
  auto s2 = std::make_shared<RecordingSink>();
  auto p1 = *first->Join(s1, {Role::kOwner, "", ""});
  ASSERT_TRUE(second->Join(s2, {Role::kOwner, "", ""}).ok());
  auto third = registry_.Create(context_);
  ASSERT_FALSE(third.ok());
  EXPECT_EQ(third.status().message(), "too many sessions");
  // The first owner leaves: its session is parked and gives way to a new one.
  first->Leave(p1);
  EXPECT_TRUE(first->empty_since().has_value());
  third = registry_.Create(context_);
  ASSERT_TRUE(third.ok());
  EXPECT_TRUE(first->closed());
  EXPECT_EQ(registry_.FindByResume(first->resume_key()), nullptr);
  EXPECT_EQ(registry_.size(), 2u);
  // Idle release: the new session never got a participant; it goes after the idle timeout.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!(*third)->closed() && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_TRUE((*third)->closed());
  EXPECT_FALSE(second->closed());
  EXPECT_EQ(registry_.size(), 1u);
}

TEST_F(SharingTest, ExpiredAndUnknownLinksAreRefused) {
  auto session = *registry_.Create(context_);
  registry_.AddShare(std::string(32, 'a'), "ida", session, Role::kViewer,
                     std::chrono::system_clock::now() - std::chrono::seconds(1));
  registry_.AddShare(std::string(32, 'b'), "idb", session, Role::kController, std::nullopt);
  EXPECT_FALSE(registry_.FindShare(std::string(32, 'a')).has_value());
  EXPECT_FALSE(registry_.FindShareById("ida").has_value());
  EXPECT_TRUE(registry_.FindShare(std::string(32, 'b')).has_value());
  EXPECT_EQ(registry_.FindShare(std::string(32, 'b'))->id, "idb");
  EXPECT_EQ(registry_.FindShareById("idb")->session, session);
  EXPECT_FALSE(registry_.FindShare("").has_value());
  EXPECT_FALSE(registry_.FindShareById(std::string(32, 'b')).has_value());
  session->Close();
  EXPECT_FALSE(registry_.FindShare(std::string(32, 'b')).has_value());
  EXPECT_FALSE(registry_.FindShareById("idb").has_value());
  EXPECT_TRUE(SecretsEqual("abc", "abc"));
  EXPECT_FALSE(SecretsEqual("abc", "abd"));
  EXPECT_FALSE(SecretsEqual("abc", "abcd"));
}

// Grants decided by the test: every grant holds unless listed in `ended`; a share grant has a
// share link on its chain.
class FakeGrants : public GrantChecker {
 public:
  GrantVerdict Check(const protocol::GrantRef& grant, std::string_view dataset) const override {
    std::lock_guard<std::mutex> lock(mu_);
    GrantVerdict v;
    const std::string text = protocol::GrantRefText(grant);
    v.holds = ended_.count(text) == 0 && (dataset.empty() || covered_.count(text + "@" + std::string(dataset)) != 0 ||
                                          covered_.count(text + "@*") != 0);
    v.reason = ended_.count(text) != 0 ? "token expired" : "not allowed for this dataset";
    v.via_share = grant.kind == protocol::GrantRef::Kind::kShare;
    v.owner = {protocol::GrantRef::Kind::kUser, "u1"};
    return v;
  }
  void End(const std::string& grant) {
    std::lock_guard<std::mutex> lock(mu_);
    ended_.insert(grant);
  }
  void Cover(const std::string& grant_at_dataset) {
    std::lock_guard<std::mutex> lock(mu_);
    covered_.insert(grant_at_dataset);
  }

 private:
  mutable std::mutex mu_;
  std::set<std::string> ended_, covered_;
};

class GrantedSharingTest : public SharingTest {
 protected:
  GrantedSharingTest() { context_.grants = &grants_; }

  // A session owned by user u1 with its owner connected and welcomed (sink: owner_sink_).
  std::shared_ptr<ViewSession> OwnedSession(const ViewSessionOptions& options = {}) {
    auto session = *registry_.Create(context_, options, {protocol::GrantRef::Kind::kUser, "u1"});
    owner_sink_ = std::make_shared<RecordingSink>();
    owner_ = *session->Join(owner_sink_, {Role::kOwner, "alice", ""});
    Hello(*session, owner_, "alice");
    return session;
  }

  FakeGrants grants_;
  std::shared_ptr<RecordingSink> owner_sink_;
  std::string owner_;
};

TEST_F(GrantedSharingTest, AJoinThatRacesARevocationIsRefused) {
  auto session = OwnedSession();
  auto owner_sink = owner_sink_;
  const std::string owner = owner_;
  session->HandleText(owner, R"({"type":"share_create","role":"controller"})");
  const std::string token = owner_sink->Last("share_created")["token"];
  // The upgrade found the link; the owner revokes it before the join lands.
  auto found = registry_.FindShare(token);
  ASSERT_TRUE(found.has_value());
  session->HandleText(owner, json{{"type", "share_revoke"}, {"token", token}}.dump());
  auto late = session->Join(std::make_shared<RecordingSink>(), {found->role, "", token});
  ASSERT_FALSE(late.ok());
  EXPECT_EQ(late.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(session->participant_count(), 1u);
  // A token the session never made is refused the same way.
  EXPECT_FALSE(session->Join(std::make_shared<RecordingSink>(), {Role::kViewer, "", "x"}).ok());
}

TEST_F(GrantedSharingTest, GuestsActUnderTheirLinkAndCannotShareOn) {
  auto session = OwnedSession();
  auto owner_sink = owner_sink_;
  const std::string owner = owner_;
  session->HandleText(owner, R"({"type":"share_create","role":"controller"})");
  const json created = owner_sink->Last("share_created");
  ASSERT_FALSE(created.is_null()) << owner_sink->Last("error");
  const std::string token = created["token"];
  auto guest_sink = std::make_shared<RecordingSink>();
  auto guest = *session->Join(guest_sink, {Role::kController, "", token});
  Hello(*session, guest, "bob");
  // The link's grant does not cover "other": refused like a dataset that does not exist.
  session->HandleText(guest, R"({"type":"open","dataset":"other"})");
  EXPECT_EQ(guest_sink->Last("error")["message"], "no dataset 'other'");
  // A session owned under a grant with a share link on its chain cannot be shared on.
  auto forked = *registry_.Create(context_, {}, {protocol::GrantRef::Kind::kShare, "abc"});
  auto fork_sink = std::make_shared<RecordingSink>();
  auto fork_owner = *forked->Join(fork_sink, {Role::kOwner, "", ""});
  forked->HandleText(fork_owner, R"({"type":"share_create","role":"viewer"})");
  EXPECT_TRUE(fork_sink->Last("share_created").is_null());
  EXPECT_NE(fork_sink->Last("error")["message"].get<std::string>().find("cannot be shared further"),
            std::string::npos);
}

TEST_F(GrantedSharingTest, WhenTheOwnersGrantEndsEveryoneIsClosedWith4005) {
  auto session = OwnedSession();
  auto owner_sink = owner_sink_;
  const std::string owner = owner_;
  session->HandleText(owner, R"({"type":"share_create","role":"viewer"})");
  const std::string token = owner_sink->Last("share_created")["token"];
  auto guest_sink = std::make_shared<RecordingSink>();
  ASSERT_TRUE(session->Join(guest_sink, {Role::kViewer, "", token}).ok());
  registry_.Revalidate();
  EXPECT_EQ(owner_sink->close_code(), 0);
  grants_.End("user:u1");
  registry_.Revalidate();
  EXPECT_EQ(owner_sink->close_code(), 4005);
  EXPECT_EQ(guest_sink->close_code(), 4005);
  EXPECT_TRUE(session->closed());
  EXPECT_FALSE(registry_.FindShare(token).has_value());
  EXPECT_EQ(registry_.FindByResume(session->resume_key()), nullptr);
  EXPECT_EQ(registry_.size(), 0u);
}

TEST_F(GrantedSharingTest, AnExpiredLinkClosesThoseWhoJoinedThroughIt) {
  auto clock = std::make_shared<std::atomic<int64_t>>(1'800'000'000);
  ViewSessionOptions options;
  options.unix_clock = [clock] { return clock->load(); };
  auto session = OwnedSession(options);
  auto owner_sink = owner_sink_;
  const std::string owner = owner_;
  session->HandleText(owner, R"({"type":"share_create","role":"viewer","ttl_s":60})");
  session->HandleText(owner, R"({"type":"share_create","role":"viewer"})");
  ASSERT_EQ(owner_sink->Count("share_created"), 2);
  const std::string forever = owner_sink->Last("share_created")["token"];
  const std::string token = owner_sink->Last("shares")["shares"][0]["token"];
  ASSERT_NE(token, forever);
  const std::string id = registry_.FindShare(token)->id;
  auto guest_sink = std::make_shared<RecordingSink>();
  ASSERT_TRUE(session->Join(guest_sink, {Role::kViewer, "", token}).ok());
  auto other_sink = std::make_shared<RecordingSink>();
  ASSERT_TRUE(session->Join(other_sink, {Role::kViewer, "", forever}).ok());
  ASSERT_TRUE(session->share_state(id).has_value());
  EXPECT_FALSE(session->share_state("nope").has_value());
  // Not expired yet: nothing happens.
  clock->store(1'800'000'059);
  registry_.Revalidate();
  EXPECT_EQ(guest_sink->close_code(), 0);
  // Expired: the link admits nobody, and those who joined through it go with it (4001).
  clock->store(1'800'000'060);
  EXPECT_FALSE(session->share_state(id).has_value());
  EXPECT_FALSE(session->Join(std::make_shared<RecordingSink>(), {Role::kViewer, "", token}).ok());
  registry_.Revalidate();
  EXPECT_EQ(guest_sink->close_code(), 4001);
  EXPECT_EQ(other_sink->close_code(), 0);
  EXPECT_FALSE(registry_.FindShare(token).has_value());
  EXPECT_EQ(owner_sink->Last("shares")["shares"].size(), 1u);
}

TEST_F(GrantedSharingTest, OneOwnerHoldsAtMostItsShareOfSessions) {
  SessionLimits limits = Limits();
  limits.max_sessions = 10;
  limits.max_sessions_per_owner = 2;
  SessionRegistry registry(&timers_, limits);
  const protocol::GrantRef alice{protocol::GrantRef::Kind::kUser, "ua"};
  const protocol::GrantRef bob{protocol::GrantRef::Kind::kUser, "ub"};
  std::vector<std::shared_ptr<ViewSession>> held;
  for (int i = 0; i < 2; ++i) {
    auto s = registry.Create(context_, {}, alice);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE((*s)->Join(std::make_shared<RecordingSink>(), {Role::kOwner, "", ""}).ok());
    held.push_back(*s);
  }
  auto third = registry.Create(context_, {}, alice);
  ASSERT_FALSE(third.ok());
  EXPECT_EQ(third.status().message(), "too many sessions for this user");
  // Others are not affected.
  EXPECT_TRUE(registry.Create(context_, {}, bob).ok());
}

TEST_F(GrantedSharingTest, MessageFloodsAreDroppedWithOneErrorASecondButAcksPass) {
  ViewSessionOptions options;
  options.messages_per_second = 10;
  options.message_burst = 20;
  options.hello_burst = 2;
  options.hellos_per_second = 0.001;
  auto session = *registry_.Create(context_, options, {protocol::GrantRef::Kind::kUser, "u1"});
  auto sink = std::make_shared<RecordingSink>();
  auto p = *session->Join(sink, {Role::kOwner, "alice", ""});
  for (int i = 0; i < 100; ++i) {
    session->HandleText(p, json{{"type", "ping"}, {"t", i}}.dump());
  }
  EXPECT_EQ(sink->Count("pong"), 20);
  EXPECT_EQ(sink->Count("error"), 1);
  EXPECT_NE(sink->Last("error")["message"].get<std::string>().find("too many messages"),
            std::string::npos);
  EXPECT_EQ(sink->Last("error")["fatal"], false);
  // Acknowledgements are never dropped (they cost nothing and a lost one stalls frames).
  for (int i = 0; i < 50; ++i) session->HandleText(p, R"({"type":"ack","frame":1})");
  EXPECT_EQ(sink->Count("error"), 1);
  EXPECT_EQ(sink->close_code(), 0);
}

}  // namespace
}  // namespace octoscope::session
