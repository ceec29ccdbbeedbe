// Participant: one connection's part in a viewing session (docs/protocol.md, "Sharing"): who it
// is (id, display name, role, the share link it joined through), how it is reached (its
// SessionSink), and everything about frames that is its own — viewport sizes, quality
// preferences, frame ids, acknowledgements and flow control (its Outbox: at most `window`
// unacknowledged frames; a slow participant only fills its own mailboxes).
//
// Thread safety: id(), number(), sink() and outbox() may be used from any thread (the sink and
// the Outbox are thread-safe). The plain fields below are guarded by the owning ViewSession's
// mutex: read and written only with it held.
#ifndef OCTOSCOPE_SESSION_PARTICIPANT_H_
#define OCTOSCOPE_SESSION_PARTICIPANT_H_

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "protocol/grant_ref.h"
#include "protocol/ws_messages.h"
#include "session/outbox.h"
#include "session/server_metrics.h"
#include "util/timer_queue.h"
#include "util/token_bucket.h"

namespace octoscope::session {

// How a session reaches one participant's client. Every call may come from any thread and must
// not block.
class SessionSink {
 public:
  virtual ~SessionSink() = default;
  virtual void SendText(std::string text) = 0;
  virtual void SendBinary(std::vector<uint8_t> bytes) = 0;
  // Ends the connection (WebSocket close code and a one-line reason).
  virtual void Close(uint16_t code, std::string reason) = 0;
};

struct ParticipantPreferences {
  int jpeg_interactive = 70;
  int jpeg_final = 92;
  bool lossless_final = false;
  double lod_bias = 0;
};

class Participant {
 public:
  // `metrics` may be null; counts the frames this participant is sent.
  Participant(uint64_t number, std::shared_ptr<SessionSink> sink, ServerMetrics* metrics,
              int window);
  Participant(const Participant&) = delete;
  Participant& operator=(const Participant&) = delete;

  // "p" + number: unique within the session, never reused.
  const std::string& id() const { return id_; }
  uint64_t number() const { return number_; }
  SessionSink& sink() const { return *sink_; }
  Outbox& outbox() { return outbox_; }

  // ---- Guarded by the owning session's mutex ----
  std::string name;
  protocol::Role role = protocol::Role::kViewer;
  std::string share_token;  // The link it joined through; "" for the owner and view links.
  protocol::GrantRef grant;  // What it acts under: the session owner's grant, or its share link.
  bool welcomed = false;    // `welcome` sent (answers `hello`).
  bool left = false;        // The connection ended or was closed by the session.
  int malformed = 0;
  bool interacting = false;  // Its last `interaction` was active.
  ParticipantPreferences preferences;
  // Full-resolution sizes of the four views; 0 x 0 = not shown.
  std::array<protocol::PixelSize, protocol::kViewCount> pixels{};
  std::optional<TimerQueue::TimerId> stats_timer;
  OutboxStats last_stats;
  // Rate limits of its messages (ViewSessionOptions) and when it was last told it went over.
  TokenBucket messages{0, 1};
  TokenBucket hellos{0, 1};
  TokenBucket::Clock::time_point rate_error_sent{};

 private:
  const uint64_t number_;
  const std::string id_;
  std::shared_ptr<SessionSink> sink_;
  Outbox outbox_;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_PARTICIPANT_H_
