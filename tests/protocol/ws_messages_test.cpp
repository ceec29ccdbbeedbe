// The WebSocket messages of docs/protocol.md: every client message type parsed, every kind of
// bad input refused with an error naming the message type and field, the limits, the state
// document's round trip and the server's events (checked with an independent JSON parser).
#include "protocol/ws_messages.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <variant>

#include "protocol/render_json.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

// The message of type T that `text` parses to; a test failure (thrown, so that the test stops)
// otherwise.
template <typename T>
T ParseAs(const std::string& text) {
  std::string type;
  Result<ClientMessage> m = ParseClientMessage(text, &type);
  if (!m.ok() || !std::holds_alternative<T>(*m)) {
    throw std::runtime_error(text + ": " + m.status().ToString());
  }
  EXPECT_EQ(MessageTypeName(*m), type);
  return std::get<T>(*m);
}

TEST(WsMessagesTest, ParsesEveryMessageType) {
  EXPECT_EQ(ParseAs<HelloMessage>(R"({"type":"hello","client":"web 1.0","protocol":1})").client,
            "web 1.0");
  EXPECT_EQ(ParseAs<HelloMessage>(R"({"type":"hello","protocol":1})").client, "");

  const OpenMessage open = ParseAs<OpenMessage>(
      R"({"type":"open","dataset":"a3f09c21d4e1","state":{"slices":{"position_um":[1,2.5,-3]},
          "layout":{"maximized":"y"}}})");
  EXPECT_EQ(open.dataset, "a3f09c21d4e1");
  ASSERT_TRUE(open.state.has_value());
  ASSERT_TRUE(open.state->slice_position_um.has_value());
  EXPECT_EQ((*open.state->slice_position_um)[1], 2.5);
  ASSERT_TRUE(open.state->layout.has_value());
  EXPECT_EQ(open.state->layout->maximized, ViewId::kY);
  EXPECT_FALSE(open.state->camera.has_value());
  EXPECT_FALSE(ParseAs<OpenMessage>(R"({"type":"open","dataset":"demo"})").state.has_value());

  const CameraMessage camera = ParseAs<CameraMessage>(
      R"({"type":"camera","camera":{"projection":"perspective","position":[0,0,-100],
          "target":[0,0,0],"up":[0,1,0],"fov_y_degrees":40}})");
  EXPECT_EQ(camera.camera.projection(), render::Projection::kPerspective);
  EXPECT_EQ(camera.camera.position().z, -100);
  EXPECT_NEAR(camera.camera.forward().z, 1, 1e-12);
  EXPECT_EQ(camera.camera.fov_y_degrees(), 40);

  const ParamsMessage params =
      ParseAs<ParamsMessage>(R"({"type":"params","params":{"mode":"mip","step_voxels":0.5}})");
  const render::RenderParams current =
      render::DefaultRenderParams(2, volume::DataType::kUint16, render::RenderMode::kDvr);
  Result<render::RenderParams> applied = ApplyParams(params.params_json, current);
  ASSERT_TRUE(applied.ok()) << applied.status().ToString();
  EXPECT_EQ(applied->mode, render::RenderMode::kMip);
  EXPECT_EQ(applied->step_voxels, 0.5);
  EXPECT_EQ(applied->channels.size(), 2u);  // Keys left out keep their values.

  const SlicesMessage slices =
      ParseAs<SlicesMessage>(R"({"type":"slices","position_um":[10, 20.25, 1e3]})");
  EXPECT_EQ(slices.position_um[0], 10);
  EXPECT_EQ(slices.position_um[1], 20.25);
  EXPECT_EQ(slices.position_um[2], 1000);

  const ViewportMessage viewport = ParseAs<ViewportMessage>(
      R"({"type":"viewport","view":"x","width":800,"height":600,"dpr":2})");
  EXPECT_EQ(viewport.view, ViewId::kX);
  EXPECT_EQ(viewport.width, 800);
  EXPECT_EQ(viewport.height, 600);
  EXPECT_EQ(viewport.dpr, 2);
  EXPECT_EQ(ParseAs<ViewportMessage>(R"({"type":"viewport","view":"3d","width":0,"height":0})").dpr,
            1);

  EXPECT_TRUE(ParseAs<InteractionMessage>(R"({"type":"interaction","active":true})").active);
  EXPECT_FALSE(ParseAs<InteractionMessage>(R"({"type":"interaction","active":false})").active);

  const QualityMessage quality = ParseAs<QualityMessage>(
      R"({"type":"quality","jpeg_interactive":60,"jpeg_final":100,"lossless_final":true,
          "lod_bias":-1.5})");
  EXPECT_EQ(quality.jpeg_interactive, 60);
  EXPECT_EQ(quality.jpeg_final, 100);
  EXPECT_EQ(quality.lossless_final, true);
  EXPECT_EQ(quality.lod_bias, -1.5);
  const QualityMessage partial = ParseAs<QualityMessage>(R"({"type":"quality"})");
  EXPECT_FALSE(partial.jpeg_interactive || partial.jpeg_final || partial.lossless_final ||
               partial.lod_bias);

  EXPECT_EQ(ParseAs<AckMessage>(R"({"type":"ack","frame":9007199254740991})").frame,
            kMaxSafeInteger);

  const ScreenshotMessage shot =
      ParseAs<ScreenshotMessage>(R"({"type":"screenshot","view":"z","scale":2,"id":4294967295})");
  EXPECT_EQ(shot.view, ViewId::kZ);
  EXPECT_EQ(shot.scale, 2);
  EXPECT_EQ(shot.id, 4294967295u);
  EXPECT_EQ(ParseAs<ScreenshotMessage>(R"({"type":"screenshot","view":"3d","id":0})").scale, 1);

  EXPECT_EQ(ParseAs<PingMessage>(R"({"type":"ping","t":1732521600123.5})").t, 1732521600123.5);
}

struct Bad {
  std::string text;
  std::string type;  // The type reported for the error event ("" when unknown).
  std::string says;  // A substring of the error: the field path and the problem.
};

TEST(WsMessagesTest, BadMessagesAreRefusedNamingTypeAndField) {
  const Bad bad[] = {
      // Not a message at all.
      {"", "", "not valid JSON"},
      {"{\"type\":\"ping\",\"t\":1", "", "not valid JSON"},
      {"[1,2]", "", "must be a JSON object"},
      {"\"ping\"", "", "must be a JSON object"},
      {R"({"t":1})", "", "type: missing"},
      {R"({"type":7})", "", "type: must be a string"},
      {R"({"type":"pong","t":1})", "", "unknown message type \"pong\""},
      {R"({"type":"Ping","t":1})", "", "unknown message type"},
      // Unknown fields.
      {R"({"type":"ping","t":1,"x":2})", "ping", "unknown key \"x\" in ping"},
      {R"({"type":"viewport","view":"3d","width":1,"height":1,"DPR":2})", "viewport",
       "unknown key \"DPR\" in viewport"},
      {R"({"type":"open","dataset":"d","state":{"cam":{}}})", "open",
       "unknown key \"cam\" in open.state"},
      {R"({"type":"open","dataset":"d","state":{"slices":{"pos":[1,2,3]}}})", "open",
       "unknown key \"pos\" in open.state.slices"},
      {R"({"type":"camera","camera":{"position":[0,0,1],"target":[0,0,0],"zoom":2}})", "camera",
       "camera.camera: unknown key \"zoom\""},
      {R"({"type":"params","params":{"mode":"mip","gain":2}})", "params",
       "params.params: unknown key \"gain\""},
      // Missing fields.
      {R"({"type":"hello"})", "hello", "hello.protocol: missing"},
      {R"({"type":"open"})", "open", "open.dataset: missing"},
      {R"({"type":"viewport","view":"3d","width":1})", "viewport", "viewport.height: missing"},
      {R"({"type":"ack"})", "ack", "ack.frame: missing"},
      {R"({"type":"screenshot","view":"3d"})", "screenshot", "screenshot.id: missing"},
      {R"({"type":"interaction"})", "interaction", "interaction.active: missing"},
      // Wrong JSON types.
      {R"({"type":"ping","t":"1"})", "ping", "ping.t: must be a number"},
      {R"({"type":"interaction","active":1})", "interaction", "interaction.active: must be true"},
      {R"({"type":"viewport","view":3,"width":1,"height":1})", "viewport",
       "viewport.view: must be a string"},
      {R"({"type":"viewport","view":"3d","width":1.5,"height":1})", "viewport",
       "viewport.width: must be an integer"},
      {R"({"type":"ack","frame":2.0})", "ack", "ack.frame: must be an integer"},
      {R"({"type":"ack","frame":1e3})", "ack", "ack.frame: must be an integer"},
      {R"({"type":"slices","position_um":[1,2]})", "slices", "slices.position_um: must have 3"},
      {R"({"type":"slices","position_um":[1,"2",3]})", "slices", "slices.position_um[1]"},
      {R"({"type":"open","dataset":"d","state":[]})", "open", "open.state: must be an object"},
      {R"({"type":"camera","camera":[0,0,1]})", "camera", "camera.camera: must be an object"},
      {R"({"type":"quality","lossless_final":"yes"})", "quality", "quality.lossless_final"},
      // Out-of-range values.
      {R"({"type":"hello","protocol":2})", "hello", "hello.protocol: is 2"},
      {R"({"type":"viewport","view":"w","width":1,"height":1})", "viewport",
       "viewport.view: is \"w\""},
      {R"({"type":"viewport","view":"3d","width":8193,"height":1})", "viewport",
       "viewport.width: is 8193"},
      {R"({"type":"viewport","view":"3d","width":-1,"height":1})", "viewport", "viewport.width"},
      {R"({"type":"viewport","view":"3d","width":1,"height":1,"dpr":4.5})", "viewport",
       "viewport.dpr: is 4.5"},
      {R"({"type":"viewport","view":"3d","width":1,"height":1,"dpr":0.25})", "viewport",
       "viewport.dpr"},
      {R"({"type":"quality","jpeg_interactive":96})", "quality", "quality.jpeg_interactive"},
      {R"({"type":"quality","jpeg_final":49})", "quality", "quality.jpeg_final"},
      {R"({"type":"quality","lod_bias":5})", "quality", "quality.lod_bias"},
      {R"({"type":"ack","frame":0})", "ack", "ack.frame: is 0"},
      {R"({"type":"ack","frame":9007199254740992})", "ack", "ack.frame"},
      {R"({"type":"ack","frame":18446744073709551615})", "ack", "ack.frame"},
      {R"({"type":"ack","frame":-1})", "ack", "ack.frame"},
      {R"({"type":"screenshot","view":"3d","scale":3,"id":1})", "screenshot", "screenshot.scale"},
      {R"({"type":"screenshot","view":"3d","id":4294967296})", "screenshot", "screenshot.id"},
      {R"({"type":"slices","position_um":[1,2,1e300]})", "slices", "slices.position_um[2]"},
      {R"({"type":"open","dataset":""})", "open", "open.dataset"},
      {R"({"type":"open","dataset":"../etc"})", "open", "open.dataset"},
      {R"({"type":"open","dataset":"A"})", "open", "open.dataset"},
      {R"({"type":"hello","client":"a\nb","protocol":1})", "hello", "hello.client"},
      {R"({"type":"open","dataset":"d","state":{"layout":{"maximized":"w"}}})", "open",
       "open.state.layout.maximized"},
      // Documents the render JSON parser checks, named from the message's root.
      {R"({"type":"camera","camera":{"position":[0,0,0],"target":[0,0,0]}})", "camera",
       "camera.camera"},
      {R"({"type":"params","params":{"mode":"xray"}})", "params", "params.params.mode"},
      {R"({"type":"params","params":{"step_voxels":-1}})", "params", "params.params"},
      // Parser limits.
      {R"({"type":"ping","t":1,"t":2})", "", "duplicate key \"t\""},
  };
  for (const Bad& b : bad) {
    std::string type = "stale";
    Result<ClientMessage> m = ParseClientMessage(b.text, &type);
    ASSERT_FALSE(m.ok()) << b.text;
    EXPECT_EQ(m.status().code(), StatusCode::kInvalidArgument) << b.text;
    EXPECT_NE(m.status().message().find(b.says), std::string::npos)
        << b.text << "\n  got: " << m.status().message() << "\n  expected: " << b.says;
    EXPECT_EQ(type, b.type) << b.text;
  }
}

TEST(WsMessagesTest, SizeNestingAndStringLimits) {
  // 64 KiB of text is the largest message.
  std::string ok = R"({"type":"hello","protocol":1,"client":"x"})";
  ok.append(kMaxClientMessageBytes - ok.size(), ' ');
  EXPECT_TRUE(ParseClientMessage(ok).ok());
  ok.push_back(' ');
  Result<ClientMessage> big = ParseClientMessage(ok);
  ASSERT_FALSE(big.ok());
  EXPECT_NE(big.status().message().find("65537 bytes"), std::string::npos)
      << big.status().ToString();

  // Nesting: 32 levels are parsed (and then refused by the schema), 33 are refused by the parser.
  auto nested = [](int levels) {
    std::string s = R"({"type":"ping","t":1,"x":)";
    for (int i = 1; i < levels; ++i) s += "[";
    for (int i = 1; i < levels; ++i) s += "]";
    return s + "}";
  };
  Result<ClientMessage> deep32 = ParseClientMessage(nested(kMaxClientMessageDepth));
  ASSERT_FALSE(deep32.ok());
  EXPECT_NE(deep32.status().message().find("unknown key"), std::string::npos)
      << deep32.status().ToString();
  Result<ClientMessage> deep33 = ParseClientMessage(nested(kMaxClientMessageDepth + 1));
  ASSERT_FALSE(deep33.ok());
  EXPECT_NE(deep33.status().message().find("nested too deeply"), std::string::npos)
      << deep33.status().ToString();
  // A million brackets cost no recursion.
  EXPECT_FALSE(ParseClientMessage(std::string(60000, '[')).ok());

  // Strings (and keys) of at most 4096 bytes.
  const std::string s4096(kMaxClientStringBytes, 'a');
  Result<ClientMessage> long_ok =
      ParseClientMessage(R"({"type":"ping","t":1,")" + s4096 + R"(":1})");
  ASSERT_FALSE(long_ok.ok());
  EXPECT_NE(long_ok.status().message().find("unknown key"), std::string::npos);
  Result<ClientMessage> long_key =
      ParseClientMessage(R"({"type":"ping","t":1,")" + s4096 + R"(a":1})");
  ASSERT_FALSE(long_key.ok());
  EXPECT_NE(long_key.status().message().find("longer than 4096"), std::string::npos);
  Result<ClientMessage> long_value =
      ParseClientMessage(R"({"type":"ping","t":1,"x":")" + s4096 + R"(a"})");
  ASSERT_FALSE(long_value.ok());
  EXPECT_NE(long_value.status().message().find("longer than 4096"), std::string::npos);
  // The client name has its own, smaller limit.
  EXPECT_FALSE(ParseClientMessage(R"({"type":"hello","protocol":1,"client":")" +
                                  std::string(kMaxClientNameBytes + 1, 'c') + R"("})")
                   .ok());

  // Invalid UTF-8 is refused by the parser, never passed on.
  EXPECT_FALSE(ParseClientMessage("{\"type\":\"hello\",\"protocol\":1,\"client\":\"\xff\"}").ok());
  // Error messages quote untrusted text shortened and escaped.
  Result<ClientMessage> unknown =
      ParseClientMessage(R"({"type":")" + std::string(3000, 'z') + "\\n\"}");
  ASSERT_FALSE(unknown.ok());
  EXPECT_LT(unknown.status().message().size(), 300u);
  EXPECT_EQ(unknown.status().message().find('\n'), std::string::npos);
}

TEST(WsMessagesTest, ViewportPixels) {
  auto pixels = [](int w, int h, double dpr) {
    const PixelSize p = ViewportPixels(ViewportMessage{ViewId::k3d, w, h, dpr});
    return std::make_pair(p.width, p.height);
  };
  EXPECT_EQ(pixels(1280, 720, 2), std::make_pair(2560, 1440));
  EXPECT_EQ(pixels(1280, 720, 1.25), std::make_pair(1600, 900));
  EXPECT_EQ(pixels(801, 601, 0.5), std::make_pair(401, 301));  // round(400.5) = 401.
  EXPECT_EQ(pixels(0, 720, 2), std::make_pair(0, 0));          // Not rendered.
  EXPECT_EQ(pixels(1, 1, 0.5), std::make_pair(1, 1));          // Never below 1 x 1.
  // Capped at 4096 per axis, aspect kept.
  EXPECT_EQ(pixels(8192, 100, 4), std::make_pair(4096, 50));
  EXPECT_EQ(pixels(3000, 1500, 2), std::make_pair(4096, 2048));
  EXPECT_EQ(pixels(8192, 1, 4), std::make_pair(4096, 1));
}

render::Camera TestCamera(render::Projection projection) {
  Result<render::Camera> c =
      render::Camera::LookAt(projection, {10, 20, -300}, {10, 20, 0}, {0, -1, 0}, 1, 1, 35, 250);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return *c;
}

TEST(WsMessagesTest, StateDocumentRoundTrips) {
  render::RenderParams params =
      render::DefaultRenderParams(3, volume::DataType::kUint16, render::RenderMode::kMip);
  params.step_voxels = 0.75;
  params.channels[1].enabled = false;
  const ViewState state{
      TestCamera(render::Projection::kPerspective), params, {1.5, -2, 300}, ViewId::kZ};
  const std::string text = StateJson(state);
  // An independent parser sees the documented shape.
  const json doc = json::parse(text);
  EXPECT_TRUE(doc["camera"].is_object());
  EXPECT_TRUE(doc["params"].is_object());
  EXPECT_EQ(doc["slices"]["position_um"], json::parse("[1.5,-2.0,300.0]"));
  EXPECT_EQ(doc["layout"]["maximized"], "z");

  Result<StateUpdate> back = ParseStateDocument(text);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_TRUE(back->camera && back->params_json && back->slice_position_um && back->layout);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(back->camera->position()[i], state.camera.position()[i], 1e-9);
    EXPECT_NEAR(back->camera->forward()[i], state.camera.forward()[i], 1e-12);
    EXPECT_NEAR(back->camera->up()[i], state.camera.up()[i], 1e-12);
  }
  EXPECT_EQ(back->camera->projection(), render::Projection::kPerspective);
  EXPECT_NEAR(back->camera->fov_y_degrees(), 35, 1e-12);
  EXPECT_EQ(*back->slice_position_um, state.slice_position_um);
  EXPECT_EQ(back->layout->maximized, ViewId::kZ);
  Result<render::RenderParams> params_back = ApplyParams(
      *back->params_json,
      render::DefaultRenderParams(3, volume::DataType::kUint16, render::RenderMode::kDvr));
  ASSERT_TRUE(params_back.ok()) << params_back.status().ToString();
  EXPECT_EQ(RenderParamsToJson(*params_back), RenderParamsToJson(params));

  // No maximised view is null; null reads back as none.
  const ViewState plain{
      TestCamera(render::Projection::kOrthographic), params, {0, 0, 0}, std::nullopt};
  EXPECT_TRUE(json::parse(StateJson(plain))["layout"]["maximized"].is_null());
  Result<StateUpdate> plain_back = ParseStateDocument(StateJson(plain));
  ASSERT_TRUE(plain_back.ok());
  EXPECT_FALSE(plain_back->layout->maximized.has_value());

  // Parameters that do not fit the dataset are refused when applied, naming the field.
  Result<render::RenderParams> wrong_channels = ApplyParams(
      *back->params_json,
      render::DefaultRenderParams(2, volume::DataType::kUint16, render::RenderMode::kDvr));
  ASSERT_FALSE(wrong_channels.ok());
  EXPECT_EQ(wrong_channels.status().message().rfind("params", 0), 0u)
      << wrong_channels.status().ToString();
}

TEST(WsMessagesTest, CameraForSizeKeepsThePoseAndTakesTheSize) {
  const render::Camera c = TestCamera(render::Projection::kOrthographic);
  Result<render::Camera> sized = CameraForSize(c, 640, 480);
  ASSERT_TRUE(sized.ok()) << sized.status().ToString();
  EXPECT_EQ(sized->width(), 640);
  EXPECT_EQ(sized->height(), 480);
  EXPECT_EQ(sized->position(), c.position());
  EXPECT_EQ(sized->ortho_height(), c.ortho_height());
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(sized->forward()[i], c.forward()[i], 1e-12);
}

TEST(WsMessagesTest, EventsAreTheDocumentedJson) {
  const json welcome = json::parse(WelcomeEvent("0.1.0", "s-17"));
  EXPECT_EQ(welcome, json::parse(R"({"type":"welcome","protocol":1,"server":"0.1.0",
                                     "session":"s-17","datasets_url":"/api/datasets",
                                     "participant":"p1","role":"owner"})"));

  const ViewState state{
      TestCamera(render::Projection::kOrthographic),
      render::DefaultRenderParams(1, volume::DataType::kUint8, render::RenderMode::kDvr),
      {1, 2, 3},
      std::nullopt};
  const json opened = json::parse(OpenedEvent(R"({"id":"abc"})", state, 42));
  EXPECT_EQ(opened["type"], "opened");
  EXPECT_EQ(opened["dataset"]["id"], "abc");
  EXPECT_EQ(opened["version"], 42);
  EXPECT_EQ(opened["state"], json::parse(StateJson(state)));

  const json state_event = json::parse(StateEvent(state, 43));
  EXPECT_EQ(state_event["type"], "state");
  EXPECT_EQ(state_event["version"], 43);
  EXPECT_EQ(state_event["state"], json::parse(StateJson(state)));

  EXPECT_EQ(json::parse(DatasetEvent(R"({"id":"abc","progress":0.5})")),
            json::parse(R"({"type":"dataset","dataset":{"id":"abc","progress":0.5}})"));

  const json error = json::parse(ErrorEvent("viewport.width: is 9000", "viewport", false));
  EXPECT_EQ(error, json::parse(R"({"type":"error","message":"viewport.width: is 9000",
                                   "request":"viewport","fatal":false})"));
  const json no_request = json::parse(ErrorEvent("too many malformed messages", "", true));
  EXPECT_FALSE(no_request.contains("request"));
  EXPECT_EQ(no_request["fatal"], true);
  // Untrusted text: one line, bounded, valid JSON even with invalid UTF-8.
  const json hostile =
      json::parse(ErrorEvent("a\nb\r\"c\"\xff" + std::string(5000, 'x'), "ping", false));
  const std::string message = hostile["message"];
  EXPECT_EQ(message.find('\n'), std::string::npos);
  EXPECT_LE(message.size(), 1010u);

  EXPECT_EQ(json::parse(PongEvent(12.5)), json::parse(R"({"type":"pong","t":12.5})"));
  EXPECT_EQ(json::parse(StatsEvent({5, 2, 123456789012, 7})),
            json::parse(R"({"type":"stats","frames_sent":5,"frames_dropped":2,
                            "bytes_sent":123456789012,"bricks_pending":7})"));
}

}  // namespace
}  // namespace octoscope::protocol

namespace octoscope::protocol {
namespace {

TEST(WsMessagesSharingTest, ParsesTheSharingMessages) {
  const HelloMessage hello = ParseAs<HelloMessage>(
      R"({"type":"hello","protocol":1,"name":"Ada L.","resume":"0123456789abcdef0123456789abcdef"})");
  EXPECT_EQ(hello.name, "Ada L.");
  EXPECT_EQ(hello.resume, "0123456789abcdef0123456789abcdef");
  const OpenMessage view =
      ParseAs<OpenMessage>(R"({"type":"open","view":"AbC_-0123456789abcdefg"})");
  EXPECT_EQ(view.view, "AbC_-0123456789abcdefg");
  EXPECT_TRUE(view.dataset.empty());
  const ShareCreateMessage share =
      ParseAs<ShareCreateMessage>(R"({"type":"share_create","role":"controller","ttl_s":60})");
  EXPECT_EQ(share.role, Role::kController);
  EXPECT_EQ(share.ttl_s, 60);
  EXPECT_FALSE(ParseAs<ShareCreateMessage>(R"({"type":"share_create","role":"viewer"})").ttl_s);
  EXPECT_EQ(ParseAs<ShareRevokeMessage>(R"({"type":"share_revoke","token":"abc"})").token, "abc");
  const ParticipantRoleMessage role = ParseAs<ParticipantRoleMessage>(
      R"({"type":"participant_role","participant":"p2","role":"viewer"})");
  EXPECT_EQ(role.participant, "p2");
  EXPECT_EQ(role.role, Role::kViewer);
  EXPECT_EQ(ParseAs<KickMessage>(R"({"type":"kick","participant":"p7"})").participant, "p7");
  EXPECT_FALSE(ParseAs<ViewSaveMessage>(R"({"type":"view_save"})").ttl_s);
  EXPECT_EQ(ParseAs<ViewSaveMessage>(R"({"type":"view_save","ttl_s":3600})").ttl_s, 3600);
}

TEST(WsMessagesSharingTest, BadSharingMessagesAreRefusedNamingTheField) {
  const Bad bad[] = {
      {R"({"type":"hello","protocol":1,"resume":"XYZ"})", "hello", "hello.resume"},
      {R"({"type":"hello","protocol":1,"resume":"0123456789ABCDEF0123456789ABCDEF"})", "hello",
       "hello.resume"},
      {R"({"type":"hello","protocol":1,"name":""})", "hello", "hello.name: is empty"},
      {R"({"type":"open","view":"short"})", "open", "open.view"},
      {R"({"type":"open","view":"AAAAAAAAAAAAAAAAAAAAAA","dataset":"d"})", "open",
       "open.view: is given with dataset"},
      {R"({"type":"open","view":"AAAAAAAAAAAAAAAAAAAAA/"})", "open", "open.view"},
      {R"({"type":"share_create","role":"owner"})", "share_create",
       "share_create.role: is \"owner\", expected viewer or controller"},
      {R"({"type":"share_create"})", "share_create", "share_create.role: missing"},
      {R"({"type":"share_create","role":"viewer","ttl_s":59})", "share_create",
       "share_create.ttl_s"},
      {R"({"type":"share_create","role":"viewer","ttl_s":1e12})", "share_create",
       "share_create.ttl_s"},
      {R"({"type":"share_revoke","token":""})", "share_revoke", "share_revoke.token: is empty"},
      {R"({"type":"participant_role","participant":"p2","role":"admin"})", "participant_role",
       "participant_role.role"},
      {R"({"type":"participant_role","participant":"","role":"viewer"})", "participant_role",
       "participant_role.participant: is empty"},
      {R"({"type":"kick"})", "kick", "kick.participant: missing"},
      {R"({"type":"view_save","id":1})", "view_save", "unknown key \"id\" in view_save"},
      {R"({"type":"view_save","ttl_s":59})", "view_save", "view_save.ttl_s"},
      {R"({"type":"view_save","ttl_s":"1h"})", "view_save", "view_save.ttl_s"},
  };
  for (const Bad& b : bad) {
    std::string type = "stale";
    Result<ClientMessage> m = ParseClientMessage(b.text, &type);
    ASSERT_FALSE(m.ok()) << b.text;
    EXPECT_NE(m.status().message().find(b.says), std::string::npos)
        << b.text << "\n  got: " << m.status().message() << "\n  expected: " << b.says;
    EXPECT_EQ(type, b.type) << b.text;
  }
}

TEST(WsMessagesSharingTest, SharingEventsAreTheDocumentedJson) {
  const json welcome = json::parse(WelcomeEvent("0.1.0", "s1", "p3", Role::kViewer));
  EXPECT_EQ(welcome["participant"], "p3");
  EXPECT_EQ(welcome["role"], "viewer");
  EXPECT_FALSE(welcome.contains("resume"));
  EXPECT_EQ(json::parse(WelcomeEvent("0.1.0", "s1", "p1", Role::kOwner, "ab"))["resume"], "ab");
  const json participants = json::parse(ParticipantsEvent(
      {{"p1", "Ada \"A\"", Role::kOwner, true}, {"p2", "Bob", Role::kViewer, false}}, "p2"));
  EXPECT_EQ(participants, json::parse(R"({"type":"participants","participants":[
      {"id":"p1","name":"Ada \"A\"","role":"owner","driving":true,"you":false},
      {"id":"p2","name":"Bob","role":"viewer","driving":false,"you":true}]})"));
  const json created =
      json::parse(ShareCreatedEvent({"tok", Role::kController, "http://h/?share=tok", 0, 0}));
  EXPECT_EQ(created, json::parse(R"({"type":"share_created","token":"tok","role":"controller",
      "url":"http://h/?share=tok","expires":"1970-01-01T00:00:00Z"})"));
  const json shares = json::parse(SharesEvent({{"t", Role::kViewer, "u", std::nullopt, 2}}));
  EXPECT_EQ(shares["shares"][0]["participants"], 2);
  EXPECT_TRUE(shares["shares"][0]["expires"].is_null());
  EXPECT_EQ(json::parse(ViewSavedEvent("id", "u")),
            json::parse(R"({"type":"view_saved","id":"id","url":"u","expires":null})"));
  EXPECT_EQ(json::parse(ViewSavedEvent("id", "u", 1764072000))["expires"], "2025-11-25T12:00:00Z");
  EXPECT_EQ(IsoUtc(1764072000), "2025-11-25T12:00:00Z");
}

TEST(GrantRefTest, TextRoundTripsAndIsStrict) {
  for (const GrantRef& g : {GrantRef{GrantRef::Kind::kUser, "u0123456789abcdef"},
                            GrantRef{GrantRef::Kind::kShare, "0a1b"},
                            GrantRef{GrantRef::Kind::kView, "AAAAAAAAAAAAAAAAAAAA_-"},
                            GrantRef{GrantRef::Kind::kUser, "alice.b"}}) {
    auto back = ParseGrantRef(GrantRefText(g));
    ASSERT_TRUE(back.ok()) << GrantRefText(g);
    EXPECT_EQ(*back, g);
  }
  EXPECT_EQ(GrantRefText({GrantRef::Kind::kShare, "x"}), "share:x");
  for (const char* bad : {"", "user", "user:", "admin:x", "view:a/b", "share: x", "USER:x",
                          "user:0123456789012345678901234567890123456789012345678901234567890123456"}) {
    EXPECT_FALSE(ParseGrantRef(bad).ok()) << bad;
  }
}

TEST(WsMessagesSharingTest, ViewLinksRoundTripAndAreReadStrictly) {
  auto state = ParseStateDocument(
      R"({"camera":{"projection":"ortho","position":[1,2,3],"target":[1,2,0],"up":[0,1,0],
          "ortho_height":10},"slices":{"position_um":[1,2,3]},"layout":{"maximized":null}})");
  ASSERT_TRUE(state.ok()) << state.status().ToString();
  auto params = ApplyParams(
      "{}", render::DefaultRenderParams(1, volume::DataType::kUint16, render::RenderMode::kMip));
  ASSERT_TRUE(params.ok());
  const ViewState full{*state->camera, *params, {1, 2, 3}, ViewId::kX};
  const ViewLinkGrant grant{{GrantRef::Kind::kShare, "5f3a9c01"},
                            {GrantRef::Kind::kUser, "u0123456789abcdef"},
                            1764072000,
                            1764075600};
  const std::string text = ViewLinkJson("embryo", full, grant);
  const json doc = json::parse(text);
  EXPECT_EQ(doc["version"], 2);
  EXPECT_EQ(doc["creator"], "share:5f3a9c01");
  EXPECT_EQ(doc["owner"], "user:u0123456789abcdef");
  EXPECT_EQ(doc["created"], "2025-11-25T12:00:00Z");
  EXPECT_EQ(doc["expires"], "2025-11-25T13:00:00Z");
  auto link = ParseViewLink(text);
  ASSERT_TRUE(link.ok()) << link.status().ToString();
  EXPECT_EQ(link->dataset, "embryo");
  EXPECT_EQ(link->state.layout->maximized, ViewId::kX);
  ASSERT_TRUE(link->grant.has_value());
  EXPECT_EQ(link->grant->creator, grant.creator);
  EXPECT_EQ(link->grant->owner, grant.owner);
  EXPECT_EQ(link->grant->created_unix_s, grant.created_unix_s);
  EXPECT_EQ(link->grant->expires_unix_s, grant.expires_unix_s);
  // No expiry: null.
  auto forever = ParseViewLink(ViewLinkJson("embryo", full, {grant.owner, grant.owner, 0, {}}));
  ASSERT_TRUE(forever.ok()) << forever.status().ToString();
  EXPECT_FALSE(forever->grant->expires_unix_s.has_value());
  // Version 1 (before creators were recorded) still reads, with no grant.
  json v1 = doc;
  for (const char* key : {"creator", "owner", "created", "expires"}) v1.erase(key);
  v1["version"] = 1;
  auto legacy = ParseViewLink(v1.dump());
  ASSERT_TRUE(legacy.ok()) << legacy.status().ToString();
  EXPECT_FALSE(legacy->grant.has_value());
  // Strict: keys of one version in the other, bad grants, an owner that is not a user.
  json mixed = v1;
  mixed["creator"] = "user:x";
  EXPECT_FALSE(ParseViewLink(mixed.dump()).ok());
  for (const auto& [key, value] : std::vector<std::pair<std::string, json>>{
           {"creator", "nobody:x"}, {"creator", "user:"}, {"creator", "user:a b"},
           {"owner", "share:abc"}, {"created", "yesterday"}, {"expires", 5}, {"version", 3}}) {
    json bad = doc;
    bad[key] = value;
    auto parsed = ParseViewLink(bad.dump());
    ASSERT_FALSE(parsed.ok()) << key;
    EXPECT_NE(parsed.status().message().find(key), std::string::npos)
        << parsed.status().message();
  }
  EXPECT_FALSE(ParseViewLink(R"({"version":1,"dataset":"e"})").ok());
  EXPECT_FALSE(ParseViewLink(R"({"version":2,"dataset":"e","state":{}})").ok());
  EXPECT_FALSE(ParseViewLink(R"({"version":1,"dataset":"E!","state":{}})").ok());
  auto partial = ParseViewLink(R"({"version":1,"dataset":"e","state":{"layout":{}}})");
  ASSERT_FALSE(partial.ok());
  EXPECT_NE(partial.status().message().find("must hold camera, params, slices and layout"),
            std::string::npos);
}

}  // namespace
}  // namespace octoscope::protocol
