// Outbox: flow control of one connection's frames (docs/protocol.md, "Frame policy"). At most
// `window` frames are unacknowledged; a frame offered while the window is full waits in its
// view's one-slot mailbox, where a newer frame of that view replaces it (a drop). Per view,
// frames go out in the order of their render sequence: a frame older than one already sent (or
// waiting) for its view is dropped, so a client never receives a stale frame after a newer one.
// A slow or stalled client therefore costs at most one waiting frame per view, and never blocks
// the threads that offer frames.
//
// Acknowledgements are cumulative: ack(id) acknowledges every sent frame with an id <= id.
//
// Thread safety: thread-safe. `send` is called without the state mutex held, one call at a time,
// in frame id order.
#ifndef OCTOSCOPE_SESSION_OUTBOX_H_
#define OCTOSCOPE_SESSION_OUTBOX_H_

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <vector>

namespace octoscope::session {

// An encoded frame: the 64-byte header (protocol::FrameHeader) and the image, in one buffer. The
// header's frame id (bytes 8..15) is filled in when the frame is sent.
struct OutgoingFrame {
  int view = 0;           // 0 = 3d, 1..3 = x, y, z (screenshots use their own view numbers).
  uint64_t sequence = 0;  // Render order sequence of the view; larger = newer.
  bool final = false;     // Final frames are never replaced by progress frames of the same order.
  std::vector<uint8_t> bytes;
};

struct OutboxStats {
  uint64_t sent = 0;
  uint64_t dropped = 0;  // Replaced in a mailbox, or older than what was sent.
  uint64_t bytes_sent = 0;
  uint64_t unacked = 0;
  uint64_t waiting = 0;  // Frames in mailboxes now.
};

class Outbox {
 public:
  // Sends one frame (with its id written) to the client; must not block for long (posts to the
  // connection's strand).
  using SendFn = std::function<void(std::vector<uint8_t> bytes)>;
  Outbox(SendFn send, int window = 2);

  void Offer(OutgoingFrame frame);
  void OnAck(uint64_t frame_id);
  // Forgets mailboxes and the window (the connection is closing).
  void Close();
  OutboxStats stats() const;
  // The id the next sent frame gets.
  uint64_t next_id() const;

 private:
  // Sends what the window allows.
  void Pump();
  // Moves frames from mailboxes to `out` while the window allows. REQUIRES: mu_ held.
  void TakeSendableLocked(std::vector<std::vector<uint8_t>>* out);

  SendFn send_;
  const int window_;
  mutable std::mutex mu_;
  std::mutex send_mu_;  // One sender at a time, in id order.
  uint64_t next_id_ = 1;
  uint64_t acked_ = 0;  // Highest acknowledged id.
  bool closed_ = false;
  std::map<int, OutgoingFrame> mailbox_;   // Per view.
  std::map<int, uint64_t> sent_sequence_;  // Per view: sequence of the newest frame sent.
  std::map<int, bool> sent_final_;         // Per view: that frame was final.
  int rotate_ = 0;                         // Round robin over views when the window opens.
  OutboxStats stats_;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_OUTBOX_H_
