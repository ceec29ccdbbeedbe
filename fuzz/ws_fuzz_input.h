// What the WebSocket-protocol fuzz harness does with one input, shared by the libFuzzer entry
// point (ws_message_fuzzer.cpp) and the test that replays its seeds and regressions in every CI
// run (tests/protocol/ws_fuzz_replay_test.cpp). Input format: byte 0 picks the target, the rest
// is its input:
//   0, 1 (mod 4): a client → server message (protocol::ParseClientMessage);
//   2: a state document (ParseStateDocument), a stored view link (ParseViewLink) and the query
//      of a slab upload (ParseSlabQuery);
//   3: a binary frame message (DecodeFrameHeader, as a native client reads it).
// Parse errors are fine. What parses must respect the documented ranges; a violation is
// returned as kInternal, the finding (as is a crash, hang, leak or sanitizer report).
//
// Thread safety: a pure function.
#ifndef OCTOSCOPE_FUZZ_WS_FUZZ_INPUT_H_
#define OCTOSCOPE_FUZZ_WS_FUZZ_INPUT_H_

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <variant>

#include "protocol/api_json.h"
#include "protocol/dataset_json.h"
#include "protocol/frame_header.h"
#include "protocol/ws_messages.h"

namespace octoscope::fuzz {

namespace ws_fuzz_detail {

inline Status Expect(bool ok, const char* what) {
  return ok ? Status::Ok() : InternalError(std::string("invariant broken: ") + what);
}

inline Status CheckMessage(const protocol::ClientMessage& message) {
  using namespace protocol;
  if (const auto* v = std::get_if<ViewportMessage>(&message)) {
    const PixelSize pixels = ViewportPixels(*v);
    return Expect(v->width >= 0 && v->width <= kMaxViewportCssPixels && v->height >= 0 &&
                      v->height <= kMaxViewportCssPixels && v->dpr >= kMinDevicePixelRatio &&
                      v->dpr <= kMaxDevicePixelRatio && pixels.width >= 0 &&
                      pixels.width <= kMaxRenderPixels && pixels.height >= 0 &&
                      pixels.height <= kMaxRenderPixels &&
                      (pixels.width == 0) == (pixels.height == 0),
                  "viewport ranges");
  }
  if (const auto* a = std::get_if<AckMessage>(&message)) {
    return Expect(a->frame >= 1 && a->frame <= kMaxSafeInteger, "ack range");
  }
  if (const auto* q = std::get_if<QualityMessage>(&message)) {
    return Expect(
        (!q->jpeg_interactive || (*q->jpeg_interactive >= kMinJpegInteractive &&
                                  *q->jpeg_interactive <= kMaxJpegInteractive)) &&
            (!q->jpeg_final ||
             (*q->jpeg_final >= kMinJpegFinal && *q->jpeg_final <= kMaxJpegFinal)) &&
            (!q->lod_bias || (*q->lod_bias >= kMinLodBias && *q->lod_bias <= kMaxLodBias)),
        "quality ranges");
  }
  if (const auto* s = std::get_if<SlicesMessage>(&message)) {
    bool finite = true;
    for (double p : s->position_um) finite = finite && std::isfinite(p);
    return Expect(finite, "finite slice positions");
  }
  if (const auto* p = std::get_if<PingMessage>(&message)) {
    return Expect(std::isfinite(p->t), "finite ping time");
  }
  if (const auto* shot = std::get_if<ScreenshotMessage>(&message)) {
    return Expect(shot->scale == 1 || shot->scale == 2, "screenshot scale");
  }
  if (const auto* open = std::get_if<OpenMessage>(&message)) {
    if (!open->view.empty()) {
      return Expect(IsViewLinkId(open->view) && open->dataset.empty() && !open->state,
                    "a view link opens alone");
    }
    return Expect(!open->dataset.empty() && open->dataset.size() <= kMaxDatasetIdBytes,
                  "dataset id length");
  }
  if (const auto* hello = std::get_if<HelloMessage>(&message)) {
    return Expect((hello->resume.empty() || IsHexKey(hello->resume)) &&
                      hello->name.size() <= kMaxParticipantNameBytes,
                  "hello resume key and name");
  }
  if (const auto* share = std::get_if<ShareCreateMessage>(&message)) {
    return Expect(
        share->role != Role::kOwner && (!share->ttl_s || (*share->ttl_s >= kMinShareTtlSeconds &&
                                                          *share->ttl_s <= kMaxShareTtlSeconds)),
        "share role and ttl");
  }
  if (const auto* revoke = std::get_if<ShareRevokeMessage>(&message)) {
    return Expect(!revoke->token.empty() && revoke->token.size() <= kMaxShareTokenBytes,
                  "share token length");
  }
  if (const auto* role = std::get_if<ParticipantRoleMessage>(&message)) {
    return Expect(role->role != Role::kOwner && !role->participant.empty() &&
                      role->participant.size() <= kMaxParticipantIdBytes,
                  "participant role");
  }
  if (const auto* kick = std::get_if<KickMessage>(&message)) {
    return Expect(!kick->participant.empty() && kick->participant.size() <= kMaxParticipantIdBytes,
                  "kicked participant id");
  }
  return Status::Ok();
}

}  // namespace ws_fuzz_detail

inline Status WsMessageInput(std::span<const uint8_t> data) {
  using namespace protocol;
  if (data.empty()) return Status::Ok();
  const std::span<const uint8_t> rest = data.subspan(1);
  const std::string_view text(reinterpret_cast<const char*>(rest.data()), rest.size());
  switch (data[0] % 4) {
    case 0:
    case 1: {  // Most of the effort goes to the message parser.
      std::string type;
      Result<ClientMessage> message = ParseClientMessage(text, &type);
      if (!message.ok()) return message.status();
      OCTO_RETURN_IF_ERROR(ws_fuzz_detail::CheckMessage(*message));
      return ws_fuzz_detail::Expect(MessageTypeName(*message) == type, "type reported");
    }
    case 2: {
      // A stored view-link document (ViewStore reads them back strictly).
      Result<ViewLink> link = ParseViewLink(text);
      if (link.ok()) {
        OCTO_RETURN_IF_ERROR(ws_fuzz_detail::Expect(
            link->state.camera && link->state.params_json && link->state.slice_position_um &&
                link->state.layout && !link->dataset.empty(),
            "a view link holds the whole state"));
      }
      Result<StateUpdate> state = ParseStateDocument(text);
      Result<SlabQuery> query = ParseSlabQuery(text);
      if (query.ok()) {
        OCTO_RETURN_IF_ERROR(ws_fuzz_detail::Expect(
            query->z >= 0 && query->depth >= 1 && query->z + query->depth <= kMaxStreamAxis &&
                query->channel >= 0 && query->channel < kMaxStreamChannels,
            "slab query ranges"));
      }
      if (state.ok() || query.ok() || link.ok()) return Status::Ok();
      return state.status();
    }
    default: {
      Result<FrameHeader> header = DecodeFrameHeader(rest);
      if (!header.ok()) return header.status();
      OCTO_RETURN_IF_ERROR(ValidateFrameHeader(*header));
      return ws_fuzz_detail::Expect(header->image_bytes <= rest.size(), "image within message");
    }
  }
}

}  // namespace octoscope::fuzz

#endif  // OCTOSCOPE_FUZZ_WS_FUZZ_INPUT_H_
