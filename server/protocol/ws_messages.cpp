#include "protocol/ws_messages.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <utility>

#include "octree/brick_geometry.h"
#include "protocol/strict_json.h"
#include "protocol/render_json.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using json_fields::CheckKeys;
using json_fields::CheckObject;
using json_fields::FieldError;
using json_fields::Join;
using json_fields::Json;
using json_fields::Quote;

constexpr json_fields::ParseLimits kMessageLimits{kMaxClientMessageBytes, kMaxClientMessageDepth,
                                                  kMaxClientStringBytes};

constexpr std::string_view kTypeNames[] = {"hello",    "open",        "camera",      "params",
                                           "slices",   "viewport",    "interaction", "quality",
                                           "ack",      "screenshot",  "ping"};

// Rewrites an error of a render_json parser ("position: must be ...", "camera: missing ...",
// "unknown key ...") so that it names the field from the message's root ("camera.position: ...").
Status Reprefix(const Status& status, std::string_view strip, std::string_view path) {
  std::string_view m = status.message();
  if (m.starts_with(strip)) m.remove_prefix(strip.size());
  const size_t colon = m.find(": ");
  const std::string_view head = m.substr(0, colon == std::string_view::npos ? 0 : colon);
  const bool starts_with_field = !head.empty() && head.find_first_of(" \"") == std::string::npos;
  return InvalidArgumentError(std::string(path) + (starts_with_field ? "." : ": ") +
                              std::string(m));
}

Result<ViewId> GetView(const Json& j, std::string_view path) {
  OCTO_ASSIGN_OR_RETURN(std::string name, json_fields::GetString(j, path, 16, true));
  std::optional<ViewId> view = ViewFromName(name);
  if (!view) return FieldError(path, "is \"" + Printable(name, 16) + "\", expected 3d, x, y or z");
  return *view;
}

Result<render::Camera> CameraFromJson(const Json& j, std::string_view path) {
  OCTO_RETURN_IF_ERROR(CheckObject(j, path));
  Result<render::Camera> camera =
      ParseCameraJson(json_fields::Dump(j), render::Projection::kOrthographic, 1, 1);
  if (!camera.ok()) return Reprefix(camera.status(), "camera: ", path);
  return camera;
}

// Validates a render-parameter document as far as it can be without the dataset: every field,
// against defaults with as many channels as the document lists.
Result<std::string> ParamsFromJson(const Json& j, std::string_view path) {
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
  std::string text = json_fields::Dump(j);
  const render::RenderParams defaults =
      render::DefaultRenderParams(channels, volume::DataType::kUint16, render::RenderMode::kDvr);
  Result<render::RenderParams> params = ParseRenderParamsJson(text, defaults);
  if (!params.ok()) return Reprefix(params.status(), "render parameters: ", path);
  return text;
}

Result<StateUpdate> StateFromJson(const Json& j, std::string_view path) {
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
      OCTO_ASSIGN_OR_RETURN(state.slice_position_um,
                            json_fields::GetNumber3(*p, Join(slices, "position_um"),
                                                    -kMaxCoordinateUm, kMaxCoordinateUm));
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

// One parser per message type; `doc` has been checked to be an object with this "type".
Result<ClientMessage> ParseHello(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "hello", {"type", "client", "protocol"}));
  OCTO_ASSIGN_OR_RETURN(const Json* protocol, json_fields::Require(doc, "hello", "protocol"));
  OCTO_ASSIGN_OR_RETURN(int64_t version,
                        json_fields::GetInteger(*protocol, "hello.protocol", 0, INT32_MAX));
  if (version != kProtocolVersion) {
    return FieldError("hello.protocol", "is " + std::to_string(version) +
                                            ", this server speaks protocol " +
                                            std::to_string(kProtocolVersion));
  }
  HelloMessage hello;
  if (auto it = doc.find("client"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(hello.client,
                          json_fields::GetString(*it, "hello.client", kMaxClientNameBytes, true));
  }
  return ClientMessage(std::move(hello));
}

Result<ClientMessage> ParseOpen(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "open", {"type", "dataset", "state"}));
  OCTO_ASSIGN_OR_RETURN(const Json* dataset, json_fields::Require(doc, "open", "dataset"));
  OpenMessage open;
  OCTO_ASSIGN_OR_RETURN(open.dataset,
                        json_fields::GetString(*dataset, "open.dataset", kMaxDatasetIdBytes, true));
  const bool valid_id = !open.dataset.empty() &&
                        std::all_of(open.dataset.begin(), open.dataset.end(), [](char c) {
                          return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
                                 c == '-';
                        });
  if (!valid_id) {
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
  OCTO_ASSIGN_OR_RETURN(const Json* camera, json_fields::Require(doc, "camera", "camera"));
  OCTO_ASSIGN_OR_RETURN(render::Camera parsed, CameraFromJson(*camera, "camera.camera"));
  return ClientMessage(CameraMessage{std::move(parsed)});
}

Result<ClientMessage> ParseParams(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "params", {"type", "params"}));
  OCTO_ASSIGN_OR_RETURN(const Json* params, json_fields::Require(doc, "params", "params"));
  OCTO_ASSIGN_OR_RETURN(std::string text, ParamsFromJson(*params, "params.params"));
  return ClientMessage(ParamsMessage{std::move(text)});
}

Result<ClientMessage> ParseSlices(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "slices", {"type", "position_um"}));
  OCTO_ASSIGN_OR_RETURN(const Json* position, json_fields::Require(doc, "slices", "position_um"));
  SlicesMessage slices;
  OCTO_ASSIGN_OR_RETURN(slices.position_um,
                        json_fields::GetNumber3(*position, "slices.position_um",
                                                -kMaxCoordinateUm, kMaxCoordinateUm));
  return ClientMessage(std::move(slices));
}

Result<ClientMessage> ParseViewport(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "viewport", {"type", "view", "width", "height", "dpr"}));
  ViewportMessage viewport;
  OCTO_ASSIGN_OR_RETURN(const Json* view, json_fields::Require(doc, "viewport", "view"));
  OCTO_ASSIGN_OR_RETURN(viewport.view, GetView(*view, "viewport.view"));
  OCTO_ASSIGN_OR_RETURN(const Json* width, json_fields::Require(doc, "viewport", "width"));
  OCTO_ASSIGN_OR_RETURN(int64_t w,
                        json_fields::GetInteger(*width, "viewport.width", 0, kMaxViewportCssPixels));
  OCTO_ASSIGN_OR_RETURN(const Json* height, json_fields::Require(doc, "viewport", "height"));
  OCTO_ASSIGN_OR_RETURN(
      int64_t h, json_fields::GetInteger(*height, "viewport.height", 0, kMaxViewportCssPixels));
  viewport.width = static_cast<int>(w);
  viewport.height = static_cast<int>(h);
  if (auto it = doc.find("dpr"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(viewport.dpr, json_fields::GetNumber(*it, "viewport.dpr",
                                                               kMinDevicePixelRatio,
                                                               kMaxDevicePixelRatio));
  }
  return ClientMessage(std::move(viewport));
}

Result<ClientMessage> ParseInteraction(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "interaction", {"type", "active"}));
  OCTO_ASSIGN_OR_RETURN(const Json* active, json_fields::Require(doc, "interaction", "active"));
  InteractionMessage interaction;
  OCTO_ASSIGN_OR_RETURN(interaction.active, json_fields::GetBool(*active, "interaction.active"));
  return ClientMessage(std::move(interaction));
}

Result<ClientMessage> ParseQuality(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(
      doc, "quality", {"type", "jpeg_interactive", "jpeg_final", "lossless_final", "lod_bias"}));
  QualityMessage quality;
  if (auto it = doc.find("jpeg_interactive"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t q, json_fields::GetInteger(*it, "quality.jpeg_interactive",
                                                             kMinJpegInteractive,
                                                             kMaxJpegInteractive));
    quality.jpeg_interactive = static_cast<int>(q);
  }
  if (auto it = doc.find("jpeg_final"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t q, json_fields::GetInteger(*it, "quality.jpeg_final",
                                                             kMinJpegFinal, kMaxJpegFinal));
    quality.jpeg_final = static_cast<int>(q);
  }
  if (auto it = doc.find("lossless_final"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(quality.lossless_final,
                          json_fields::GetBool(*it, "quality.lossless_final"));
  }
  if (auto it = doc.find("lod_bias"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(quality.lod_bias, json_fields::GetNumber(*it, "quality.lod_bias",
                                                                   kMinLodBias, kMaxLodBias));
  }
  return ClientMessage(std::move(quality));
}

Result<ClientMessage> ParseAck(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "ack", {"type", "frame"}));
  OCTO_ASSIGN_OR_RETURN(const Json* frame, json_fields::Require(doc, "ack", "frame"));
  OCTO_ASSIGN_OR_RETURN(int64_t id, json_fields::GetInteger(*frame, "ack.frame", 1,
                                                            static_cast<int64_t>(kMaxSafeInteger)));
  return ClientMessage(AckMessage{static_cast<uint64_t>(id)});
}

Result<ClientMessage> ParseScreenshot(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "screenshot", {"type", "view", "scale", "id"}));
  ScreenshotMessage shot;
  OCTO_ASSIGN_OR_RETURN(const Json* view, json_fields::Require(doc, "screenshot", "view"));
  OCTO_ASSIGN_OR_RETURN(shot.view, GetView(*view, "screenshot.view"));
  if (auto it = doc.find("scale"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(int64_t scale, json_fields::GetInteger(*it, "screenshot.scale", 1, 2));
    shot.scale = static_cast<int>(scale);
  }
  OCTO_ASSIGN_OR_RETURN(const Json* id, json_fields::Require(doc, "screenshot", "id"));
  OCTO_ASSIGN_OR_RETURN(int64_t value, json_fields::GetInteger(*id, "screenshot.id", 0, UINT32_MAX));
  shot.id = static_cast<uint32_t>(value);
  return ClientMessage(std::move(shot));
}

Result<ClientMessage> ParsePing(const Json& doc) {
  OCTO_RETURN_IF_ERROR(CheckKeys(doc, "ping", {"type", "t"}));
  OCTO_ASSIGN_OR_RETURN(const Json* t, json_fields::Require(doc, "ping", "t"));
  PingMessage ping;
  OCTO_ASSIGN_OR_RETURN(ping.t, json_fields::GetNumber(*t, "ping.t", -HUGE_VAL, HUGE_VAL));
  return ClientMessage(std::move(ping));
}

std::string Number(double v) { return Json(v).dump(); }


}  // namespace

std::string_view MessageTypeName(const ClientMessage& message) {
  return kTypeNames[message.index()];
}

Result<ClientMessage> ParseClientMessage(std::string_view text, std::string* type) {
  if (type) type->clear();
  OCTO_ASSIGN_OR_RETURN(Json doc, json_fields::ParseObject(text, "message", kMessageLimits));
  OCTO_ASSIGN_OR_RETURN(const Json* type_field, json_fields::Require(doc, "", "type"));
  OCTO_ASSIGN_OR_RETURN(std::string name,
                        json_fields::GetString(*type_field, "type", kMaxClientStringBytes, false));
  using Parser = Result<ClientMessage> (*)(const Json&);
  static constexpr Parser kParsers[] = {ParseHello,       ParseOpen,    ParseCamera, ParseParams,
                                        ParseSlices,      ParseViewport, ParseInteraction,
                                        ParseQuality,     ParseAck,     ParseScreenshot,
                                        ParsePing};
  static_assert(std::size(kParsers) == std::size(kTypeNames));
  static_assert(std::size(kTypeNames) == std::variant_size_v<ClientMessage>);
  for (size_t i = 0; i < std::size(kTypeNames); ++i) {
    if (name != kTypeNames[i]) continue;
    if (type) *type = name;
    return kParsers[i](doc);
  }
  std::string known;
  for (std::string_view k : kTypeNames) known += (known.empty() ? "" : ", ") + std::string(k);
  return FieldError("type", "unknown message type \"" + Printable(name, 40) + "\" (known: " +
                                known + ")");
}

Result<StateUpdate> ParseStateDocument(std::string_view text, std::string_view path) {
  OCTO_ASSIGN_OR_RETURN(Json doc, json_fields::ParseObject(text, path, kMessageLimits));
  return StateFromJson(doc, path);
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

std::string WelcomeEvent(std::string_view server_version, std::string_view session_id) {
  return "{\"type\":\"welcome\",\"protocol\":" + std::to_string(kProtocolVersion) +
         ",\"server\":" + Quote(server_version) + ",\"session\":" + Quote(session_id) +
         ",\"datasets_url\":\"/api/datasets\"}";
}

std::string OpenedEvent(std::string_view dataset_json, const ViewState& state, uint64_t version) {
  return "{\"type\":\"opened\",\"dataset\":" + std::string(dataset_json) +
         ",\"state\":" + StateJson(state) + ",\"version\":" + std::to_string(version) + "}";
}

std::string StateEvent(const ViewState& state, uint64_t version) {
  return "{\"type\":\"state\",\"version\":" + std::to_string(version) +
         ",\"state\":" + StateJson(state) + "}";
}

std::string DatasetEvent(std::string_view dataset_json) {
  return "{\"type\":\"dataset\",\"dataset\":" + std::string(dataset_json) + "}";
}

std::string ErrorEvent(std::string_view message, std::string_view request, bool fatal) {
  std::string out =
      "{\"type\":\"error\",\"message\":" + Quote(json_fields::OneLine(message, 1000));
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
