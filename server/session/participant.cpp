#include "session/participant.h"

#include <utility>

namespace octoscope::session {
namespace {

std::string ParticipantId(uint64_t number) {
  // Appended rather than "p" + to_string (which trips GCC 12's -Wrestrict false positive).
  std::string id = "p";
  id.append(std::to_string(number));
  return id;
}

}  // namespace

Participant::Participant(uint64_t number, std::shared_ptr<SessionSink> sink, ServerMetrics* metrics,
                         int window)
    : number_(number),
      id_(ParticipantId(number)),
      sink_(std::move(sink)),
      outbox_(
          [sink = sink_, metrics](std::vector<uint8_t> bytes) {
            // Byte 25 of the frame header is the tier (docs/protocol.md).
            if (metrics != nullptr && bytes.size() > 25 && bytes[25] <= 3) {
              metrics->FrameSent(static_cast<protocol::FrameTier>(bytes[25]), bytes.size());
            }
            sink->SendBinary(std::move(bytes));
          },
          window) {}

}  // namespace octoscope::session
