#include "session/view_session.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "dataset/dataset_description.h"
#include "dataset/display_defaults.h"
#include "encode/image_encoder.h"
#include "protocol/dataset_json.h"
#include "protocol/frame_header.h"
#include "render/area_resample.h"
#include "render/camera.h"
#include "session/session_registry.h"
#include "session/view_store.h"
#include "util/random_token.h"
#include "volume/value_map.h"

namespace octoscope::session {
namespace {

using protocol::Role;
using protocol::ViewId;
constexpr ViewId kAllViews[] = {ViewId::k3d, ViewId::kX, ViewId::kY, ViewId::kZ};
// Outbox views of screenshots: beyond the four views, one per screenshot id modulo this.
constexpr int kScreenshotViewBase = 16;
constexpr int kScreenshotViewCount = 64;
constexpr char kViewersCannotDrive[] = "viewers cannot drive the view";
// Close code when the grant a connection rests on ended (docs/protocol.md).
constexpr uint16_t kAccessEndedCode = 4005;

size_t Index(ViewId view) { return static_cast<size_t>(view); }

double Elapsed(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

// The volume's box in µm along each axis.
std::array<double, 3> Extent(const dataset::Dataset& dataset) {
  const auto spacing = dataset.spacing_um();
  const auto& size = dataset.info().size;
  return {size[0] * spacing[0], size[1] * spacing[1], size[2] * spacing[2]};
}

std::array<double, 3> Clamped(const std::array<double, 3>& p, const std::array<double, 3>& hi) {
  return {std::clamp(p[0], 0.0, hi[0]), std::clamp(p[1], 0.0, hi[1]), std::clamp(p[2], 0.0, hi[2])};
}

bool SameSize(const protocol::PixelSize& a, const protocol::PixelSize& b) {
  return a.width == b.width && a.height == b.height;
}

// Messages that change the shared state: refused for viewers.
bool Drives(const protocol::ClientMessage& m) {
  return std::holds_alternative<protocol::OpenMessage>(m) ||
         std::holds_alternative<protocol::CameraMessage>(m) ||
         std::holds_alternative<protocol::ParamsMessage>(m) ||
         std::holds_alternative<protocol::SlicesMessage>(m) ||
         std::holds_alternative<protocol::InteractionMessage>(m);
}

bool OwnerOnly(const protocol::ClientMessage& m) {
  return std::holds_alternative<protocol::ShareCreateMessage>(m) ||
         std::holds_alternative<protocol::ShareRevokeMessage>(m) ||
         std::holds_alternative<protocol::ParticipantRoleMessage>(m) ||
         std::holds_alternative<protocol::KickMessage>(m);
}

int64_t SystemUnixNow() {
  return std::chrono::duration_cast<std::chrono::seconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace

std::shared_ptr<ViewSession> ViewSession::Create(const SessionContext& context,
                                                 std::string session_id, std::string resume_key,
                                                 const ViewSessionOptions& options,
                                                 protocol::GrantRef owner) {
  return std::shared_ptr<ViewSession>(new ViewSession(context, std::move(session_id),
                                                      std::move(resume_key), options,
                                                      std::move(owner)));
}

ViewSession::ViewSession(const SessionContext& context, std::string id, std::string resume_key,
                         const ViewSessionOptions& options, protocol::GrantRef owner)
    : context_(context),
      options_(options),
      id_(std::move(id)),
      resume_key_(std::move(resume_key)),
      owner_grant_(std::move(owner)),
      empty_since_(Clock::now()) {
  for (ViewId v : kAllViews) views_[Index(v)].id = v;
}

ViewSession::~ViewSession() { Close(); }

size_t ViewSession::participant_count() const {
  std::lock_guard<std::mutex> lock(mu_);
  return participants_.size();
}

bool ViewSession::closed() const {
  std::lock_guard<std::mutex> lock(mu_);
  return closed_;
}

std::optional<Clock::time_point> ViewSession::empty_since() const {
  std::lock_guard<std::mutex> lock(mu_);
  return empty_since_;
}

OutboxStats ViewSession::outbox_stats(std::string_view participant) const {
  std::shared_ptr<Participant> p;
  {
    std::lock_guard<std::mutex> lock(mu_);
    p = FindLocked(participant);
  }
  return p != nullptr ? p->outbox().stats() : OutboxStats{};
}

Result<std::string> ViewSession::Join(std::shared_ptr<SessionSink> sink, JoinOptions options) {
  std::vector<render::ViewId> to_close;
  std::string id;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return FailedPreconditionError("the session was released");
    // A share link is checked again here, under the lock its revocation takes: a join that
    // raced a revoke (or the link's expiry) is refused, never left connected.
    const Share* share = nullptr;
    if (!options.share_token.empty()) {
      const int64_t now = WallClock();
      for (const Share& s : shares_) {
        if (s.token == options.share_token && (!s.expires_unix_s || now < *s.expires_unix_s)) {
          share = &s;
        }
      }
      if (share == nullptr) {
        return FailedPreconditionError("this share link is not valid (revoked or expired)");
      }
    }
    if (options.role == Role::kOwner) {
      // The owner reattaches: an owner connection still attached gives way.
      std::vector<std::shared_ptr<Participant>> owners;
      for (const auto& p : participants_) {
        if (p->role == Role::kOwner) owners.push_back(p);
      }
      for (const auto& p : owners) RemoveLocked(p, 4002, "resumed elsewhere", &to_close);
    }
    if (participants_.size() >= static_cast<size_t>(std::max(1, context_.max_participants))) {
      return ResourceExhaustedError("session full");
    }
    auto p = std::make_shared<Participant>(next_participant_++, std::move(sink), context_.metrics,
                                           options_.window);
    p->role = options.role;
    p->name = !options.name.empty() ? options.name
                                    : std::string(protocol::RoleName(options.role)) + " " +
                                          std::to_string(p->number());
    p->share_token = std::move(options.share_token);
    p->grant = share != nullptr ? protocol::GrantRef{protocol::GrantRef::Kind::kShare, share->id}
                                : owner_grant_;
    if (share != nullptr) p->role = share->role;  // The link's role as it is now.
    p->messages = TokenBucket(options_.messages_per_second, std::max(1.0, options_.message_burst));
    p->hellos = TokenBucket(options_.hellos_per_second, std::max(1.0, options_.hello_burst));
    p->preferences.jpeg_interactive = options_.jpeg_interactive;
    p->preferences.jpeg_final = options_.jpeg_final;
    participants_.push_back(p);
    if (participants_.size() == 1 && context_.metrics != nullptr) context_.metrics->SessionOpened();
    empty_since_.reset();
    id = p->id();
    BroadcastParticipantsLocked(false);
  }
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
  return id;
}

void ViewSession::Leave(std::string_view participant) {
  std::vector<render::ViewId> to_close;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto p = FindLocked(participant);
    if (p == nullptr) return;
    RemoveLocked(p, 0, "", &to_close);
  }
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
}

void ViewSession::RemoveLocked(const std::shared_ptr<Participant>& p, uint16_t code,
                               const std::string& reason, std::vector<render::ViewId>* to_close) {
  if (p->left) return;
  p->left = true;
  std::erase(participants_, p);
  if (code != 0) p->sink().Close(code, reason);
  p->outbox().Close();
  if (p->stats_timer) context_.timers->Cancel(*p->stats_timer);
  p->stats_timer.reset();
  if (context_.metrics != nullptr) {
    context_.metrics->FramesDropped(p->outbox().stats().dropped - p->last_stats.dropped);
  }
  // Its screenshots are dropped with it (their views close outside the lock).
  for (auto it = screenshots_.begin(); it != screenshots_.end();) {
    if (it->participant == p) {
      to_close->push_back(it->render_view);
      it = screenshots_.erase(it);
    } else {
      ++it;
    }
  }
  for (int k = 0; k < protocol::kViewCount + kScreenshotViewBase + kScreenshotViewCount; ++k) {
    context_.encoders->Forget(reinterpret_cast<uintptr_t>(p.get()) + k);
  }
  if (last_changer_ == p->number()) last_changer_ = 0;
  if (participants_.empty()) {
    empty_since_ = Clock::now();
    if (context_.metrics != nullptr) context_.metrics->SessionClosed();
  }
  const auto now = Clock::now();
  for (View& view : views_) RegroupViewLocked(view, now, to_close);
  // Interaction of the one who left ends with it.
  const bool interacting = AnyInteractingLocked();
  if (interacting != interacting_) {
    interacting_ = interacting;
    for (View& view : views_) {
      for (Group& g : view.groups) g.policy.OnInteraction(interacting, now);
    }
  }
  BroadcastParticipantsLocked(false);
  PumpLocked();
}

void ViewSession::Close(uint16_t code, std::string reason) {
  std::vector<render::ViewId> to_close;
  std::vector<TimerQueue::TimerId> timers;
  std::vector<std::string> tokens;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    std::vector<std::shared_ptr<Participant>> everyone = participants_;
    for (const auto& p : everyone) RemoveLocked(p, code, reason, &to_close);
    closed_ = true;
    for (View& view : views_) {
      for (Group& g : view.groups) {
        if (g.render_view != 0) to_close.push_back(g.render_view);
      }
      view.groups.clear();
    }
    for (const Screenshot& shot : screenshots_) to_close.push_back(shot.render_view);
    screenshots_.clear();
    for (auto* timer :
         {&wake_timer_, &dataset_event_timer_, &data_refresh_timer_, &driving_timer_}) {
      if (*timer) timers.push_back(**timer);
      timer->reset();
    }
    for (const Share& share : shares_) tokens.push_back(share.token);
    shares_.clear();
  }
  if (context_.registry != nullptr) {
    for (const std::string& token : tokens) context_.registry->RemoveShare(token);
  }
  // Outside mu_: CloseView waits for a callback of the view, which may be waiting for mu_.
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
  for (TimerQueue::TimerId timer : timers) context_.timers->Cancel(timer);
  dataset::Subscription subscription;
  {
    std::lock_guard<std::mutex> lock(mu_);
    subscription = std::move(dataset_subscription_);
    dataset_.reset();
  }
  subscription.Reset();
}

int64_t ViewSession::WallClock() const {
  return options_.unix_clock ? options_.unix_clock() : SystemUnixNow();
}

GrantVerdict ViewSession::CheckGrant(const protocol::GrantRef& grant,
                                     std::string_view dataset) const {
  if (context_.grants != nullptr) return context_.grants->Check(grant, dataset);
  // No access control (tests of other parts): everything holds, owned by the grant's user.
  const bool user = grant.kind == protocol::GrantRef::Kind::kUser && !grant.id.empty();
  return GrantVerdict{true, "", false,
                      user ? grant : protocol::GrantRef{protocol::GrantRef::Kind::kUser, "anyone"}};
}

void ViewSession::RunStateIo(std::function<void()> job) const {
  // Posted: every save and read gets its answer (none replaces another).
  LatestWinsExecutor* io = context_.state_io != nullptr ? context_.state_io : context_.encoders;
  io->Post(std::move(job));
}

void ViewSession::Revalidate() {
  std::string dataset;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    if (dataset_ != nullptr) dataset = dataset_->dataset().id();
  }
  // 1. The owner's grant: when it ended (or no longer covers the dataset), so does the session.
  const GrantVerdict verdict = CheckGrant(owner_grant_, dataset);
  if (!verdict.holds) {
    Close(kAccessEndedCode, "access ended: " + verdict.reason);
    return;
  }
  // 2. Share links past their expiry end for those who joined through them too.
  std::vector<render::ViewId> to_close;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    const int64_t now = WallClock();
    std::vector<std::string> expired;
    for (const Share& share : shares_) {
      if (share.expires_unix_s && now >= *share.expires_unix_s) expired.push_back(share.token);
    }
    for (const std::string& token : expired) {
      RemoveShareLocked(token, "share link expired", &to_close);
    }
    if (!expired.empty()) SendSharesLocked();
  }
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
}

std::optional<ViewSession::ShareState> ViewSession::share_state(std::string_view id) const {
  std::lock_guard<std::mutex> lock(mu_);
  if (closed_) return std::nullopt;
  const int64_t now = WallClock();
  for (const Share& share : shares_) {
    if (share.id != id) continue;
    if (share.expires_unix_s && now >= *share.expires_unix_s) return std::nullopt;
    return ShareState{share.role, share.dataset, share.expires_unix_s};
  }
  return std::nullopt;
}

void ViewSession::RemoveShareLocked(const std::string& token, const std::string& reason,
                                    std::vector<render::ViewId>* to_close) {
  std::erase_if(shares_, [&](const Share& s) { return s.token == token; });
  if (context_.registry != nullptr) context_.registry->RemoveShare(token);
  std::vector<std::shared_ptr<Participant>> joined;
  for (const auto& p : participants_) {
    if (p->share_token == token) joined.push_back(p);
  }
  for (const auto& p : joined) RemoveLocked(p, 4001, reason, to_close);
}

std::shared_ptr<Participant> ViewSession::FindLocked(std::string_view id) const {
  for (const auto& p : participants_) {
    if (p->id() == id) return p;
  }
  return nullptr;
}

std::shared_ptr<Participant> ViewSession::FindLocked(uint64_t number) const {
  for (const auto& p : participants_) {
    if (p->number() == number) return p;
  }
  return nullptr;
}

void ViewSession::HandleText(std::string_view participant, std::string_view text) {
  std::shared_ptr<Participant> from;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    from = FindLocked(participant);
  }
  if (from == nullptr) return;
  std::string type;
  auto message = protocol::ParseClientMessage(text, &type);
  if (message.ok()) {
    // Acknowledgements are never dropped (a lost one would stall the participant's frames);
    // everything else counts against the participant's message rate.
    if (!std::holds_alternative<protocol::AckMessage>(*message)) {
      bool admitted = true, tell = false;
      {
        std::lock_guard<std::mutex> lock(mu_);
        const auto now = TokenBucket::Clock::now();
        admitted = from->messages.Take(now);
        if (admitted && std::holds_alternative<protocol::HelloMessage>(*message)) {
          admitted = from->hellos.Take(now);
        }
        if (!admitted && now - from->rate_error_sent >= std::chrono::seconds(1)) {
          from->rate_error_sent = now;
          tell = true;
        }
      }
      if (!admitted) {
        if (tell) {
          SendError(*from, "too many messages: " + type + " dropped (slow down)", type, false);
        }
        return;
      }
    }
    OnMessage(from, std::move(*message));
    return;
  }
  bool fatal;
  {
    std::lock_guard<std::mutex> lock(mu_);
    fatal = ++from->malformed > protocol::kMaxMalformedMessages;
  }
  SendError(*from, message.status().message(), type, fatal);
  if (fatal) from->sink().Close(1008, "too many malformed messages");
}

void ViewSession::SendError(Participant& to, std::string_view message, std::string_view request,
                            bool fatal) {
  to.sink().SendText(protocol::ErrorEvent(message, request, fatal));
}

void ViewSession::SendAllLocked(const std::string& text, const Participant* except) {
  for (const auto& p : participants_) {
    if (p.get() != except) p->sink().SendText(text);
  }
}

void ViewSession::SendErrorAllLocked(std::string_view message, std::string_view request) {
  SendAllLocked(protocol::ErrorEvent(message, request, false));
}

void ViewSession::OnMessage(const std::shared_ptr<Participant>& from,
                            protocol::ClientMessage message) {
  const std::string type(protocol::MessageTypeName(message));
  if (auto* hello = std::get_if<protocol::HelloMessage>(&message)) {
    OnHello(from, *hello);
    return;
  }
  if (auto* ping = std::get_if<protocol::PingMessage>(&message)) {
    from->sink().SendText(protocol::PongEvent(ping->t));
    return;
  }
  if (auto* ack = std::get_if<protocol::AckMessage>(&message)) {
    from->outbox().OnAck(ack->frame);
    return;
  }
  if (auto* save = std::get_if<protocol::ViewSaveMessage>(&message)) {
    OnViewSave(from, *save);
    return;
  }
  Role role;
  {
    std::lock_guard<std::mutex> lock(mu_);
    role = from->role;
  }
  if (OwnerOnly(message)) {
    if (role != Role::kOwner) {
      SendError(*from, "only the owner may send " + type, type, false);
      return;
    }
    OnOwnerMessage(from, message);
    return;
  }
  if (role == Role::kViewer && Drives(message)) {
    SendError(*from, kViewersCannotDrive, type, false);
    return;
  }
  if (auto* open = std::get_if<protocol::OpenMessage>(&message)) {
    if (!open->view.empty()) {
      if (context_.views == nullptr) {
        SendError(*from, "view links are not available on this server", type, false);
        return;
      }
      // The stored document is read off the I/O thread.
      RunStateIo([weak = weak_from_this(), from, view = open->view] {
                   auto self = weak.lock();
                   if (self == nullptr) return;
                   auto link = self->context_.views->Load(view);
                   if (!link.ok()) {
                     self->SendError(*from, link.status().message(), "open", false);
                     return;
                   }
                   self->OnOpen(from, link->dataset, link->state, true);
                 });
      return;
    }
    OnOpen(from, open->dataset, open->state, false);
    return;
  }
  std::vector<render::ViewId> to_close;
  std::unique_lock<std::mutex> lock(mu_);
  if (closed_ || from->left) return;
  const auto now = Clock::now();
  if (auto* interaction = std::get_if<protocol::InteractionMessage>(&message)) {
    from->interacting = interaction->active;
    const bool interacting = AnyInteractingLocked();
    if (interacting != interacting_ || interaction->active) {
      interacting_ = interacting;
      for (View& view : views_) {
        for (Group& g : view.groups) g.policy.OnInteraction(interacting, now);
      }
    }
    BroadcastParticipantsLocked(false);
    PumpLocked();
    return;
  }
  if (auto* quality = std::get_if<protocol::QualityMessage>(&message)) {
    ParticipantPreferences& prefs = from->preferences;
    if (quality->jpeg_interactive) prefs.jpeg_interactive = *quality->jpeg_interactive;
    if (quality->jpeg_final) prefs.jpeg_final = *quality->jpeg_final;
    if (quality->lossless_final) prefs.lossless_final = *quality->lossless_final;
    if (quality->lod_bias && *quality->lod_bias != prefs.lod_bias) {
      prefs.lod_bias = *quality->lod_bias;
      for (View& view : views_) RegroupViewLocked(view, now, &to_close);
      PumpLocked();
    }
  } else if (auto* viewport = std::get_if<protocol::ViewportMessage>(&message)) {
    const protocol::PixelSize pixels = protocol::ViewportPixels(*viewport);
    protocol::PixelSize& mine = from->pixels[Index(viewport->view)];
    if (!SameSize(pixels, mine)) {
      mine = pixels;
      RegroupViewLocked(views_[Index(viewport->view)], now, &to_close);
      PumpLocked();
    }
  } else if (!state_ || dataset_ == nullptr) {
    lock.unlock();
    SendError(*from, "no dataset is open (send \"open\" first)", type, false);
    return;
  } else if (auto* camera = std::get_if<protocol::CameraMessage>(&message)) {
    state_->camera = camera->camera;
    ChangedLocked({ViewId::k3d}, from.get());
  } else if (auto* params = std::get_if<protocol::ParamsMessage>(&message)) {
    auto applied = protocol::ApplyParams(params->params_json, state_->params);
    if (!applied.ok()) {
      lock.unlock();
      SendError(*from, applied.status().message(), type, false);
      return;
    }
    state_->params = std::move(*applied);
    auto_contrast_pending_ = false;  // A participant chose its own parameters.
    ChangedLocked({ViewId::k3d, ViewId::kX, ViewId::kY, ViewId::kZ}, from.get());
  } else if (auto* slices = std::get_if<protocol::SlicesMessage>(&message)) {
    const auto clamped = Clamped(slices->position_um, Extent(dataset_->dataset()));
    state_->slice_position_um = clamped;
    ChangedLocked({ViewId::kX, ViewId::kY, ViewId::kZ}, from.get());
    if (clamped != slices->position_um) {
      from->sink().SendText(protocol::StateEvent(*state_, state_version_));
    }
  } else if (auto* shot = std::get_if<protocol::ScreenshotMessage>(&message)) {
    const protocol::PixelSize pixels = from->pixels[Index(shot->view)];
    const auto in_flight = std::count_if(screenshots_.begin(), screenshots_.end(),
                                         [&](const Screenshot& s) { return s.participant == from; });
    if (in_flight >= std::max(1, options_.max_screenshots_in_flight)) {
      lock.unlock();
      SendError(*from,
                "too many screenshots at once (at most " +
                    std::to_string(std::max(1, options_.max_screenshots_in_flight)) +
                    " in flight); wait for one to arrive",
                type, false);
      return;
    }
    const auto key = dataset_->render_key();
    if (!key || pixels.width == 0) {
      lock.unlock();
      SendError(*from,
                key ? "the view has no viewport (send \"viewport\" first)"
                    : "the dataset cannot be rendered yet",
                type, false);
      return;
    }
    const uint32_t id = shot->id;
    auto render_view = context_.renderer->OpenView(
        *key, [weak = weak_from_this(), id, number = from->number()](render::FrameResult result) {
          if (auto self = weak.lock()) self->OnScreenshotResult(id, number, std::move(result));
        });
    if (!render_view.ok()) {
      lock.unlock();
      SendError(*from, render_view.status().message(), type, false);
      return;
    }
    FrameOrder order{1, true, static_cast<double>(shot->scale), 0, true};
    FramePolicy policy(context_.frame_policy);
    auto request = RequestLocked(shot->view, pixels, from->preferences.lod_bias, policy, order);
    Status submitted = request.ok() ? Status::Ok() : request.status();
    if (request.ok()) {
      request->progress_images = false;
      screenshots_.push_back({id, shot->view, *render_view, state_version_, from});
      submitted = context_.renderer->Submit(*render_view, std::move(*request));
    }
    if (!submitted.ok()) {
      std::erase_if(screenshots_,
                    [&](const Screenshot& s) { return s.id == id && s.participant == from; });
      lock.unlock();
      context_.renderer->CloseView(*render_view);
      SendError(*from, submitted.message(), type, false);
    }
    return;
  }
  lock.unlock();
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
}

std::string ViewSession::dataset_id() const {
  std::lock_guard<std::mutex> lock(mu_);
  return dataset_ != nullptr ? dataset_->dataset().id() : std::string();
}

void ViewSession::OnHello(const std::shared_ptr<Participant>& from,
                          const protocol::HelloMessage& hello) {
  std::optional<protocol::ViewLink> pending;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_ || from->left) return;
    if (!hello.name.empty()) from->name = hello.name;
    from->welcomed = true;
    from->sink().SendText(protocol::WelcomeEvent(
        context_.server_version, id_, from->id(), from->role,
        from->role == Role::kOwner ? std::string_view(resume_key_) : std::string_view()));
    if (state_ && dataset_ != nullptr) {
      from->sink().SendText(protocol::OpenedEvent(DatasetJsonLocked(), *state_, state_version_));
    }
    if (from->role == Role::kOwner) SendSharesLocked();
    BroadcastParticipantsLocked(true);
    if (pending_view_ && pending_view_->first == from->id()) {
      pending = std::move(pending_view_->second);
      pending_view_.reset();
    }
  }
  if (pending) OnOpen(from, pending->dataset, pending->state, true);
}

void ViewSession::OpenViewLink(std::string_view participant, protocol::ViewLink link) {
  std::shared_ptr<Participant> from;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    from = FindLocked(participant);
    if (from == nullptr) return;
    if (!from->welcomed) {
      // Opened right after the welcome, so that the client sees `welcome` first.
      pending_view_.emplace(from->id(), std::move(link));
      return;
    }
  }
  OnOpen(from, link.dataset, link.state, true);
}

void ViewSession::OnOwnerMessage(const std::shared_ptr<Participant>& from,
                                 const protocol::ClientMessage& message) {
  const std::string type(protocol::MessageTypeName(message));
  std::optional<GrantVerdict> share_verdict;
  if (std::holds_alternative<protocol::ShareCreateMessage>(message)) {
    // Asked before the lock: the checker may look up share links, which asks their session.
    share_verdict = CheckGrant(owner_grant_, "");
  }
  std::vector<render::ViewId> to_close;
  std::unique_lock<std::mutex> lock(mu_);
  if (closed_ || from->left) return;
  if (auto* create = std::get_if<protocol::ShareCreateMessage>(&message)) {
    if (context_.registry == nullptr) {
      lock.unlock();
      SendError(*from, "share links are not available on this server", type, false);
      return;
    }
    // A link never grants more than its maker's own access: a session opened through a link
    // that a guest made cannot be shared on.
    if (!share_verdict->holds || share_verdict->via_share) {
      lock.unlock();
      SendError(*from,
                !share_verdict->holds
                    ? "cannot share: " + share_verdict->reason
                    : std::string("this session rests on a share link; it cannot be shared further"),
                type, false);
      return;
    }
    auto token = RandomHex(16);
    auto id = RandomHex(8);
    if (!token.ok() || !id.ok()) {
      lock.unlock();
      SendError(*from, (token.ok() ? id.status() : token.status()).message(), type, false);
      return;
    }
    Share share{*token, *id, create->role, std::nullopt,
                dataset_ != nullptr ? dataset_->dataset().id() : std::string()};
    std::optional<std::chrono::system_clock::time_point> expires;
    if (create->ttl_s) {
      share.expires_unix_s = WallClock() + *create->ttl_s;
      expires = std::chrono::system_clock::time_point(std::chrono::seconds(*share.expires_unix_s));
    }
    context_.registry->AddShare(share.token, share.id, weak_from_this(), share.role, expires);
    shares_.push_back(share);
    from->sink().SendText(protocol::ShareCreatedEvent(
        {share.token, share.role, LinkUrl("share", share.token), share.expires_unix_s, 0}));
    SendSharesLocked();
    return;
  }
  if (auto* revoke = std::get_if<protocol::ShareRevokeMessage>(&message)) {
    auto it = std::find_if(shares_.begin(), shares_.end(),
                           [&](const Share& s) { return s.token == revoke->token; });
    if (it == shares_.end()) {
      lock.unlock();
      SendError(*from, "no such share link in this session", type, false);
      return;
    }
    const std::string token = it->token;
    RemoveShareLocked(token, "share link revoked", &to_close);
    SendSharesLocked();
  } else if (auto* change = std::get_if<protocol::ParticipantRoleMessage>(&message)) {
    auto target = FindLocked(std::string_view(change->participant));
    if (target == nullptr || target->role == Role::kOwner) {
      lock.unlock();
      SendError(*from,
                target == nullptr ? "no participant \"" + change->participant + "\""
                                  : std::string("the owner's role cannot change"),
                type, false);
      return;
    }
    target->role = change->role;
    if (change->role == Role::kViewer && target->interacting) {
      target->interacting = false;
      const bool interacting = AnyInteractingLocked();
      if (interacting != interacting_) {
        interacting_ = interacting;
        const auto now = Clock::now();
        for (View& view : views_) {
          for (Group& g : view.groups) g.policy.OnInteraction(interacting, now);
        }
      }
    }
    BroadcastParticipantsLocked(true);
    PumpLocked();
  } else if (auto* kick = std::get_if<protocol::KickMessage>(&message)) {
    auto target = FindLocked(std::string_view(kick->participant));
    if (target == nullptr || target == from) {
      lock.unlock();
      SendError(*from,
                target == nullptr ? "no participant \"" + kick->participant + "\""
                                  : std::string("the owner cannot remove itself"),
                type, false);
      return;
    }
    RemoveLocked(target, 4003, "removed from the session", &to_close);
    SendSharesLocked();
  }
  lock.unlock();
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
}

void ViewSession::OnViewSave(const std::shared_ptr<Participant>& from,
                             const protocol::ViewSaveMessage& message) {
  std::string dataset_id;
  std::optional<protocol::ViewState> state;
  protocol::GrantRef grant;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_ || from->left) return;
    if (!state_ || dataset_ == nullptr) {
      SendError(*from, "no dataset is open (send \"open\" first)", "view_save", false);
      return;
    }
    dataset_id = dataset_->dataset().id();
    state = *state_;
    grant = from->grant;
  }
  if (context_.views == nullptr) {
    SendError(*from, "view links are not available on this server", "view_save", false);
    return;
  }
  // The link rests on the grant of the participant who saves it, and counts against the user at
  // the root of that grant.
  const GrantVerdict verdict = CheckGrant(grant, dataset_id);
  if (!verdict.holds) {
    SendError(*from, "cannot save a view link: " + verdict.reason, "view_save", false);
    return;
  }
  if (context_.admit_view_link) {
    if (Status admitted = context_.admit_view_link(verdict.owner); !admitted.ok()) {
      SendError(*from, admitted.message(), "view_save", false);
      return;
    }
  }
  const int64_t now = WallClock();
  protocol::ViewLinkGrant link{grant, verdict.owner, now, std::nullopt};
  if (message.ttl_s) link.expires_unix_s = now + *message.ttl_s;
  // The durable write (fsync) runs off the I/O thread, and off the frame encoders.
  RunStateIo([weak = weak_from_this(), from, dataset_id, state = std::move(state), link] {
               auto self = weak.lock();
               if (self == nullptr) return;
               auto id = self->context_.views->Save(dataset_id, *state, link);
               if (!id.ok()) {
                 self->SendError(*from, id.status().message(), "view_save", false);
                 return;
               }
               from->sink().SendText(protocol::ViewSavedEvent(*id, self->LinkUrl("view", *id),
                                                              link.expires_unix_s));
             });
}

std::string ViewSession::LinkUrl(std::string_view key, std::string_view value) const {
  const std::string base = context_.link_base != nullptr ? context_.link_base->Get() : "/";
  return base + "?" + std::string(key) + "=" + std::string(value);
}

void ViewSession::SendSharesLocked() {
  std::vector<protocol::ShareInfo> infos;
  for (const Share& share : shares_) {
    int joined = 0;
    for (const auto& p : participants_) joined += p->share_token == share.token;
    infos.push_back(
        {share.token, share.role, LinkUrl("share", share.token), share.expires_unix_s, joined});
  }
  const std::string text = protocol::SharesEvent(infos);
  for (const auto& p : participants_) {
    if (p->role == Role::kOwner && p->welcomed) p->sink().SendText(text);
  }
}

std::vector<protocol::ParticipantInfo> ViewSession::ParticipantsLocked(
    Clock::time_point now) const {
  std::vector<protocol::ParticipantInfo> infos;
  for (const auto& p : participants_) {
    const bool recent = last_changer_ == p->number() && now - last_change_ < options_.driving_hold;
    infos.push_back({p->id(), p->name, p->role, p->interacting || recent});
  }
  return infos;
}

void ViewSession::BroadcastParticipantsLocked(bool force) {
  const auto now = Clock::now();
  const auto infos = ParticipantsLocked(now);
  std::vector<std::string> summary;
  for (const auto& i : infos) {
    summary.push_back(i.id + ":" + std::string(protocol::RoleName(i.role)) + ":" + i.name +
                      (i.driving ? ":1" : ":0"));
  }
  if (!force && summary == last_participants_sent_) return;
  last_participants_sent_ = summary;
  for (const auto& p : participants_) {
    if (p->welcomed) p->sink().SendText(protocol::ParticipantsEvent(infos, p->id()));
  }
}

void ViewSession::MarkDrivingLocked(Participant* from) {
  if (from == nullptr) return;
  last_changer_ = from->number();
  last_change_ = Clock::now();
  BroadcastParticipantsLocked(false);
  // When the hold ends the marker goes (unless the participant keeps changing the state).
  if (driving_timer_) {
    context_.timers->Cancel(*driving_timer_);
    driving_timer_.reset();
  }
  ArmTimerLocked(&driving_timer_,
                 last_change_ + options_.driving_hold + std::chrono::milliseconds(10),
                 [](ViewSession& s) { s.BroadcastParticipantsLocked(false); });
}

void ViewSession::OnOpen(const std::shared_ptr<Participant>& from, const std::string& dataset_id,
                         const std::optional<protocol::StateUpdate>& update, bool exact) {
  protocol::GrantRef grant;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_ || from->left) return;
    grant = from->grant;
  }
  // Only what the participant's grant covers (a share link: the dataset it was made for); any
  // other dataset is answered like one that does not exist.
  if (!CheckGrant(grant, dataset_id).holds) {
    SendError(*from, "no dataset '" + dataset_id + "'", "open", false);
    return;
  }
  auto use = context_.datasets->Use(dataset_id);
  if (!use.ok()) {
    SendError(*from, use.status().message(), "open", false);
    return;
  }
  const dataset::Dataset& dataset = (*use)->dataset();
  const volume::VolumeInfo& info = dataset.info();
  const auto spacing = dataset.spacing_um();
  const dataset::Histogram histogram = dataset.histogram();
  const render::Box3 bounds =
      render::PhysicalBounds(info.size, render::Vec3{spacing[0], spacing[1], spacing[2]});

  // The dataset's defaults (docs/protocol.md "State document"), then what the client sent.
  auto camera = render::Camera::Standard(render::StandardView::kIso,
                                         render::Projection::kPerspective, bounds, 1, 1);
  if (!camera.ok()) {
    SendError(*from, camera.status().message(), "open", false);
    return;
  }
  protocol::ViewState state{*camera,
                            dataset::DefaultDisplayParams(info, volume::StoredTypeFor(info.dtype),
                                                          &histogram, render::RenderMode::kMip),
                            {},
                            std::nullopt};
  const auto extent = Extent(dataset);
  state.slice_position_um = {extent[0] / 2, extent[1] / 2, extent[2] / 2};
  bool client_params = false;
  if (update) {
    if (update->camera) state.camera = *update->camera;
    if (update->params_json) {
      auto params = protocol::ApplyParams(*update->params_json, state.params);
      if (!params.ok()) {
        SendError(*from, "state.params: " + params.status().message(), "open", false);
        return;
      }
      state.params = std::move(*params);
      client_params = true;
    }
    if (update->slice_position_um) {
      state.slice_position_um = Clamped(*update->slice_position_um, extent);
    }
    if (update->layout) state.maximized = update->layout->maximized;
  }
  (void)exact;  // A view link holds every part: the state above is exactly the stored one.

  std::vector<render::ViewId> to_close;
  dataset::Subscription old_subscription;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_ || from->left) return;
    if (from->role == Role::kViewer) {
      // Demoted while the view link was being read.
      SendError(*from, kViewersCannotDrive, "open", false);
      return;
    }
    for (View& view : views_) {
      for (Group& g : view.groups) {
        if (g.render_view != 0) to_close.push_back(g.render_view);
        g.render_view = 0;
      }
    }
    // Share links admit to the dataset they were made for: those made for another one end here.
    std::vector<std::string> other_dataset;
    bool scoped = false;
    for (Share& share : shares_) {
      if (share.dataset.empty()) {
        share.dataset = dataset_id;
        scoped = true;
      } else if (share.dataset != dataset_id) {
        other_dataset.push_back(share.token);
      }
    }
    for (const std::string& token : other_dataset) {
      RemoveShareLocked(token, "share link revoked: the session opened another dataset", &to_close);
    }
    if (scoped || !other_dataset.empty()) SendSharesLocked();
    old_subscription = std::move(dataset_subscription_);
    dataset_ = *use;
    state_ = std::move(state);
    auto_contrast_pending_ = !client_params && !dataset.status().histogram_complete;
    seen_planes_ = dataset.status().planes_inserted;
    ++state_version_;
    const std::string opened = protocol::OpenedEvent(DatasetJsonLocked(), *state_, state_version_);
    for (const auto& p : participants_) {
      if (p->welcomed || p == from) p->sink().SendText(opened);
    }
    const auto now = Clock::now();
    for (View& view : views_) {
      ++view.content_version;
      for (Group& g : view.groups) g.policy.OnChange(view.content_version, now);
    }
    MarkDrivingLocked(from.get());
    AttachRenderViewsLocked();
    PumpLocked();
  }
  old_subscription.Reset();
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
  // Subscribed last: the callback takes mu_.
  auto subscription = (*use)->dataset().OnChange([weak = weak_from_this()] {
    if (auto self = weak.lock()) self->OnDatasetChange();
  });
  std::lock_guard<std::mutex> lock(mu_);
  if (!closed_ && dataset_ == *use) dataset_subscription_ = std::move(subscription);
}

void ViewSession::ChangedLocked(std::initializer_list<ViewId> views, Participant* from) {
  ++state_version_;
  const auto now = Clock::now();
  for (ViewId v : views) {
    View& view = views_[Index(v)];
    ++view.content_version;
    for (Group& g : view.groups) g.policy.OnChange(view.content_version, now);
  }
  // The others follow: their UI shows the new state.
  const std::string event =
      protocol::StateEvent(*state_, state_version_, from != nullptr ? from->id() : "");
  for (const auto& p : participants_) {
    if (p.get() != from && p->welcomed) p->sink().SendText(event);
  }
  MarkDrivingLocked(from);
  PumpLocked();
}

bool ViewSession::AnyInteractingLocked() const {
  return std::any_of(participants_.begin(), participants_.end(),
                     [](const auto& p) { return p->interacting && p->role != Role::kViewer; });
}

void ViewSession::RegroupViewLocked(View& view, Clock::time_point now,
                                    std::vector<render::ViewId>* to_close) {
  std::vector<GroupMember> members;
  for (const auto& p : participants_) {
    const protocol::PixelSize pixels = p->pixels[Index(view.id)];
    if (pixels.width > 0) members.push_back({p->number(), pixels, p->preferences.lod_bias});
  }
  const std::vector<AspectGroup> wanted = GroupByAspect(std::move(members));
  std::vector<Group> old = std::move(view.groups);
  view.groups.clear();
  std::vector<bool> used(old.size(), false);
  for (const AspectGroup& w : wanted) {
    // Keep the render view and frame policy of a group of the same aspect and bias.
    size_t match = old.size();
    for (size_t i = 0; i < old.size(); ++i) {
      if (!used[i] && old[i].lod_bias == w.lod_bias && SameAspect(old[i].pixels, w.pixels)) {
        match = i;
        break;
      }
    }
    Group group;
    if (match < old.size()) {
      used[match] = true;
      group = std::move(old[match]);
      // A new size or a new member: a new frame is due even without a change.
      if (!SameSize(group.pixels, w.pixels) || group.members != w.members) {
        group.policy.Invalidate(now);
      }
    } else {
      group.key = next_group_key_++;
      group.policy = FramePolicy(context_.frame_policy);
      if (view.content_version > 0) group.policy.OnChange(view.content_version, now);
      if (interacting_) group.policy.OnInteraction(true, now);
    }
    group.pixels = w.pixels;
    group.lod_bias = w.lod_bias;
    group.members = w.members;
    view.groups.push_back(std::move(group));
  }
  for (size_t i = 0; i < old.size(); ++i) {
    if (!used[i] && old[i].render_view != 0) to_close->push_back(old[i].render_view);
  }
  AttachRenderViewsLocked();
}

void ViewSession::AttachRenderViewsLocked() {
  if (dataset_ == nullptr || closed_) return;
  bool missing = false;
  for (const View& view : views_) {
    for (const Group& g : view.groups) missing |= g.render_view == 0;
  }
  if (!missing) return;
  const auto key = dataset_->render_key();
  if (!key) return;
  for (View& view : views_) {
    for (Group& g : view.groups) {
      if (g.render_view != 0) continue;
      auto opened = context_.renderer->OpenView(
          *key, [weak = weak_from_this(), v = view.id, group = g.key](render::FrameResult result) {
            if (auto self = weak.lock()) self->OnRenderResult(v, group, std::move(result));
          });
      if (!opened.ok()) {
        SendErrorAllLocked(opened.status().message(), "open");
        return;
      }
      g.render_view = *opened;
      g.policy.Invalidate(Clock::now());
    }
  }
}

ViewSession::Group* ViewSession::FindGroupLocked(ViewId view, uint64_t key) {
  for (Group& g : views_[Index(view)].groups) {
    if (g.key == key) return &g;
  }
  return nullptr;
}

void ViewSession::PumpLocked() {
  if (closed_ || !state_) return;
  const auto now = Clock::now();
  std::optional<Clock::time_point> earliest;
  for (View& view : views_) {
    for (Group& g : view.groups) {
      if (g.render_view == 0 || g.pixels.width == 0) continue;
      std::optional<Clock::time_point> wake;
      PumpGroupLocked(view, g, now, &wake);
      if (wake && (!earliest || *wake < *earliest)) earliest = wake;
    }
  }
  if (earliest) {
    ArmTimerLocked(&wake_timer_, *earliest, [](ViewSession& s) { s.PumpLocked(); });
  }
}

void ViewSession::PumpGroupLocked(View& view, Group& group, Clock::time_point now,
                                  std::optional<Clock::time_point>* wake) {
  auto order = group.policy.Poll(now, wake);
  if (!order) return;
  auto request = RequestLocked(view.id, group.pixels, group.lod_bias, group.policy, *order);
  Status status = request.ok() ? Status::Ok() : request.status();
  if (request.ok()) {
    group.order_sequence = order->sequence;
    group.order_frame_sequence = ++frame_sequence_;
    group.order_state_version = state_version_;
    group.order_refine = order->refine;
    group.order_submitted = now;
    status = context_.renderer->Submit(group.render_view, std::move(*request));
  }
  if (!status.ok()) {
    group.policy.OnFrameDone(order->sequence, false, 0);
    SendErrorAllLocked(status.message(), "render");
  }
}

Result<render::FrameRequest> ViewSession::RequestLocked(ViewId view, protocol::PixelSize pixels,
                                                        double lod_bias, const FramePolicy& policy,
                                                        const FrameOrder& order) const {
  const int width = std::max(1, static_cast<int>(std::lround(pixels.width * order.scale)));
  const int height = std::max(1, static_cast<int>(std::lround(pixels.height * order.scale)));
  render::FrameRequest request;
  request.params = state_->params;
  request.sequence = order.sequence;
  render::FrameOptions options;
  options.mode = order.refine ? render::FrameMode::kRefine : render::FrameMode::kFullFrame;
  options.lod_bias = lod_bias;
  options.lod_view_spacing = order.lod_view_spacing;
  // Interactive frames shrink first (FramePolicy); once at the smallest scale, the renderer
  // coarsens the level of detail to hold the frame time.
  if (!order.refine && policy.scale() <= context_.frame_policy.min_scale) {
    options.target_frame_ms = context_.frame_policy.target_frame_ms;
  }
  request.options = options;
  if (view == ViewId::k3d) {
    request.kind = render::FrameKind::kVolume;
    auto camera = protocol::CameraForSize(state_->camera, width, height);
    if (!camera.ok()) return camera.status();
    request.camera = *camera;
  } else {
    request.kind = render::FrameKind::kSlice;
    render::SliceView slice;
    slice.axis = static_cast<int>(view) - 1;
    slice.position_um = state_->slice_position_um[slice.axis];
    slice.width = width;
    slice.height = height;
    request.slice = slice;
  }
  return request;
}

void ViewSession::OnRenderResult(ViewId v, uint64_t group_key, render::FrameResult result) {
  std::vector<EncodeJob> jobs;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    Group* group = FindGroupLocked(v, group_key);
    if (group == nullptr || result.view != group->render_view ||
        result.sequence != group->order_sequence) {
      return;
    }
    if (!result.status.ok()) {
      if (result.final) group->policy.OnFrameDone(result.sequence, false, 0);
      SendErrorAllLocked(result.status.message(), "render");
      PumpLocked();
      return;
    }
    const auto tier = !group->order_refine ? protocol::FrameTier::kInteractive
                      : result.final       ? protocol::FrameTier::kFinal
                                           : protocol::FrameTier::kRefining;
    // The policy holds the frame rate the user sees: submit to result, so that the time a frame
    // waits for other views' frames on the shared device counts too (N busy clients each shrink
    // their frames instead of each waiting N times longer).
    if (result.final) {
      group->policy.OnFrameDone(result.sequence, true,
                                std::max(result.stats.ms_total, Elapsed(group->order_submitted)));
    }
    if (context_.metrics != nullptr) {
      context_.metrics->Rendered(tier, result.stats.ms_total, result.stats.bricks_uploaded);
    }
    bricks_pending_ = result.stats.bricks_unavailable;
    const auto now = Clock::now();
    bool send = true;
    if (tier == protocol::FrameTier::kRefining) {
      // Progress frames at most every progress_interval: the final one is what matters.
      send = now - group->last_progress >= options_.progress_interval;
      if (send) group->last_progress = now;
    }
    // Copied before PumpLocked may submit the group's next order.
    const uint64_t frame_sequence = group->order_frame_sequence;
    const uint64_t state_version = group->order_state_version;
    const bool refine = group->order_refine;
    const protocol::PixelSize group_pixels = group->pixels;
    const std::vector<uint64_t> members = group->members;
    PumpLocked();
    if (!send || result.image.width <= 0 || result.image.height <= 0) return;
    protocol::FrameHeader header;
    header.state_version = state_version;
    header.view = v;
    header.tier = tier;
    header.final = tier == protocol::FrameTier::kFinal;
    header.progress =
        refine ? static_cast<float>(std::clamp(result.stats.finished_fraction, 0.0, 1.0)) : 0.f;
    if (header.final) header.progress = 1.f;
    header.render_ms = static_cast<float>(std::max(0.0, result.stats.ms_total));
    header.lod_bias = static_cast<float>(result.stats.lod_bias_used);
    auto image = std::make_shared<const render::RenderImage>(std::move(result.image));
    const protocol::PixelSize rendered{image->width, image->height};
    // One encoding per distinct (size, format, quality) among the members.
    for (uint64_t number : members) {
      auto p = FindLocked(number);
      if (p == nullptr) continue;
      const protocol::PixelSize size = MemberFrameSize(p->pixels[Index(v)], group_pixels, rendered);
      const bool png = tier == protocol::FrameTier::kFinal && p->preferences.lossless_final;
      const int quality = tier == protocol::FrameTier::kInteractive
                              ? p->preferences.jpeg_interactive
                          : tier == protocol::FrameTier::kRefining ? options_.jpeg_refining
                                                                   : p->preferences.jpeg_final;
      auto same = std::find_if(jobs.begin(), jobs.end(), [&](const EncodeJob& j) {
        return SameSize(j.size, size) && j.png == png && (png || j.jpeg_quality == quality);
      });
      if (same == jobs.end()) {
        EncodeJob job;
        job.outbox_view = static_cast<int>(v);
        job.sequence = frame_sequence;
        job.header = header;
        job.png = png;
        job.jpeg_quality = quality;
        job.size = size;
        job.image = image;
        jobs.push_back(std::move(job));
        same = jobs.end() - 1;
      }
      same->recipients.push_back(std::move(p));
    }
  }
  for (EncodeJob& job : jobs) SubmitEncode(std::move(job));
}

void ViewSession::SubmitEncode(EncodeJob job) {
  // Latest image wins per (first recipient, outbox view): a newer frame of the view replaces one
  // still waiting for an encoder.
  const uint64_t key = reinterpret_cast<uintptr_t>(job.recipients.front().get()) + job.outbox_view;
  context_.encoders->Submit(key, [weak = weak_from_this(), job = std::move(job)]() mutable {
    if (auto self = weak.lock()) self->Encode(std::move(job));
  });
}

void ViewSession::OnScreenshotResult(uint32_t id, uint64_t participant,
                                     render::FrameResult result) {
  if (!result.final) return;
  EncodeJob job;
  render::ViewId render_view = 0;
  std::shared_ptr<Participant> to;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    auto it = std::find_if(screenshots_.begin(), screenshots_.end(), [&](const Screenshot& s) {
      return s.id == id && s.participant->number() == participant;
    });
    if (it == screenshots_.end()) return;
    const Screenshot shot = *it;
    screenshots_.erase(it);
    render_view = shot.render_view;
    to = shot.participant;
    if (result.status.ok() && result.image.width > 0) {
      job.outbox_view = kScreenshotViewBase + static_cast<int>(id % kScreenshotViewCount);
      job.sequence = ++screenshot_sequence_;
      job.png = true;
      protocol::FrameHeader& header = job.header;
      header.state_version = shot.state_version;
      header.view = shot.view;
      header.tier = protocol::FrameTier::kScreenshot;
      header.final = true;
      header.progress = 1.f;
      header.render_ms = static_cast<float>(std::max(0.0, result.stats.ms_total));
      header.lod_bias = static_cast<float>(result.stats.lod_bias_used);
      header.screenshot_id = id;
      job.size = {result.image.width, result.image.height};
      job.image = std::make_shared<const render::RenderImage>(std::move(result.image));
      job.recipients.push_back(to);
      if (context_.metrics != nullptr) {
        context_.metrics->Rendered(protocol::FrameTier::kScreenshot, result.stats.ms_total,
                                   result.stats.bricks_uploaded);
      }
    }
  }
  // From the view's own callback CloseView does not wait.
  context_.renderer->CloseView(render_view);
  if (!result.status.ok()) {
    SendError(*to, "screenshot " + std::to_string(id) + ": " + result.status.message(),
              "screenshot", false);
    return;
  }
  SubmitEncode(std::move(job));
}

void ViewSession::Encode(EncodeJob job) {
  const auto start = Clock::now();
  // Smaller participants of the group: the render area-averaged down to their size.
  std::optional<render::RenderImage> resampled;
  const render::RenderImage* source = job.image.get();
  if (!SameSize(job.size, {source->width, source->height})) {
    resampled = render::AreaResample(*source, job.size.width, job.size.height);
    source = &*resampled;
  }
  std::vector<uint8_t> png;  // Owns PNG bytes; JPEG bytes live in the leased encoder.
  std::optional<encode::JpegEncoderPool::Lease> encoder;
  Result<std::span<const uint8_t>> image = InternalError("not encoded");
  if (job.png) {
    // The pixels as shown (over black), opaque: exactly what the JPEG frames approximate.
    encode::Rgba8Image rgba = encode::ToRgba8(source->rgba.data(), source->width, source->height,
                                              encode::AlphaMode::kOverBlack);
    for (size_t i = 3; i < rgba.pixels.size(); i += 4) rgba.pixels[i] = 255;
    auto encoded = encode::EncodePng(rgba);
    if (encoded.ok()) png = std::move(*encoded);
    image = encoded.ok() ? Result<std::span<const uint8_t>>(std::span<const uint8_t>(png))
                         : Result<std::span<const uint8_t>>(encoded.status());
  } else {
    auto lease = context_.jpeg->Acquire();
    if (!lease.ok()) {
      image = lease.status();
    } else {
      encoder.emplace(std::move(*lease));
      // Final frames get the exact DCT; interactive and progress frames the fast one.
      image = (*encoder)->Encode(source->rgba.data(), source->width, source->height,
                                 job.jpeg_quality, job.header.final);
    }
  }
  if (!image.ok()) {
    for (const auto& p : job.recipients) {
      SendError(*p, "encoding a frame: " + image.status().message(), "render", false);
    }
    return;
  }
  const double encode_ms = Elapsed(start);
  protocol::FrameHeader header = job.header;
  header.format = job.png ? protocol::ImageFormat::kPng : protocol::ImageFormat::kJpeg;
  header.lossless = job.png;
  header.width = static_cast<uint16_t>(source->width);
  header.height = static_cast<uint16_t>(source->height);
  header.encode_ms = static_cast<float>(encode_ms);
  auto message = protocol::BuildFrameMessage(header, *image);
  if (!message.ok()) {
    for (const auto& p : job.recipients) {
      SendError(*p, "framing: " + message.status().message(), "render", false);
    }
    return;
  }
  if (context_.metrics != nullptr) context_.metrics->Encoded(header.format, encode_ms);
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    for (const auto& p : job.recipients) {
      if (p->left || p->stats_timer) continue;
      p->stats_timer = context_.timers->Schedule(Clock::now() + options_.stats_interval,
                                                 [weak = weak_from_this(), p] {
                                                   auto self = weak.lock();
                                                   if (self == nullptr) return;
                                                   std::lock_guard<std::mutex> lock(self->mu_);
                                                   p->stats_timer.reset();
                                                   if (!self->closed_ && !p->left)
                                                     self->SendStatsLocked(p);
                                                 });
    }
  }
  // Each recipient gets its own copy: the outbox writes the participant's frame id into it.
  for (size_t i = 0; i < job.recipients.size(); ++i) {
    std::vector<uint8_t> bytes =
        i + 1 == job.recipients.size() ? std::move(*message) : std::vector<uint8_t>(*message);
    job.recipients[i]->outbox().Offer(
        OutgoingFrame{job.outbox_view, job.sequence, header.final, std::move(bytes)});
  }
}

void ViewSession::OnDatasetChange() {
  std::lock_guard<std::mutex> lock(mu_);
  if (closed_ || dataset_ == nullptr) return;
  AttachRenderViewsLocked();
  const auto now = Clock::now();
  ArmTimerLocked(&dataset_event_timer_, now + options_.dataset_event_interval,
                 [](ViewSession& s) { s.SendDatasetEventLocked(); });
  if (dataset_->dataset().status().planes_inserted != seen_planes_) {
    ArmTimerLocked(&data_refresh_timer_, now + options_.data_refresh_interval,
                   [](ViewSession& s) { s.RefreshDataLocked(); });
  }
  PumpLocked();
}

void ViewSession::SendDatasetEventLocked() {
  if (dataset_ == nullptr) return;
  SendAllLocked(protocol::DatasetEvent(DatasetJsonLocked()));
}

void ViewSession::RefreshDataLocked() {
  if (dataset_ == nullptr || !state_) return;
  const dataset::DatasetStatus status = dataset_->dataset().status();
  seen_planes_ = status.planes_inserted;
  if (auto_contrast_pending_) {
    // The histogram grows with the data: keep the opening auto-contrast up to date until a
    // participant sets its own parameters or every voxel is counted.
    const dataset::Histogram histogram = dataset_->dataset().histogram();
    bool changed = false;
    for (int c = 0;
         c < histogram.channels() && c < static_cast<int>(state_->params.channels.size()); ++c) {
      const render::ChannelParams before = state_->params.channels[c];
      if (dataset::AutoContrast(histogram, c, state_->params.channels[c])) {
        changed |= before.window != state_->params.channels[c].window ||
                   before.level != state_->params.channels[c].level;
      }
    }
    auto_contrast_pending_ = !status.histogram_complete;
    if (changed) {
      ++state_version_;
      SendAllLocked(protocol::StateEvent(*state_, state_version_));
      const auto now = Clock::now();
      for (View& view : views_) {
        ++view.content_version;
        for (Group& g : view.groups) g.policy.OnChange(view.content_version, now);
      }
      PumpLocked();
      return;
    }
  }
  for (View& view : views_) {
    ++view.content_version;
    for (Group& g : view.groups) g.policy.OnDataChange(view.content_version);
  }
  PumpLocked();
}

void ViewSession::SendStatsLocked(const std::shared_ptr<Participant>& p) {
  const OutboxStats stats = p->outbox().stats();
  if (context_.metrics != nullptr && stats.dropped > p->last_stats.dropped) {
    context_.metrics->FramesDropped(stats.dropped - p->last_stats.dropped);
  }
  if (stats.sent == p->last_stats.sent && stats.dropped == p->last_stats.dropped) return;
  p->last_stats = stats;
  p->sink().SendText(
      protocol::StatsEvent({stats.sent, stats.dropped, stats.bytes_sent, bricks_pending_}));
}

void ViewSession::ArmTimerLocked(std::optional<TimerQueue::TimerId>* timer, Clock::time_point when,
                                 void (*fire)(ViewSession&)) {
  if (*timer) return;  // Armed: it fires no later than a new one would matter.
  *timer = context_.timers->Schedule(when, [weak = weak_from_this(), timer, fire] {
    auto self = weak.lock();
    if (self == nullptr) return;
    std::lock_guard<std::mutex> lock(self->mu_);
    timer->reset();
    if (!self->closed_) fire(*self);
  });
}

std::string ViewSession::DatasetJsonLocked() const {
  return protocol::DatasetJson(dataset::Describe(dataset_->dataset()));
}

}  // namespace octoscope::session
