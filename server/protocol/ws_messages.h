// WebSocket messages (docs/protocol.md): the typed client → server messages with their strict
// parser, the session state document, and the builders of the server → client JSON events.
//
// Parsing is strict and bounded: at most kMaxClientMessageBytes of text, nesting at most
// kMaxClientMessageDepth, strings at most kMaxClientStringBytes, no duplicate keys; unknown
// types and fields, wrong JSON types and out-of-range values are kInvalidArgument errors naming
// the offending field by its path from the message's root ("viewport.width: is 9000, must be in
// 0..8192", "unknown key \"x\" in ping (known: type, t)"). The camera and render-parameter
// documents are checked by protocol/render_json.h.
// Nothing throws out of these functions, whatever the input.
//
// Thread safety: pure functions; the message structs are plain values.
#ifndef OCTOSCOPE_PROTOCOL_WS_MESSAGES_H_
#define OCTOSCOPE_PROTOCOL_WS_MESSAGES_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "protocol/grant_ref.h"
#include "protocol/view_id.h"
#include "render/camera.h"
#include "render/render_params.h"
#include "util/result.h"

namespace octoscope::protocol {

inline constexpr int kProtocolVersion = 1;
// Message limits (docs/protocol.md, "Limits").
inline constexpr size_t kMaxClientMessageBytes = size_t{64} << 10;
inline constexpr int kMaxClientMessageDepth = 32;
inline constexpr size_t kMaxClientStringBytes = 4096;
// A client that sends more malformed messages than this is closed (policy of the session layer).
inline constexpr int kMaxMalformedMessages = 20;
// Field ranges.
inline constexpr size_t kMaxClientNameBytes = 64;
inline constexpr size_t kMaxDatasetIdBytes = 64;
inline constexpr int kMaxViewportCssPixels = 8192;
inline constexpr double kMinDevicePixelRatio = 0.5;
inline constexpr double kMaxDevicePixelRatio = 4;
inline constexpr int kMaxRenderPixels = 4096;  // Per axis of a rendered view.
inline constexpr int kMinJpegInteractive = 20, kMaxJpegInteractive = 95;
inline constexpr int kMinJpegFinal = 50, kMaxJpegFinal = 100;
inline constexpr double kMinLodBias = -2, kMaxLodBias = 4;
// Largest integer a JavaScript number holds exactly (frame ids a browser can acknowledge).
inline constexpr uint64_t kMaxSafeInteger = (uint64_t{1} << 53) - 1;
// Largest |coordinate| in µm accepted for slice positions (clamped to the volume afterwards).
inline constexpr double kMaxCoordinateUm = 1e9;
// Sharing (docs/protocol.md, "Sharing").
inline constexpr size_t kMaxParticipantNameBytes = 64;
inline constexpr size_t kMaxParticipantIdBytes = 32;
inline constexpr size_t kMaxShareTokenBytes = 128;
inline constexpr size_t kResumeKeyChars = 32;   // Hex digits of a 128-bit key.
inline constexpr size_t kViewLinkIdChars = 22;  // base64url of a 128-bit id.
inline constexpr int64_t kMinShareTtlSeconds = 60, kMaxShareTtlSeconds = 31536000;

// ---- Client → server ----

struct HelloMessage {
  std::string client;  // Informative; "" when absent. The protocol version was checked.
  std::string name;    // Display name for the other participants; "" when absent.
  std::string resume;  // The owner's resume key (kResumeKeyChars of 0-9a-f); "" when absent.
};

// Participant roles (docs/protocol.md, "Sharing").
enum class Role { kOwner, kController, kViewer };
std::string_view RoleName(Role role);  // "owner", "controller", "viewer".

// The layout part of the state document.
struct Layout {
  std::optional<ViewId> maximized;  // nullopt: no view maximised.
};

// A state document as a client sends it (in `open`): every part optional, a missing part keeps
// its default. The camera is validated and held at a nominal 1 x 1 image size (CameraForSize
// makes the camera of a view); the parameters are validated against their own channel count and
// applied to a dataset with ApplyParams.
struct StateUpdate {
  std::optional<render::Camera> camera;
  std::optional<std::string> params_json;
  std::optional<std::array<double, 3>> slice_position_um;
  std::optional<Layout> layout;
};

// Either `dataset` (with an optional state) or `view` (a view link, alone) is set.
struct OpenMessage {
  std::string dataset;               // 1 to kMaxDatasetIdBytes of [a-z0-9_-]; "" with `view`.
  std::optional<StateUpdate> state;  // Applied over the dataset's defaults.
  std::string view;                  // A view-link id (IsViewLinkId); "" with `dataset`.
};

struct CameraMessage {
  render::Camera camera;  // Nominal 1 x 1; see CameraForSize.
};

// A render-parameter document, applied over the current parameters: keys it leaves out keep
// their current values (docs/protocol.md). Validated as far as possible without the dataset.
struct ParamsMessage {
  std::string params_json;
};

struct SlicesMessage {
  std::array<double, 3> position_um{};  // Finite; the session clamps to the volume.
};

struct ViewportMessage {
  ViewId view = ViewId::k3d;
  int width = 0;  // CSS pixels, [0, kMaxViewportCssPixels].
  int height = 0;
  double dpr = 1;  // [kMinDevicePixelRatio, kMaxDevicePixelRatio]; 1 when absent.
};

struct InteractionMessage {
  bool active = false;
};

// Per-connection preferences; absent fields keep their values.
struct QualityMessage {
  std::optional<int> jpeg_interactive;
  std::optional<int> jpeg_final;
  std::optional<bool> lossless_final;
  std::optional<double> lod_bias;
};

struct AckMessage {
  uint64_t frame = 0;  // [1, kMaxSafeInteger].
};

struct ScreenshotMessage {
  ViewId view = ViewId::k3d;
  int scale = 1;    // 1 or 2.
  uint32_t id = 0;  // Chosen by the client; echoed in the frame header.
};

struct PingMessage {
  double t = 0;  // Finite; echoed by pong.
};

struct ShareCreateMessage {
  Role role = Role::kViewer;     // kViewer or kController.
  std::optional<int64_t> ttl_s;  // [kMinShareTtlSeconds, kMaxShareTtlSeconds].
};

struct ShareRevokeMessage {
  std::string token;  // 1 to kMaxShareTokenBytes.
};

struct ParticipantRoleMessage {
  std::string participant;    // 1 to kMaxParticipantIdBytes.
  Role role = Role::kViewer;  // kViewer or kController.
};

struct KickMessage {
  std::string participant;
};

struct ViewSaveMessage {
  std::optional<int64_t> ttl_s;  // [kMinShareTtlSeconds, kMaxShareTtlSeconds]; none: no expiry.
};

using ClientMessage =
    std::variant<HelloMessage, OpenMessage, CameraMessage, ParamsMessage, SlicesMessage,
                 ViewportMessage, InteractionMessage, QualityMessage, AckMessage, ScreenshotMessage,
                 PingMessage, ShareCreateMessage, ShareRevokeMessage, ParticipantRoleMessage,
                 KickMessage, ViewSaveMessage>;

// True for a view-link id: kViewLinkIdChars of A-Z a-z 0-9 _ -.
bool IsViewLinkId(std::string_view id);
// True for a share token or resume key as the server makes them: kResumeKeyChars of 0-9a-f.
bool IsHexKey(std::string_view key);

// The message's "type" ("hello", "open", ...).
std::string_view MessageTypeName(const ClientMessage& message);

// Parses one client text message. On error, `*type` (when given) is set to the message's type
// when it was one of the known types (for the error event's "request"), else cleared.
Result<ClientMessage> ParseClientMessage(std::string_view text, std::string* type = nullptr);

// Parses a state document (the "state" of `open`). `path` prefixes field paths in errors.
Result<StateUpdate> ParseStateDocument(std::string_view text, std::string_view path = "state");

// Applies a validated render-parameter document to `current` (the dataset's channel count):
// ParseRenderParamsJson with `current` as defaults.
Result<render::RenderParams> ApplyParams(std::string_view params_json,
                                         const render::RenderParams& current);

// The same camera for a width x height image (REQUIRES: both >= 1).
Result<render::Camera> CameraForSize(const render::Camera& camera, int width, int height);

// The rendered image size of a viewport: round(width × dpr) × round(height × dpr), scaled down
// uniformly (aspect kept) so neither axis exceeds kMaxRenderPixels; 0 x 0 when either CSS size
// is 0 (the view is not rendered), else at least 1 x 1.
struct PixelSize {
  int width = 0;
  int height = 0;
};
PixelSize ViewportPixels(const ViewportMessage& viewport);

// ---- The full state (server → client) ----

struct ViewState {
  render::Camera camera;  // The 3-D view's camera (its image size is not part of the document).
  render::RenderParams params;
  std::array<double, 3> slice_position_um{};
  std::optional<ViewId> maximized;
};

// {"camera": {...}, "params": {...}, "slices": {"position_um": [x, y, z]},
//  "layout": {"maximized": null|"3d"|"x"|"y"|"z"}}; ParseStateDocument reads it back.
std::string StateJson(const ViewState& state);

// ---- Server → client events (one JSON object each, compact) ----

// {"type":"welcome","protocol":1,"server":VERSION,"session":ID,"datasets_url":"/api/datasets",
//  "participant":P,"role":ROLE[,"resume":KEY]} (resume only when not empty).
std::string WelcomeEvent(std::string_view server_version, std::string_view session_id,
                         std::string_view participant = "p1", Role role = Role::kOwner,
                         std::string_view resume = "");
// {"type":"opened","dataset":DATASET,"state":STATE,"version":N}.
// REQUIRES: dataset_json is one JSON object (as the protocol's dataset JSON builder writes it).
std::string OpenedEvent(std::string_view dataset_json, const ViewState& state, uint64_t version);
// {"type":"state","version":N,"state":STATE[,"by":PARTICIPANT]} (by only when not empty).
std::string StateEvent(const ViewState& state, uint64_t version, std::string_view by = "");
// {"type":"dataset","dataset":DATASET}. REQUIRES: as OpenedEvent.
std::string DatasetEvent(std::string_view dataset_json);
// {"type":"error","message":..., "request":TYPE (omitted when empty), "fatal":bool}; the message
// is made one line (control characters become spaces) of at most 1000 bytes.
std::string ErrorEvent(std::string_view message, std::string_view request, bool fatal);
// {"type":"pong","t":T}
std::string PongEvent(double t);

struct ConnectionStats {
  uint64_t frames_sent = 0;
  uint64_t frames_dropped = 0;
  uint64_t bytes_sent = 0;
  uint64_t bricks_pending = 0;
};
struct ParticipantInfo {
  std::string id;
  std::string name;
  Role role = Role::kViewer;
  bool driving = false;
};
// {"type":"participants","participants":[{"id","name","role","driving","you"}...]}; `you` is
// true for the entry whose id is `you`.
std::string ParticipantsEvent(const std::vector<ParticipantInfo>& participants,
                              std::string_view you);

struct ShareInfo {
  std::string token;
  Role role = Role::kViewer;
  std::string url;
  std::optional<int64_t> expires_unix_s;  // nullopt: never.
  int participants = 0;
};
// {"type":"share_created","token","role","url","expires":ISO-8601 UTC|null}
std::string ShareCreatedEvent(const ShareInfo& share);
// {"type":"shares","shares":[{"token","role","url","expires","participants"}...]}
std::string SharesEvent(const std::vector<ShareInfo>& shares);
// {"type":"view_saved","id","url","expires":ISO-8601 UTC|null}
std::string ViewSavedEvent(std::string_view id, std::string_view url,
                           std::optional<int64_t> expires_unix_s = std::nullopt);
// "2026-11-25T12:00:00Z".
std::string IsoUtc(int64_t unix_s);

// ---- View links (STATE_DIR/views/ID.json; docs/protocol.md "View links") ----

// Who made a view link and for how long it may open (docs/protocol.md "View links").
struct ViewLinkGrant {
  GrantRef creator;  // The grant of the participant that saved it: the link holds while it does.
  GrantRef owner;    // The user at the root of that grant's chain: lists, deletes, is counted.
  int64_t created_unix_s = 0;
  std::optional<int64_t> expires_unix_s;  // nullopt: no expiry of its own.
};

struct ViewLink {
  std::string dataset;
  StateUpdate state;  // Every part present in a document this server wrote.
  // Documents of version 1 (written before creators were recorded) have none: such a link is no
  // credential of its own any more (docs/protocol.md).
  std::optional<ViewLinkGrant> grant;
};
// {"version":2,"dataset":ID,"creator":GRANT,"owner":GRANT,"created":ISO-8601,
//  "expires":ISO-8601|null,"state":STATE}
std::string ViewLinkJson(std::string_view dataset, const ViewState& state,
                         const ViewLinkGrant& grant);
// Strict: unknown keys, a wrong version, a bad dataset id, grant, time or state are
// kInvalidArgument naming the field; the state must hold every part (camera, params, slices,
// layout). Version 1 documents ({"version":1,"dataset","state"}) are read with no grant.
Result<ViewLink> ParseViewLink(std::string_view text);

// {"type":"stats","frames_sent":..,"frames_dropped":..,"bytes_sent":..,"bricks_pending":..}
std::string StatsEvent(const ConnectionStats& stats);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_WS_MESSAGES_H_
