// SessionRegistry: the server's viewing sessions (docs/protocol.md, "Sharing"): creates them
// within the `max-sessions` limit, finds them by share token (a live join) and by resume key
// (the owner's reconnect), and releases the ones that had no participant for `idle-timeout-s`.
// Share tokens and resume keys are secrets: they are looked up by a salted 64-bit digest and
// then compared in constant time, so lookup timing reveals nothing about them.
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

#include "session/view_session.h"
#include "util/result.h"
#include "util/timer_queue.h"

namespace octoscope::session {

struct SessionLimits {
  int max_sessions = 64;
  std::chrono::milliseconds idle_timeout{900'000};
};

struct ShareLookup {
  std::shared_ptr<ViewSession> session;
  protocol::Role role = protocol::Role::kViewer;
};

class SessionRegistry {
 public:
  // REQUIRES: timers outlives the registry.
  SessionRegistry(TimerQueue* timers, SessionLimits limits);
  // Closes every session (1001).
  ~SessionRegistry();
  SessionRegistry(const SessionRegistry&) = delete;
  SessionRegistry& operator=(const SessionRegistry&) = delete;

  // A new empty session (random id and resume key), or kResourceExhausted "too many sessions"
  // when max_sessions sessions have participants.
  Result<std::shared_ptr<ViewSession>> Create(const SessionContext& context,
                                              const ViewSessionOptions& options = {});
  // The live session whose resume key is `key`, else null.
  std::shared_ptr<ViewSession> FindByResume(std::string_view key) const;

  // Share links (the session registers and removes its own).
  void AddShare(const std::string& token, std::weak_ptr<ViewSession> session, protocol::Role role,
                std::optional<std::chrono::system_clock::time_point> expires);
  void RemoveShare(const std::string& token);
  // The session and role of a valid, unexpired link, else nullopt.
  std::optional<ShareLookup> FindShare(std::string_view token) const;

  // Releases sessions with no participant for the idle timeout (also run by a periodic timer).
  void ReleaseIdle();
  // Releases `session` at once if it has no participant (a connection that moved elsewhere).
  void ReleaseIfEmpty(const std::shared_ptr<ViewSession>& session);
  size_t size() const;

 private:
  struct Share {
    std::string token;
    std::weak_ptr<ViewSession> session;
    protocol::Role role;
    std::optional<std::chrono::system_clock::time_point> expires;
  };
  uint64_t Digest(std::string_view secret) const;
  // Arms the next idle sweep. REQUIRES: mu_ held.
  void ScheduleSweepLocked();
  // Removes `session` and its share links. REQUIRES: mu_ held.
  void EraseLocked(const ViewSession* session);

  TimerQueue* const timers_;
  const SessionLimits limits_;
  uint64_t salt_ = 0;
  mutable std::mutex mu_;
  bool stopping_ = false;
  bool sweeping_ = false;  // A sweep runs on the timer thread.
  std::condition_variable sweeping_cv_;
  std::map<std::string, std::shared_ptr<ViewSession>> sessions_;  // By id.
  std::multimap<uint64_t, std::shared_ptr<ViewSession>> by_resume_;
  std::multimap<uint64_t, Share> shares_;
  std::optional<TimerQueue::TimerId> sweep_timer_;
};

// Constant-time equality of two secrets (no early exit on the first differing byte).
bool SecretsEqual(std::string_view a, std::string_view b);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_SESSION_REGISTRY_H_
