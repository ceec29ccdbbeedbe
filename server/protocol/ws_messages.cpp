#include "protocol/ws_messages.h"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <initializer_list>
#include <utility>
#include <vector>

#include "octree/brick_geometry.h"
#include "protocol/json_fields.h"
#include "protocol/render_json.h"
#include "protocol/serve_config.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using Json = nlohmann::json;

Result<Json> ParseMessageText(std::string_view text, std::string_view what) {
  return ParseJsonObject(text, what, kMaxClientMessageBytes, kMaxClientMessageDepth,
                         kMaxClientStringBytes);
}

// Three finite numbers in [lo, hi].
Result<std::array<double, 3>> GetNumber3(const Json& j, const std::string& path, double lo,
                                         double hi) {
  OCTO_ASSIGN_OR_RETURN(std::vector<double> v, GetNumbers(j, path, 3, lo, hi));
  return std::array<double, 3>{v[0], v[1], v[2]};
}

constexpr std::string_view kTypeNames[] = {"hello",        "open",
                                           "camera",       "params",
                                           "slices",       "viewport",
                                           "interaction",  "quality",
                                           "ack",          "screenshot",
                                           "ping",         "share_create",
                                           "share_revoke", "participant_role",
                                           "kick",         "view_save"};

constexpr std::string_view kRoleNames[] = {"owner", "controller", "viewer"};

// "viewer" or "controller" (the roles a client may give).
Result<Role> GetGrantableRole(const Json& j, const std::string& path) {
  OCTO_ASSIGN_OR_RETURN(std::string name, GetString(j, path, 16, true));
  if (name == "viewer") return Role::kViewer;
  if (name == "controller") return Role::kController;
  return FieldError(path, "is \"" + Printable(name, 16) + "\", expected viewer or controller");
}

Result<std::string> GetParticipantId(const Json& doc, const std::string& type) {
  const std::string path = type + ".participant";
  OCTO_ASSIGN_OR_RETURN(const Json* j, Require(doc, type, "participant"));
  OCTO_ASSIGN_OR_RETURN(std::string id, GetString(*j, path, kMaxParticipantIdBytes, true));
  if (id.empty()) return FieldError(path, "is empty");
  return id;
}

// Rewrites an error of a render_json parser ("position: must be ...", "camera: missing ...",
// "unknown key ...") so that it names the field from the message's root ("camera.position: ...").
Status Reprefix(const Status& status, std::string_view strip, const std::string& path) {
  std::string_view m = status.message();
  if (m.starts_with(strip)) m.remove_prefix(strip.size());
  const size_t colon = m.find(": ");
  const std::string_view head = m.substr(0, colon == std::string_view::npos ? 0 : colon);
  const bool starts_with_field = !head.empty() && head.find_first_of(" \"") == std::string::npos;
  return InvalidArgumentError(std::string(path) + (starts_with_field ? "." : ": ") +
                              std::string(m));
}

Result<ViewId> GetView(const Json& j, const std::string& path) {
  OCTO_ASSIGN_OR_RETURN(std::string name, GetString(j, path, 16, true));
  std::optional<ViewId> view = ViewFromName(name);
  if (!view) return FieldError(path, "is \"" + Printable(name, 16) + "\", expected 3d, x, y or z");
  return *view;
}

Result<render::Camera> CameraFromJson(const Json& j, const std::string& path) {
  OCTO_RETURN_IF_ERROR(CheckObject(j, path));
  Result<render::Camera> camera = ParseCameraJson(Dump(j), render::Projection::kOrthographic, 1, 1);
  if (!camera.ok()) return Reprefix(camera.status(), "camera: ", path);
  return camera;
}

// Validates a render-parameter document as far as it can be without the dataset: every field,
// against defaults with as many channels as the document lists.
Result<std::string> ParamsFromJson(const Json& j, const std::string& path) {
  OCTO_RETURN_IF_ERROR(CheckObject(j, path));
  int channels = 1;
  if (auto it = j.find("channels"); it != j.end() && it->is_array()) {
    if (it->size() > static_cast<size_t>(octree::kMaxChannels)) {
      return FieldError(Join(path, "channels"), "has " + std::to_string(it->size()) +
                                                    " entries, at most " +
                                                    std::to_string(octree::kMaxChannels));
    }
    channels = std::max<int>(1, static_cast<int>(it->size()));
  }
  std::string text = Dump(j);
  const render::RenderParams defaults =
      render::DefaultRenderParams(channels, volume::DataType::kUint16, render::RenderMode::kDvr);
  Result<render::RenderParams> params = ParseRenderParamsJson(text, defaults);
  if (!params.ok()) return Reprefix(params.status(), "render parameters: ", path);
  return text;
}

Result<StateUpdate> StateFromJson(const Json& j, const std::string& path) {
  OCTO_RETURN_IF_ERROR(CheckObject(j, path));
  OCTO_RETURN_IF_ERROR(CheckKeys(j, path, {"camera", "params", "slices", "layout"}));
  StateUpdate state;
  if (auto it = j.find("camera"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(state.camera, CameraFromJson(*it, Join(path, "camera")));
  }
  if (auto it = j.find("params"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(state.params_json, ParamsFromJson(*it, Join(path, "params")));
  }
  if (auto it = j.find("slices"); it != j.end()) {
    const std::string slices = Join(path, "slices");
    OCTO_RETURN_IF_ERROR(CheckObject(*it, slices));
    OCTO_RETURN_IF_ERROR(CheckKeys(*it, slices, {"position_um"}));
    if (auto p = it->find("position_um"); p != it->end()) {
      OCTO_ASSIGN_OR_RETURN(
          state.slice_position_um,
          GetNumber3(*p, Join(slices, "position_um"), -kMaxCoordinateUm, kMaxCoordinateUm));
    }
  }
  if (auto it = j.find("layout"); it != j.end()) {
    const std::string layout_path = Join(path, "layout");
    OCTO_RETURN_IF_ERROR(CheckObject(*it, layout_path));
    OCTO_RETURN_IF_ERROR(CheckKeys(*it, layout_path, {"maximized"}));
    Layout layout;
    if (auto m = it->find("maximized"); m != it->end() && !m->is_null()) {
      OCTO_ASSIGN_OR_RETURN(layout.maximized, GetView(*m, Join(layout_path, "maximized")));
    }
    state.layout = layout;
  }
  return state;
}

bool IsDatasetId(std::string_view id) {
  return !id.empty() && id.size() <= kMaxDatasetIdBytes &&
         std::all_of(id.begin(), id.end(), [](char c) {
           return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
         });
}

// One parser per message type; `doc` has been checked to be an object with this "type".
Result<ClientMessage> ParseHello(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "hello", {"type", "client", "protocol", "name", "resume"}));
  OCTO_ASSIGN_OR_RETURN(const Json* protocol, Require(doc, "hello", "protocol"));
  OCTO_ASSIGN_OR_RETURN(int64_t version, GetInteger(*protocol, "hello.protocol", 0, INT32_MAX));
  if (version != kProtocolVersion) {
    return FieldError("hello.protocol", "is " + std::to_string(version) +
                                            ", this server speaks protocol " +
                                            std::to_string(kProtocolVersion));
  }
  HelloMessage hello;
  if (auto it = doc.find("client"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(hello.client, GetString(*it, "hello.client", kMaxClientNameBytes, true));
  }
  if (auto it = doc.find("name"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(hello.name, GetString(*it, "hello.name", kMaxParticipantNameBytes, true));
    if (hello.name.empty()) return FieldError("hello.name", "is empty");
  }
  if (auto it = doc.find("resume"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(hello.resume, GetString(*it, "hello.resume", 64, true));
    if (!IsHexKey(hello.resume)) {
      return FieldError("hello.resume", "is not a resume key (32 of 0-9 a-f)");
    }
  }
  return ClientMessage(std::move(hello));
}

Result<ClientMessage> ParseOpen(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "open", {"type", "dataset", "state", "view"}));
  OpenMessage open;
  if (auto it = doc.find("view"); it != doc.end()) {
    if (doc.contains("dataset") || doc.contains("state")) {
      return FieldError("open.view", "is given with dataset or state (a view link opens alone)");
    }
    OCTO_ASSIGN_OR_RETURN(open.view, GetString(*it, "open.view", 64, true));
    if (!IsViewLinkId(open.view)) {
      return FieldError("open.view", "\"" + Printable(open.view, 40) +
                                         "\" is not a view-link id (22 of A-Z a-z 0-9 _ -)");
    }
    return ClientMessage(std::move(open));
  }
  OCTO_ASSIGN_OR_RETURN(const Json* dataset, Require(doc, "open", "dataset"));
  OCTO_ASSIGN_OR_RETURN(open.dataset,
                        GetString(*dataset, "open.dataset", kMaxDatasetIdBytes, true));
  if (!IsDatasetId(open.dataset)) {
    return FieldError("open.dataset", "\"" + Printable(open.dataset, 40) +
                                          "\" is not a dataset id (1 to 64 of a-z 0-9 _ -)");
  }
  if (auto it = doc.find("state"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(open.state, StateFromJson(*it, "open.state"));
  }
  return ClientMessage(std::move(open));
}

Result<ClientMessage> ParseCamera(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "camera", {"type", "camera"}));
  OCTO_ASSIGN_OR_RETURN(const Json* camera, Require(doc, "camera", "camera"));
  OCTO_ASSIGN_OR_RETURN(render::Camera parsed, CameraFromJson(*camera, "camera.camera"));
  return ClientMessage(CameraMessage{std::move(parsed)});
}

Result<ClientMessage> ParseParams(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "params", {"type", "params"}));
  OCTO_ASSIGN_OR_RETURN(const Json* params, Require(doc, "params", "params"));
  OCTO_ASSIGN_OR_RETURN(std::string text, ParamsFromJson(*params, "params.params"));
  return ClientMessage(ParamsMessage{std::move(text)});
}

Result<ClientMessage> ParseSlices(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "slices", {"type", "position_um"}));
  OCTO_ASSIGN_OR_RETURN(const Json* position, Require(doc, "slices", "position_um"));
  SlicesMessage slices;
  OCTO_ASSIGN_OR_RETURN(slices.position_um, GetNumber3(*position, "slices.position_um",
                                                       -kMaxCoordinateUm, kMaxCoordinateUm));
  return ClientMessage(std::move(slices));
}

Result<ClientMessage> ParseViewport(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "viewport", {"type", "view", "width", "height", "dpr"}));
  ViewportMessage viewport;
  OCTO_ASSIGN_OR_RETURN(const Json* view, Require(doc, "viewport", "view"));
  OCTO_ASSIGN_OR_RETURN(viewport.view, GetView(*view, "viewport.view"));
  OCTO_ASSIGN_OR_RETURN(const Json* width, Require(doc, "viewport", "width"));
  OCTO_ASSIGN_OR_RETURN(int64_t w, GetInteger(*width, "viewport.width", 0, kMaxViewportCssPixels));
  OCTO_ASSIGN_OR_RETURN(const Json* height, Require(doc, "viewport", "height"));
  OCTO_ASSIGN_OR_RETURN(int64_t h,
                        GetInteger(*height, "viewport.height", 0, kMaxViewportCssPixels));
  viewport.width = static_cast<int>(w);
  viewport.height = static_cast<int>(h);
  if (auto it = doc.find("dpr"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(
        viewport.dpr, GetNumberIn(*it, "viewport.dpr", kMinDevicePixelRatio, kMaxDevicePixelRatio));
  }
  return ClientMessage(std::move(viewport));
}

Result<ClientMessage> ParseInteraction(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "interaction", {"type", "active"}));
  OCTO_ASSIGN_OR_RETURN(const Json* active, Require(doc, "interaction", "active"));
  InteractionMessage interaction;
  OCTO_ASSIGN_OR_RETURN(interaction.active, GetBool(*active, "interaction.active"));
  return ClientMessage(std::move(interaction));
}

Result<ClientMessage> ParseQuality(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(
      doc, "quality", {"type", "jpeg_interactive", "jpeg_final", "lossless_final", "lod_bias"}));
  QualityMessage quality;
  if (auto it = doc.find("jpeg_interactive"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t q, GetInteger(*it, "quality.jpeg_interactive",
                                                kMinJpegInteractive, kMaxJpegInteractive));
    quality.jpeg_interactive = static_cast<int>(q);
  }
  if (auto it = doc.find("jpeg_final"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t q,
                          GetInteger(*it, "quality.jpeg_final", kMinJpegFinal, kMaxJpegFinal));
    quality.jpeg_final = static_cast<int>(q);
  }
  if (auto it = doc.find("lossless_final"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(quality.lossless_final, GetBool(*it, "quality.lossless_final"));
  }
  if (auto it = doc.find("lod_bias"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(quality.lod_bias,
                          GetNumberIn(*it, "quality.lod_bias", kMinLodBias, kMaxLodBias));
  }
  return ClientMessage(std::move(quality));
}

Result<ClientMessage> ParseAck(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "ack", {"type", "frame"}));
  OCTO_ASSIGN_OR_RETURN(const Json* frame, Require(doc, "ack", "frame"));
  OCTO_ASSIGN_OR_RETURN(int64_t id,
                        GetInteger(*frame, "ack.frame", 1, static_cast<int64_t>(kMaxSafeInteger)));
  return ClientMessage(AckMessage{static_cast<uint64_t>(id)});
}

Result<ClientMessage> ParseScreenshot(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "screenshot", {"type", "view", "scale", "id"}));
  ScreenshotMessage shot;
  OCTO_ASSIGN_OR_RETURN(const Json* view, Require(doc, "screenshot", "view"));
  OCTO_ASSIGN_OR_RETURN(shot.view, GetView(*view, "screenshot.view"));
  if (auto it = doc.find("scale"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t scale, GetInteger(*it, "screenshot.scale", 1, 2));
    shot.scale = static_cast<int>(scale);
  }
  OCTO_ASSIGN_OR_RETURN(const Json* id, Require(doc, "screenshot", "id"));
  OCTO_ASSIGN_OR_RETURN(int64_t value, GetInteger(*id, "screenshot.id", 0, UINT32_MAX));
  shot.id = static_cast<uint32_t>(value);
  return ClientMessage(std::move(shot));
}

Result<ClientMessage> ParsePing(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "ping", {"type", "t"}));
  OCTO_ASSIGN_OR_RETURN(const Json* t, Require(doc, "ping", "t"));
  PingMessage ping;
  OCTO_ASSIGN_OR_RETURN(ping.t, GetNumberIn(*t, "ping.t", -HUGE_VAL, HUGE_VAL));
  return ClientMessage(std::move(ping));
}

Result<ClientMessage> ParseShareCreate(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "share_create", {"type", "role", "ttl_s"}));
  ShareCreateMessage share;
  OCTO_ASSIGN_OR_RETURN(const Json* role, Require(doc, "share_create", "role"));
  OCTO_ASSIGN_OR_RETURN(share.role, GetGrantableRole(*role, "share_create.role"));
  if (auto it = doc.find("ttl_s"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(share.ttl_s, GetInteger(*it, "share_create.ttl_s", kMinShareTtlSeconds,
                                                  kMaxShareTtlSeconds));
  }
  return ClientMessage(std::move(share));
}

Result<ClientMessage> ParseShareRevoke(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "share_revoke", {"type", "token"}));
  OCTO_ASSIGN_OR_RETURN(const Json* token, Require(doc, "share_revoke", "token"));
  ShareRevokeMessage revoke;
  OCTO_ASSIGN_OR_RETURN(revoke.token,
                        GetString(*token, "share_revoke.token", kMaxShareTokenBytes, true));
  if (revoke.token.empty()) return FieldError("share_revoke.token", "is empty");
  return ClientMessage(std::move(revoke));
}

Result<ClientMessage> ParseParticipantRole(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "participant_role", {"type", "participant", "role"}));
  ParticipantRoleMessage message;
  OCTO_ASSIGN_OR_RETURN(message.participant, GetParticipantId(doc, "participant_role"));
  OCTO_ASSIGN_OR_RETURN(const Json* role, Require(doc, "participant_role", "role"));
  OCTO_ASSIGN_OR_RETURN(message.role, GetGrantableRole(*role, "participant_role.role"));
  return ClientMessage(std::move(message));
}

Result<ClientMessage> ParseKick(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "kick", {"type", "participant"}));
  KickMessage kick;
  OCTO_ASSIGN_OR_RETURN(kick.participant, GetParticipantId(doc, "kick"));
  return ClientMessage(std::move(kick));
}

Result<ClientMessage> ParseViewSave(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "view_save", {"type", "ttl_s"}));
  ViewSaveMessage save;
  if (auto it = doc.find("ttl_s"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(save.ttl_s, GetInteger(*it, "view_save.ttl_s", kMinShareTtlSeconds,
                                                 kMaxShareTtlSeconds));
  }
  return ClientMessage(std::move(save));
}

std::string Number(double v) { return Json(v).dump(); }

std::string ExpiresJson(const std::optional<int64_t>& expires) {
  return expires ? Quote(IsoUtc(*expires)) : std::string("null");
}

std::string ShareFields(const ShareInfo& share) {
  return "\"token\":" + Quote(share.token) + ",\"role\":" + Quote(RoleName(share.role)) +
         ",\"url\":" + Quote(share.url) + ",\"expires\":" + ExpiresJson(share.expires_unix_s);
}

}  // namespace

std::string_view MessageTypeName(const ClientMessage& message) {
  return kTypeNames[message.index()];
}

Result<ClientMessage> ParseClientMessage(std::string_view text, std::string* type) {
  if (type) type->clear();
  OCTO_ASSIGN_OR_RETURN(Json doc, ParseMessageText(text, "message"));
  OCTO_ASSIGN_OR_RETURN(const Json* type_field, Require(doc, "", "type"));
  OCTO_ASSIGN_OR_RETURN(std::string name,
                        GetString(*type_field, "type", kMaxClientStringBytes, false));
  using Parser = Result<ClientMessage> (*)(const Json&);
  static constexpr Parser kParsers[] = {ParseHello,       ParseOpen,
                                        ParseCamera,      ParseParams,
                                        ParseSlices,      ParseViewport,
                                        ParseInteraction, ParseQuality,
                                        ParseAck,         ParseScreenshot,
                                        ParsePing,        ParseShareCreate,
                                        ParseShareRevoke, ParseParticipantRole,
                                        ParseKick,        ParseViewSave};
  static_assert(std::size(kParsers) == std::size(kTypeNames));
  static_assert(std::size(kTypeNames) == std::variant_size_v<ClientMessage>);
  for (size_t i = 0; i < std::size(kTypeNames); ++i) {
    if (name != kTypeNames[i]) continue;
    if (type) *type = name;
    return kParsers[i](doc);
  }
  std::string known;
  for (std::string_view k : kTypeNames) known += (known.empty() ? "" : ", ") + std::string(k);
  return FieldError("type",
                    "unknown message type \"" + Printable(name, 40) + "\" (known: " + known + ")");
}

Result<StateUpdate> ParseStateDocument(std::string_view text, std::string_view path) {
  OCTO_ASSIGN_OR_RETURN(Json doc, ParseMessageText(text, path));
  return StateFromJson(doc, std::string(path));
}

Result<render::RenderParams> ApplyParams(std::string_view params_json,
                                         const render::RenderParams& current) {
  Result<render::RenderParams> params = ParseRenderParamsJson(params_json, current);
  if (!params.ok()) return Reprefix(params.status(), "render parameters: ", "params");
  return params;
}

Result<render::Camera> CameraForSize(const render::Camera& c, int width, int height) {
  return render::Camera::LookAt(c.projection(), c.position(), c.position() + c.forward(), c.up(),
                                width, height, c.fov_y_degrees(), c.ortho_height());
}

PixelSize ViewportPixels(const ViewportMessage& viewport) {
  if (viewport.width <= 0 || viewport.height <= 0) return {};
  double w = std::max(1.0, std::round(viewport.width * viewport.dpr));
  double h = std::max(1.0, std::round(viewport.height * viewport.dpr));
  const double largest = std::max(w, h);
  if (largest > kMaxRenderPixels) {
    // One factor for both axes keeps the aspect ratio.
    const double s = kMaxRenderPixels / largest;
    w = std::clamp(std::round(w * s), 1.0, double{kMaxRenderPixels});
    h = std::clamp(std::round(h * s), 1.0, double{kMaxRenderPixels});
  }
  return {static_cast<int>(w), static_cast<int>(h)};
}

std::string StateJson(const ViewState& state) {
  const auto& p = state.slice_position_um;
  std::string out = "{\"camera\":" + CameraToJson(state.camera) +
                    ",\"params\":" + RenderParamsToJson(state.params) +
                    ",\"slices\":{\"position_um\":[" + Number(p[0]) + "," + Number(p[1]) + "," +
                    Number(p[2]) + "]},\"layout\":{\"maximized\":";
  out += state.maximized ? Quote(ViewName(*state.maximized)) : "null";
  out += "}}";
  return out;
}

std::string WelcomeEvent(std::string_view server_version, std::string_view session_id,
                         std::string_view participant, Role role, std::string_view resume) {
  std::string out = "{\"type\":\"welcome\",\"protocol\":" + std::to_string(kProtocolVersion) +
                    ",\"server\":" + Quote(server_version) + ",\"session\":" + Quote(session_id) +
                    ",\"datasets_url\":\"/api/datasets\",\"participant\":" + Quote(participant) +
                    ",\"role\":" + Quote(RoleName(role));
  if (!resume.empty()) out += ",\"resume\":" + Quote(resume);
  return out + "}";
}

std::string OpenedEvent(std::string_view dataset_json, const ViewState& state, uint64_t version) {
  return "{\"type\":\"opened\",\"dataset\":" + std::string(dataset_json) +
         ",\"state\":" + StateJson(state) + ",\"version\":" + std::to_string(version) + "}";
}

std::string StateEvent(const ViewState& state, uint64_t version, std::string_view by) {
  std::string out = "{\"type\":\"state\",\"version\":" + std::to_string(version) +
                    ",\"state\":" + StateJson(state);
  if (!by.empty()) out += ",\"by\":" + Quote(by);
  return out + "}";
}

std::string_view RoleName(Role role) { return kRoleNames[static_cast<size_t>(role)]; }

bool IsViewLinkId(std::string_view id) {
  return id.size() == kViewLinkIdChars && std::all_of(id.begin(), id.end(), [](char c) {
           return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                  c == '_' || c == '-';
         });
}

bool IsHexKey(std::string_view key) {
  return key.size() == kResumeKeyChars && std::all_of(key.begin(), key.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

std::string ParticipantsEvent(const std::vector<ParticipantInfo>& participants,
                              std::string_view you) {
  std::string out = "{\"type\":\"participants\",\"participants\":[";
  for (size_t i = 0; i < participants.size(); ++i) {
    const ParticipantInfo& p = participants[i];
    out += std::string(i ? "," : "") + "{\"id\":" + Quote(p.id) + ",\"name\":" + Quote(p.name) +
           ",\"role\":" + Quote(RoleName(p.role)) +
           ",\"driving\":" + (p.driving ? "true" : "false") +
           ",\"you\":" + (p.id == you ? "true" : "false") + "}";
  }
  return out + "]}";
}

std::string ShareCreatedEvent(const ShareInfo& share) {
  return "{\"type\":\"share_created\"," + ShareFields(share) + "}";
}

std::string SharesEvent(const std::vector<ShareInfo>& shares) {
  std::string out = "{\"type\":\"shares\",\"shares\":[";
  for (size_t i = 0; i < shares.size(); ++i) {
    out += std::string(i ? "," : "") + "{" + ShareFields(shares[i]) +
           ",\"participants\":" + std::to_string(shares[i].participants) + "}";
  }
  return out + "]}";
}

std::string ViewSavedEvent(std::string_view id, std::string_view url,
                           std::optional<int64_t> expires_unix_s) {
  return "{\"type\":\"view_saved\",\"id\":" + Quote(id) + ",\"url\":" + Quote(url) +
         ",\"expires\":" + ExpiresJson(expires_unix_s) + "}";
}

std::string IsoUtc(int64_t unix_s) {
  const std::time_t t = static_cast<std::time_t>(unix_s);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

std::string ViewLinkJson(std::string_view dataset, const ViewState& state,
                         const ViewLinkGrant& grant) {
  // The camera in its canonical form: CameraToJson of a camera read back from its own JSON may
  // differ in the last digits (target and up are recomputed), so it is read back until the text
  // no longer changes — then opening the link gives a session whose state reads exactly as stored.
  ViewState canonical = state;
  std::string camera = CameraToJson(canonical.camera);
  for (int i = 0; i < 4; ++i) {
    Result<render::Camera> again = ParseCameraJson(camera, render::Projection::kOrthographic, 1, 1);
    if (!again.ok()) break;
    canonical.camera = *again;
    std::string text = CameraToJson(canonical.camera);
    if (text == camera) break;
    camera = std::move(text);
  }
  return "{\"version\":2,\"dataset\":" + Quote(dataset) +
         ",\"creator\":" + Quote(GrantRefText(grant.creator)) +
         ",\"owner\":" + Quote(GrantRefText(grant.owner)) +
         ",\"created\":" + Quote(IsoUtc(grant.created_unix_s)) +
         ",\"expires\":" + ExpiresJson(grant.expires_unix_s) +
         ",\"state\":" + StateJson(canonical) + "}";
}

namespace {

Result<GrantRef> GetGrant(const Json& doc, const char* key) {
  OCTO_ASSIGN_OR_RETURN(const Json* j, Require(doc, "view link", key));
  OCTO_ASSIGN_OR_RETURN(std::string text, GetString(*j, key, 128, true));
  auto grant = ParseGrantRef(text);
  if (!grant.ok()) return FieldError(key, grant.status().message());
  return grant;
}

Result<int64_t> GetTime(const Json& j, const char* key) {
  OCTO_ASSIGN_OR_RETURN(std::string text, GetString(j, key, 64, true));
  return ParseRfc3339Utc(text, key);
}

}  // namespace

Result<ViewLink> ParseViewLink(std::string_view text) {
  // Stored documents are small; the message limits bound them too.
  OCTO_ASSIGN_OR_RETURN(Json doc, ParseMessageText(text, "view link"));
  OCTO_ASSIGN_OR_RETURN(const Json* version, Require(doc, "view link", "version"));
  OCTO_ASSIGN_OR_RETURN(int64_t v, GetInteger(*version, "version", 1, 2));
  if (v == 1) {
    OCTO_RETURN_IF_ERROR(CheckKeys(doc, "view link", {"version", "dataset", "state"}));
  } else {
    OCTO_RETURN_IF_ERROR(CheckKeys(
        doc, "view link",
        {"version", "dataset", "creator", "owner", "created", "expires", "state"}));
  }
  ViewLink link;
  OCTO_ASSIGN_OR_RETURN(const Json* dataset, Require(doc, "view link", "dataset"));
  OCTO_ASSIGN_OR_RETURN(link.dataset, GetString(*dataset, "dataset", kMaxDatasetIdBytes, true));
  if (!IsDatasetId(link.dataset)) return FieldError("dataset", "is not a dataset id");
  if (v == 2) {
    ViewLinkGrant grant;
    OCTO_ASSIGN_OR_RETURN(grant.creator, GetGrant(doc, "creator"));
    OCTO_ASSIGN_OR_RETURN(grant.owner, GetGrant(doc, "owner"));
    if (grant.owner.kind != GrantRef::Kind::kUser) return FieldError("owner", "is not a user");
    OCTO_ASSIGN_OR_RETURN(const Json* created, Require(doc, "view link", "created"));
    OCTO_ASSIGN_OR_RETURN(grant.created_unix_s, GetTime(*created, "created"));
    OCTO_ASSIGN_OR_RETURN(const Json* expires, Require(doc, "view link", "expires"));
    if (!expires->is_null()) {
      OCTO_ASSIGN_OR_RETURN(grant.expires_unix_s, GetTime(*expires, "expires"));
    }
    link.grant = std::move(grant);
  }
  OCTO_ASSIGN_OR_RETURN(const Json* state, Require(doc, "view link", "state"));
  OCTO_ASSIGN_OR_RETURN(link.state, StateFromJson(*state, "state"));
  if (!link.state.camera || !link.state.params_json || !link.state.slice_position_um ||
      !link.state.layout) {
    return FieldError("state", "must hold camera, params, slices and layout");
  }
  return link;
}

std::string DatasetEvent(std::string_view dataset_json) {
  return "{\"type\":\"dataset\",\"dataset\":" + std::string(dataset_json) + "}";
}

std::string ErrorEvent(std::string_view message, std::string_view request, bool fatal) {
  std::string out = "{\"type\":\"error\",\"message\":" + Quote(OneLine(message, 1000));
  if (!request.empty()) out += ",\"request\":" + Quote(request);
  out += std::string(",\"fatal\":") + (fatal ? "true" : "false") + "}";
  return out;
}

std::string PongEvent(double t) {
  return "{\"type\":\"pong\",\"t\":" + (std::isfinite(t) ? Number(t) : std::string("null")) + "}";
}

std::string StatsEvent(const ConnectionStats& s) {
  return "{\"type\":\"stats\",\"frames_sent\":" + std::to_string(s.frames_sent) +
         ",\"frames_dropped\":" + std::to_string(s.frames_dropped) +
         ",\"bytes_sent\":" + std::to_string(s.bytes_sent) +
         ",\"bricks_pending\":" + std::to_string(s.bricks_pending) + "}";
}

}  // namespace octoscope::protocol
