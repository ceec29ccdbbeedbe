#include "session/outbox.h"

#include <cstring>
#include <utility>

namespace octoscope::session {

Outbox::Outbox(SendFn send, int window) : send_(std::move(send)), window_(window) {}

void Outbox::Offer(OutgoingFrame frame) {
  {
    std::lock_guard lock(mu_);
    if (closed_) return;
    // Older than what the client already has of this view: never send it.
    if (auto it = sent_sequence_.find(frame.view); it != sent_sequence_.end()) {
      const bool older =
          frame.sequence < it->second || (frame.sequence == it->second && sent_final_[frame.view]);
      if (older) {
        ++stats_.dropped;
        return;
      }
    }
    auto [slot, inserted] = mailbox_.try_emplace(frame.view);
    if (!inserted) {
      // The waiting frame is replaced unless it is newer (or the final of the same order).
      const OutgoingFrame& waiting = slot->second;
      if (waiting.sequence > frame.sequence ||
          (waiting.sequence == frame.sequence && waiting.final && !frame.final)) {
        ++stats_.dropped;
        return;
      }
      ++stats_.dropped;
    }
    slot->second = std::move(frame);
  }
  Pump();
}

void Outbox::Pump() {
  // Taking and sending under send_mu_ keeps ids in send order across threads.
  std::lock_guard send_lock(send_mu_);
  std::vector<std::vector<uint8_t>> ready;
  {
    std::lock_guard lock(mu_);
    TakeSendableLocked(&ready);
  }
  for (auto& bytes : ready) send_(std::move(bytes));
}

void Outbox::OnAck(uint64_t frame_id) {
  {
    std::lock_guard lock(mu_);
    if (frame_id >= next_id_) frame_id = next_id_ - 1;  // Never-sent ids count as the last sent.
    if (frame_id > acked_) acked_ = frame_id;
  }
  Pump();
}

void Outbox::TakeSendableLocked(std::vector<std::vector<uint8_t>>* out) {
  while (!closed_ && !mailbox_.empty() && next_id_ - 1 - acked_ < static_cast<uint64_t>(window_)) {
    // Round robin over the views with a waiting frame.
    auto it = mailbox_.lower_bound(rotate_);
    if (it == mailbox_.end()) it = mailbox_.begin();
    rotate_ = it->first + 1;
    OutgoingFrame frame = std::move(it->second);
    mailbox_.erase(it);
    const uint64_t id = next_id_++;
    if (frame.bytes.size() >= 16) {
      for (int b = 0; b < 8; ++b) frame.bytes[8 + b] = static_cast<uint8_t>(id >> (8 * b));
    }
    sent_sequence_[frame.view] = frame.sequence;
    sent_final_[frame.view] = frame.final;
    ++stats_.sent;
    stats_.bytes_sent += frame.bytes.size();
    out->push_back(std::move(frame.bytes));
  }
}

void Outbox::Close() {
  std::lock_guard lock(mu_);
  closed_ = true;
  mailbox_.clear();
}

OutboxStats Outbox::stats() const {
  std::lock_guard lock(mu_);
  OutboxStats s = stats_;
  s.unacked = next_id_ - 1 - acked_;
  s.waiting = mailbox_.size();
  return s;
}

uint64_t Outbox::next_id() const {
  std::lock_guard lock(mu_);
  return next_id_;
}

}  // namespace octoscope::session
