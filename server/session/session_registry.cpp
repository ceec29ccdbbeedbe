#include "session/session_registry.h"

#include <algorithm>
#include <utility>

#include "util/durable_file.h"
#include "util/random_token.h"

namespace octoscope::session {
namespace {

std::string RandomOr(int bytes, std::string fallback) {
  auto token = RandomHex(bytes);
  return token.ok() ? *token : std::move(fallback);
}

}  // namespace

bool SecretsEqual(std::string_view a, std::string_view b) {
  // Every byte is looked at whatever differs; only the lengths (not secret) exit early.
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    diff |= static_cast<unsigned char>(a[i]) ^ static_cast<unsigned char>(b[i]);
  }
  return diff == 0;
}

SessionRegistry::SessionRegistry(TimerQueue* timers, SessionLimits limits)
    : timers_(timers), limits_(limits) {
  auto salt = RandomHex(8);
  salt_ = salt.ok() ? Fnv1a64(*salt) : Fnv1a64("octoscope");
  std::lock_guard<std::mutex> lock(mu_);
  ScheduleSweepLocked();
  ScheduleRevalidateLocked();
}

SessionRegistry::~SessionRegistry() {
  std::map<std::string, std::shared_ptr<ViewSession>> sessions;
  {
    std::unique_lock<std::mutex> lock(mu_);
    stopping_ = true;
    if (sweep_timer_ && timers_->Cancel(*sweep_timer_)) sweep_timer_.reset();
    if (revalidate_timer_ && timers_->Cancel(*revalidate_timer_)) revalidate_timer_.reset();
    // A sweep that started (or is about to) finishes, and touches the registry no more.
    sweeping_cv_.wait(lock,
                      [&] { return !sweep_timer_ && !revalidate_timer_ && running_timers_ == 0; });
    sessions.swap(sessions_);
    by_resume_.clear();
    shares_.clear();
  }
  for (auto& [id, session] : sessions) session->Close(1001, "server shutting down");
}

uint64_t SessionRegistry::Digest(std::string_view secret) const { return Fnv1a64(secret, salt_); }

void SessionRegistry::ScheduleSweepLocked() {
  // A few sweeps per idle timeout, at most every 5 s and at least every 50 ms.
  const auto period = std::clamp<std::chrono::milliseconds>(
      limits_.idle_timeout / 4, std::chrono::milliseconds(50), std::chrono::milliseconds(5000));
  SchedulePeriodicLocked(&sweep_timer_, period, &SessionRegistry::ReleaseIdle);
}

void SessionRegistry::ScheduleRevalidateLocked() {
  const auto period = std::max(limits_.revalidate_interval, std::chrono::milliseconds(10));
  SchedulePeriodicLocked(&revalidate_timer_, period, &SessionRegistry::Revalidate);
}

void SessionRegistry::SchedulePeriodicLocked(std::optional<TimerQueue::TimerId>* timer,
                                             std::chrono::milliseconds period,
                                             void (SessionRegistry::*work)()) {
  *timer = timers_->Schedule(Clock::now() + period, [this, timer, period, work] {
    std::unique_lock<std::mutex> lock(mu_);
    timer->reset();
    if (stopping_) {
      sweeping_cv_.notify_all();
      return;
    }
    ++running_timers_;
    lock.unlock();
    (this->*work)();
    lock.lock();
    --running_timers_;
    if (!stopping_) SchedulePeriodicLocked(timer, period, work);
    sweeping_cv_.notify_all();
  });
}

std::vector<std::shared_ptr<ViewSession>> SessionRegistry::Snapshot() const {
  std::vector<std::shared_ptr<ViewSession>> snapshot;
  std::lock_guard<std::mutex> lock(mu_);
  for (const auto& [id, session] : sessions_) snapshot.push_back(session);
  return snapshot;
}

void SessionRegistry::Revalidate() {
  // Outside mu_: sessions take their own mutex and ask the grant checker, which may look up
  // share links here.
  for (const auto& session : Snapshot()) {
    session->Revalidate();
    if (!session->closed()) continue;
    std::lock_guard<std::mutex> lock(mu_);
    EraseLocked(session.get());
  }
}

Result<std::shared_ptr<ViewSession>> SessionRegistry::Create(const SessionContext& context,
                                                             const ViewSessionOptions& options,
                                                             protocol::GrantRef owner) {
  const std::vector<std::shared_ptr<ViewSession>> snapshot = Snapshot();
  // Outside mu_: sessions take their own mutex.
  size_t active = 0, owned = 0;
  std::vector<std::pair<Clock::time_point, std::shared_ptr<ViewSession>>> parked;
  for (const auto& session : snapshot) {
    if (auto since = session->empty_since()) {
      parked.emplace_back(*since, session);
    } else {
      ++active;
      owned += session->owner_grant() == owner;
    }
  }
  const size_t max = static_cast<size_t>(std::max(1, limits_.max_sessions));
  if (active >= max) return ResourceExhaustedError("too many sessions");
  if (owned >= static_cast<size_t>(std::max(1, limits_.max_sessions_per_owner))) {
    return ResourceExhaustedError("too many sessions for this user");
  }
  // Room for one more: the longest-parked sessions give way.
  std::sort(parked.begin(), parked.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  for (size_t i = 0; i < parked.size() && snapshot.size() - i >= max; ++i) {
    parked[i].second->Close(4004, "session released");
    std::lock_guard<std::mutex> lock(mu_);
    EraseLocked(parked[i].second.get());
  }
  auto session = ViewSession::Create(context, RandomOr(8, "session"), RandomOr(16, ""), options,
                                     std::move(owner));
  std::lock_guard<std::mutex> lock(mu_);
  if (stopping_) return FailedPreconditionError("the server is shutting down");
  sessions_[session->id()] = session;
  if (!session->resume_key().empty()) {
    by_resume_.emplace(Digest(session->resume_key()), session);
  }
  return session;
}

std::shared_ptr<ViewSession> SessionRegistry::FindByResume(std::string_view key) const {
  std::shared_ptr<ViewSession> found;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto [lo, hi] = by_resume_.equal_range(Digest(key));
    for (auto it = lo; it != hi; ++it) {
      if (SecretsEqual(it->second->resume_key(), key)) found = it->second;
    }
  }
  return found != nullptr && !found->closed() ? found : nullptr;
}

void SessionRegistry::AddShare(const std::string& token, const std::string& id,
                               std::weak_ptr<ViewSession> session, protocol::Role role,
                               std::optional<std::chrono::system_clock::time_point> expires) {
  std::lock_guard<std::mutex> lock(mu_);
  shares_.emplace(Digest(token), Share{token, id, std::move(session), role, expires});
}

void SessionRegistry::RemoveShare(const std::string& token) {
  std::lock_guard<std::mutex> lock(mu_);
  auto [lo, hi] = shares_.equal_range(Digest(token));
  for (auto it = lo; it != hi;) {
    it = SecretsEqual(it->second.token, token) ? shares_.erase(it) : std::next(it);
  }
}

std::optional<ShareLookup> SessionRegistry::Lookup(const Share& share) const {
  if (share.expires && std::chrono::system_clock::now() >= *share.expires) return std::nullopt;
  auto session = share.session.lock();
  if (session == nullptr) return std::nullopt;
  return ShareLookup{std::move(session), share.role, share.id};
}

std::optional<ShareLookup> SessionRegistry::FindShare(std::string_view token) const {
  std::optional<ShareLookup> found;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto [lo, hi] = shares_.equal_range(Digest(token));
    for (auto it = lo; it != hi; ++it) {
      if (!SecretsEqual(it->second.token, token)) continue;
      if (auto lookup = Lookup(it->second)) found = std::move(lookup);
    }
  }
  if (found && found->session->closed()) return std::nullopt;
  return found;
}

std::optional<ShareLookup> SessionRegistry::FindShareById(std::string_view id) const {
  std::optional<ShareLookup> found;
  {
    // Ids are not secrets (they name links in view-link documents): a plain scan.
    std::lock_guard<std::mutex> lock(mu_);
    for (const auto& [digest, share] : shares_) {
      if (share.id != id) continue;
      if (auto lookup = Lookup(share)) found = std::move(lookup);
    }
  }
  if (found && found->session->closed()) return std::nullopt;
  return found;
}

void SessionRegistry::ReleaseIdle() {
  const auto now = Clock::now();
  for (const auto& session : Snapshot()) {
    const auto since = session->empty_since();
    if (!since || now - *since < limits_.idle_timeout) continue;
    session->Close(4004, "session released");
    std::lock_guard<std::mutex> lock(mu_);
    EraseLocked(session.get());
  }
}

void SessionRegistry::ReleaseIfEmpty(const std::shared_ptr<ViewSession>& session) {
  if (session == nullptr || session->participant_count() != 0) return;
  session->Close(4004, "session released");
  std::lock_guard<std::mutex> lock(mu_);
  EraseLocked(session.get());
}

void SessionRegistry::EraseLocked(const ViewSession* session) {
  sessions_.erase(session->id());
  std::erase_if(by_resume_, [&](const auto& entry) { return entry.second.get() == session; });
  std::erase_if(shares_, [&](const auto& entry) {
    auto s = entry.second.session.lock();
    return s == nullptr || s.get() == session;
  });
}

size_t SessionRegistry::size() const {
  std::lock_guard<std::mutex> lock(mu_);
  return sessions_.size();
}

}  // namespace octoscope::session
