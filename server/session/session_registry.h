// SessionRegistry: the server's viewing sessions (docs/protocol.md, "Sharing"): creates them
// within the `max-sessions` limit and the per-owner limit (one user, or one view link, holds at
// most `max_sessions_per_owner`), finds them by share token (a live join), by share-link id (the
// grant a view link made through a share link rests on) and by resume key (the owner's
// reconnect), releases the ones that had no participant for `idle-timeout-s`, and has every
// session revalidate its grants each `revalidate_interval` (ViewSession::Revalidate). Share
// tokens and resume keys are secrets: they are looked up by a salted 64-bit digest and then
// compared in constant time, so lookup timing reveals nothing about them.
//
// Sessions with a participant count against max_sessions; sessions without one are parked (kept
// for their owner's reconnect and their share links) until the idle timeout, or until a new
// session needs their place (the longest-parked goes first).
//
// Thread safety: thread-safe; lookups are fast (never touch disk) and may run on I/O threads.
// The registry never calls a session while holding its own mutex (sessions call it while
// holding theirs).
#ifndef OCTOSCOPE_SESSION_SESSION_REGISTRY_H_
#define OCTOSCOPE_SESSION_SESSION_REGISTRY_H_

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/grant_ref.h"
#include "session/view_session.h"
#include "util/result.h"
#include "util/timer_queue.h"

namespace octoscope::session {

struct SessionLimits {
  int max_sessions = 64;
  // Sessions with a participant that one owner grant (a user, or a view link) holds at once.
  int max_sessions_per_owner = 16;
  std::chrono::milliseconds idle_timeout{900'000};
  // How often every session checks that its grants still hold.
  std::chrono::milliseconds revalidate_interval{1000};
};

struct ShareLookup {
  std::shared_ptr<ViewSession> session;
  protocol::Role role = protocol::Role::kViewer;
  std::string id;  // The link's public id (its grant: protocol::GrantRef kShare).
};

class SessionRegistry {
 public:
  // REQUIRES: timers outlives the registry.
  SessionRegistry(TimerQueue* timers, SessionLimits limits);
  // Closes every session (1001).
  ~SessionRegistry();
  SessionRegistry(const SessionRegistry&) = delete;
  SessionRegistry& operator=(const SessionRegistry&) = delete;

  // A new empty session (random id and resume key) owned under `owner`, or kResourceExhausted
  // "too many sessions" when max_sessions sessions have participants, "too many sessions for
  // this user" when `owner` holds max_sessions_per_owner of them.
  Result<std::shared_ptr<ViewSession>> Create(const SessionContext& context,
                                              const ViewSessionOptions& options = {},
                                              protocol::GrantRef owner = {});
  // The live session whose resume key is `key`, else null.
  std::shared_ptr<ViewSession> FindByResume(std::string_view key) const;

  // Share links (the session registers and removes its own).
  void AddShare(const std::string& token, const std::string& id, std::weak_ptr<ViewSession> session,
                protocol::Role role, std::optional<std::chrono::system_clock::time_point> expires);
  void RemoveShare(const std::string& token);
  // The session, role and id of a valid, unexpired link, else nullopt.
  std::optional<ShareLookup> FindShare(std::string_view token) const;
  // The same by the link's public id (not a secret).
  std::optional<ShareLookup> FindShareById(std::string_view id) const;

  // Every session checks its grants now (also run by a periodic timer).
  void Revalidate();

  // Releases sessions with no participant for the idle timeout (also run by a periodic timer).
  void ReleaseIdle();
  // Releases `session` at once if it has no participant (a connection that moved elsewhere).
  void ReleaseIfEmpty(const std::shared_ptr<ViewSession>& session);
  size_t size() const;

 private:
  struct Share {
    std::string token;
    std::string id;
    std::weak_ptr<ViewSession> session;
    protocol::Role role;
    std::optional<std::chrono::system_clock::time_point> expires;
  };
  uint64_t Digest(std::string_view secret) const;
  std::optional<ShareLookup> Lookup(const Share& share) const;
  std::vector<std::shared_ptr<ViewSession>> Snapshot() const;
  // Arms the next idle sweep. REQUIRES: mu_ held.
  void ScheduleSweepLocked();
  // Arms the next revalidation. REQUIRES: mu_ held.
  void ScheduleRevalidateLocked();
  // Runs `work` (without mu_) in `period`, then again every `period` until the registry stops.
  // REQUIRES: mu_ held.
  void SchedulePeriodicLocked(std::optional<TimerQueue::TimerId>* timer,
                              std::chrono::milliseconds period, void (SessionRegistry::*work)());
  // Removes `session` and its share links. REQUIRES: mu_ held.
  void EraseLocked(const ViewSession* session);

  TimerQueue* const timers_;
  const SessionLimits limits_;
  uint64_t salt_ = 0;
  mutable std::mutex mu_;
  bool stopping_ = false;
  int running_timers_ = 0;  // Sweeps or revalidations running on the timer thread.
  std::condition_variable sweeping_cv_;
  std::map<std::string, std::shared_ptr<ViewSession>> sessions_;  // By id.
  std::multimap<uint64_t, std::shared_ptr<ViewSession>> by_resume_;
  std::multimap<uint64_t, Share> shares_;
  std::optional<TimerQueue::TimerId> sweep_timer_;
  std::optional<TimerQueue::TimerId> revalidate_timer_;
};

// Constant-time equality of two secrets (no early exit on the first differing byte).
bool SecretsEqual(std::string_view a, std::string_view b);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_SESSION_REGISTRY_H_
