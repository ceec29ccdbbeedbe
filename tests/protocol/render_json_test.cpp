#include "protocol/render_json.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <string>

namespace octoscope::protocol {
namespace {

using render::Camera;
using render::Mat4;
using render::Projection;
using render::RenderMode;
using render::RenderParams;
using render::Vec3;

void ExpectNear(const Vec3& a, const Vec3& b, double tol = 1e-9) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

void ExpectSameCamera(const Camera& a, const Camera& b) {
  EXPECT_EQ(a.projection(), b.projection());
  EXPECT_EQ(a.width(), b.width());
  EXPECT_EQ(a.height(), b.height());
  ExpectNear(a.position(), b.position());
  ExpectNear(a.forward(), b.forward());
  ExpectNear(a.up(), b.up());
  EXPECT_NEAR(a.fov_y_degrees(), b.fov_y_degrees(), 1e-9);
  EXPECT_NEAR(a.ortho_height(), b.ortho_height(), 1e-9);
}

// A double as JSON text that parses back to the same value.
std::string ExactNumber(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.17g", v);
  return buffer;
}

// The status message, or "" when ok.
template <typename T>
std::string ErrorOf(const Result<T>& r) {
  return r.ok() ? "" : r.status().message();
}

TEST(CameraJsonTest, LookAtFormMatchesCameraLookAt) {
  auto parsed = ParseCameraJson(
      R"({"projection": "perspective", "position": [10, 20, -100], "target": [10, 20, 5],
          "up": [0, -1, 0], "fov_y_degrees": 40, "ortho_height": 7})",
      Projection::kOrthographic, 64, 48);
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  auto expected = Camera::LookAt(Projection::kPerspective, {10, 20, -100}, {10, 20, 5}, {0, -1, 0},
                                 64, 48, 40, 7);
  ASSERT_TRUE(expected.ok());
  ExpectSameCamera(*parsed, *expected);
}

TEST(CameraJsonTest, DefaultsProjectionUpFovAndOrthoHeight) {
  auto parsed = ParseCameraJson(R"({"position": [0, 0, -10], "target": [0, 0, 0]})",
                                Projection::kOrthographic, 32, 32);
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(parsed->projection(), Projection::kOrthographic);
  EXPECT_DOUBLE_EQ(parsed->fov_y_degrees(), 30);
  ExpectNear(parsed->up(), {0, -1, 0});
  ExpectNear(parsed->forward(), {0, 0, 1});
  // The height a 30-degree perspective camera sees 10 µm ahead.
  EXPECT_NEAR(parsed->ortho_height(), 2 * 10 * std::tan(15 * std::numbers::pi / 180), 1e-12);
}

TEST(CameraJsonTest, ViewMatrixFormMatchesFromViewMatrix) {
  auto original =
      Camera::LookAt(Projection::kPerspective, {5, -3, 2}, {1, 1, 1}, {0, 0, 1}, 40, 30, 25, 3);
  ASSERT_TRUE(original.ok());
  const Mat4 view = original->ViewMatrix();
  std::string text = R"({"projection": "perspective", "fov_y_degrees": 25, "view_matrix": [)";
  // append() rather than chained operator+: GCC 12's -Wrestrict misfires on the latter at -O3.
  for (int i = 0; i < 16; ++i) text.append(i ? "," : "").append(ExactNumber(view.m[i]));
  text += "]}";
  auto parsed = ParseCameraJson(text, Projection::kOrthographic, 40, 30);
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  auto expected = Camera::FromViewMatrix(Projection::kPerspective, view, 40, 30, 25, 1);
  ASSERT_TRUE(expected.ok());
  ExpectSameCamera(*parsed, *expected);
  ExpectNear(parsed->position(), {5, -3, 2});
}

TEST(CameraJsonTest, RoundTripsThroughCameraToJson) {
  for (Projection projection : {Projection::kOrthographic, Projection::kPerspective}) {
    auto camera =
        Camera::LookAt(projection, {3, 4, 5}, {-7, 2, 9}, {0.2, 1, 0.1}, 50, 70, 33, 12.5);
    ASSERT_TRUE(camera.ok());
    auto back = ParseCameraJson(CameraToJson(*camera), Projection::kOrthographic, 50, 70);
    ASSERT_TRUE(back.ok()) << back.status().ToString() << CameraToJson(*camera);
    ExpectSameCamera(*back, *camera);
  }
}

TEST(CameraJsonTest, ErrorsNameTheField) {
  const Projection o = Projection::kOrthographic;
  EXPECT_NE(
      ErrorOf(ParseCameraJson(R"({"position": [0,0,1], "target": [0,0,0], "zoom": 2})", o, 8, 8))
          .find("\"zoom\""),
      std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"position": [0,"a",1], "target": [0,0,0]})", o, 8, 8))
                .find("position[1]"),
            std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"position": [0,0], "target": [0,0,0]})", o, 8, 8))
                .find("position"),
            std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"position": [0,0,1]})", o, 8, 8)).find("target"),
            std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"position": [0,0,1], "target": [0,0,0],
                                       "fov_y_degrees": 180})",
                                    o, 8, 8))
                .find("fov_y_degrees"),
            std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"position": [0,0,1e999], "target": [0,0,0]})", o, 8, 8))
                .find("overflow"),
            std::string::npos);
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"projection": "fisheye", "position": [0,0,1],
                                       "target": [0,0,0]})",
                                    o, 8, 8))
                .find("projection"),
            std::string::npos);
  // Orthographic view matrix without a height; both forms at once; up parallel to the view.
  const std::string identity = "[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]";
  EXPECT_NE(ErrorOf(ParseCameraJson(R"({"view_matrix": )" + identity + "}", o, 8, 8))
                .find("ortho_height"),
            std::string::npos);
  EXPECT_TRUE(
      ParseCameraJson(R"({"view_matrix": )" + identity + R"(, "ortho_height": 3})", o, 8, 8).ok());
  EXPECT_FALSE(
      ParseCameraJson(R"({"view_matrix": )" + identity + R"(, "position": [0,0,0]})", o, 8, 8)
          .ok());
  auto parallel =
      ParseCameraJson(R"({"position": [0,0,1], "target": [0,0,0], "up": [0,0,1]})", o, 8, 8);
  EXPECT_EQ(parallel.status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseCameraJson("[1, 2]", o, 8, 8).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ParseCameraJson("{", o, 8, 8).status().code(), StatusCode::kInvalidArgument);
}

RenderParams Defaults(int channels) {
  return render::DefaultRenderParams(channels, volume::DataType::kUint16, RenderMode::kDvr);
}

TEST(RenderParamsJsonTest, EmptyDocumentGivesTheDefaults) {
  auto parsed = ParseRenderParamsJson("{}", Defaults(2));
  ASSERT_TRUE(parsed.ok()) << parsed.status().ToString();
  EXPECT_EQ(RenderParamsToJson(*parsed), RenderParamsToJson(Defaults(2)));
  // Missing channel keys keep the per-channel defaults.
  auto partial = ParseRenderParamsJson(R"({"channels": [{}, {"enabled": false}]})", Defaults(2));
  ASSERT_TRUE(partial.ok()) << partial.status().ToString();
  EXPECT_TRUE(partial->channels[0].enabled);
  EXPECT_FALSE(partial->channels[1].enabled);
  EXPECT_DOUBLE_EQ(partial->channels[1].window, 65535);
}

TEST(RenderParamsJsonTest, ParsesEveryField) {
  std::string lut = "[";
  for (int i = 0; i < 256; ++i) {
    lut.append(i ? ",[" : "[").append(std::to_string(i)).append(",0,");
    lut.append(std::to_string(255 - i)).append(",128]");
  }
  lut += "]";
  const std::string text = R"({"mode": "mip", "step_voxels": 0.5, "background": [0.1, 0.2, 0.3, 1],
    "clip_planes": [{"normal": [1, 0, 0], "distance": 12.5}, {"normal": [0, -2, 0]}],
    "channels": [
      {"color": [1, 0.5, 0], "window": 1000, "level": 600, "gamma": 0.8, "opacity_scale": 2,
       "transform": {"translate": [1, 2, 3], "scale": [2, 2, 0.5]}},
      {"enabled": false, "lut": )" +
                           lut + R"(, "transform": [1,0,0,4, 0,1,0,5, 0,0,1,6, 0,0,0,1]}]})";
  auto p = ParseRenderParamsJson(text, Defaults(2));
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->mode, RenderMode::kMip);
  EXPECT_DOUBLE_EQ(p->step_voxels, 0.5);
  EXPECT_EQ(p->background, (std::array<double, 4>{0.1, 0.2, 0.3, 1}));
  ASSERT_EQ(p->clip_planes.size(), 2u);
  EXPECT_EQ(p->clip_planes[0].normal, (Vec3{1, 0, 0}));
  EXPECT_DOUBLE_EQ(p->clip_planes[0].distance, 12.5);
  EXPECT_EQ(p->clip_planes[1].normal, (Vec3{0, -2, 0}));
  EXPECT_DOUBLE_EQ(p->clip_planes[1].distance, 0);
  const render::ChannelParams& c0 = p->channels[0];
  EXPECT_EQ(c0.color, (std::array<double, 3>{1, 0.5, 0}));
  EXPECT_DOUBLE_EQ(c0.window, 1000);
  EXPECT_DOUBLE_EQ(c0.level, 600);
  EXPECT_DOUBLE_EQ(c0.gamma, 0.8);
  EXPECT_DOUBLE_EQ(c0.opacity_scale, 2);
  // translate + scale means p' = scale * p + translate.
  EXPECT_EQ(c0.transform.TransformPoint({1, 1, 1}), (Vec3{3, 4, 3.5}));
  const render::ChannelParams& c1 = p->channels[1];
  EXPECT_FALSE(c1.enabled);
  ASSERT_TRUE(c1.lut.has_value());
  EXPECT_EQ((*c1.lut)[10], (volume::Rgba{10, 0, 245, 128}));
  EXPECT_EQ(c1.transform.TransformPoint({0, 0, 0}), (Vec3{4, 5, 6}));
}

TEST(RenderParamsJsonTest, RoundTripsThroughRenderParamsToJson) {
  RenderParams p = Defaults(3);
  p.mode = RenderMode::kMinIp;
  p.step_voxels = 0.25;
  p.background = {0, 0.5, 1, 0.25};
  p.clip_planes = {{{0.3, 0.4, -1}, -7.25}};
  p.channels[0].color = {0.1, 0.7, 0.3};
  p.channels[0].window = 123.456;
  p.channels[0].level = -5;
  p.channels[1].enabled = false;
  p.channels[1].transform = Mat4::Translation({0.5, -0.25, 1}) * Mat4::Scale({1.01, 0.99, 1});
  std::array<volume::Rgba, render::kLutEntries> lut;
  for (int i = 0; i < render::kLutEntries; ++i) {
    lut[i] = volume::Rgba{static_cast<uint8_t>(i), static_cast<uint8_t>(i / 2),
                          static_cast<uint8_t>(7), static_cast<uint8_t>(255 - i)};
  }
  p.channels[2].lut = lut;
  p.channels[2].gamma = 2.2;
  p.channels[2].opacity_scale = 0;
  const std::string text = RenderParamsToJson(p);
  auto back = ParseRenderParamsJson(text, Defaults(3));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(RenderParamsToJson(*back), text);
  EXPECT_EQ(back->channels[1].transform, p.channels[1].transform);  // Exact doubles.
  EXPECT_EQ(back->channels[2].lut, p.channels[2].lut);
  EXPECT_EQ(back->clip_planes[0].normal, p.clip_planes[0].normal);
}

TEST(RenderParamsJsonTest, ErrorsAreInvalidArgumentNamingTheFieldPath) {
  struct Case {
    const char* text;
    const char* names;
  };
  const Case cases[] = {
      {R"({"channels": [{}, {"window": "wide"}]})", "channels[1].window"},
      {R"({"channels": [{}, {"window": -3}]})", "channels[1].window"},
      // Overflowing numbers (JSON has no NaN or Inf) are refused by the JSON parser itself.
      {R"({"channels": [{}, {"window": 1e999}]})", "overflow"},
      {R"({"channels": [{"gamma": 0}, {}]})", "channels[0].gamma"},
      {R"({"channels": [{"colour": [1, 0, 0]}, {}]})", "\"colour\" in channels[0]"},
      {R"({"channels": [{"color": [1, 0, 2]}, {}]})", "channels[0].color[2]"},
      {R"({"channels": [{"color": [1, 0]}, {}]})", "channels[0].color"},
      {R"({"channels": [{"lut": [[0, 0, 0, 0]]}, {}]})", "channels[0].lut"},
      {R"({"channels": [{}, {"transform": [1, 2, 3]}]})", "channels[1].transform"},
      {R"({"channels": [{}, {"transform": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,1,1]}]})",
       "channels[1].transform"},
      {R"({"channels": [{}, {"transform": {"rotate": 3}}]})",
       "\"rotate\" in channels[1].transform"},
      {R"({"channels": [{"enabled": 1}, {}]})", "channels[0].enabled"},
      {R"({"channels": [{}]})", "channels"},
      {R"({"channels": {}})", "channels"},
      {R"({"mode": "xray"})", "mode"},
      {R"({"step_voxels": 0})", "step_voxels"},
      {R"({"step_voxels": 1000})", "step_voxels"},
      {R"({"background": [0, 0, 0]})", "background"},
      {R"({"background": [0, 0, 0, -1]})", "background[3]"},
      {R"({"clip_planes": [{"normal": [0, 0, 0]}]})", "clip_planes[0].normal"},
      {R"({"clip_planes": [{}, {}, {}, {}]})", "clip_planes"},
      {R"({"clip_planes": [{"distance": null}]})", "clip_planes[0].distance"},
      {R"({"brightness": 2})", "\"brightness\""},
      {R"([])", "object"},
      {R"({"mode": "mip",)", "JSON"},
  };
  for (const Case& c : cases) {
    auto r = ParseRenderParamsJson(c.text, Defaults(2));
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << c.text;
    EXPECT_NE(r.status().message().find(c.names), std::string::npos)
        << c.text << " -> " << r.status().message();
  }
}

// Deterministic mutation fuzz: byte flips, insertions, deletions and truncations of valid
// documents either parse (to valid parameters / a camera) or fail with kInvalidArgument; they
// never crash or throw.
// A 2 MB document nesting a million arrays where a LUT entry belongs used to overflow the stack
// while the error message printed the value; nesting is now refused while parsing.
TEST(RenderJsonFuzzTest, DeepNestingIsRefusedNotACrash) {
  const size_t depth = 1'000'000;
  std::string text = R"({"channels": [{"lut": [)";
  text.append(depth, '[');
  text.append(depth, ']');
  text += "]}, {}]}";
  Result<RenderParams> parsed = ParseRenderParamsJson(text, Defaults(2));
  ASSERT_FALSE(parsed.ok());
  EXPECT_EQ(parsed.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(parsed.status().message().find("nested too deeply"), std::string::npos)
      << parsed.status().ToString();
  // Depth within the limit still parses (or fails for its content, not its depth).
  Result<RenderParams> shallow =
      ParseRenderParamsJson(R"({"channels": [{"lut": [[[[1]]]]}, {}]})", Defaults(2));
  ASSERT_FALSE(shallow.ok());
  EXPECT_NE(shallow.status().message().find("channels[0].lut"), std::string::npos)
      << shallow.status().ToString();
}

TEST(RenderJsonFuzzTest, MutatedDocumentsParseOrFailCleanly) {
  RenderParams p = Defaults(2);
  p.channels[1].lut.emplace();
  p.clip_planes = {{{1, 0, 0}, 5}};
  const std::string params_doc = RenderParamsToJson(p);
  const std::string camera_doc =
      R"({"projection": "perspective", "position": [1, 2, -30], "target": [1, 2, 3],
          "up": [0, -1, 0], "fov_y_degrees": 30})";
  const std::string alphabet = "{}[]\",:0123456789.-eE truefalsnul\\\x01\xff";
  std::mt19937 rng(12345);
  int parsed_ok = 0, failed = 0;
  for (int iteration = 0; iteration < 3000; ++iteration) {
    const bool camera = iteration % 3 == 0;
    std::string text = camera ? camera_doc : params_doc;
    const int edits = 1 + static_cast<int>(rng() % 4);
    for (int e = 0; e < edits && !text.empty(); ++e) {
      const size_t at = rng() % text.size();
      switch (rng() % 4) {
        case 0:
          text[at] = static_cast<char>(text[at] ^ (1 << (rng() % 8)));
          break;
        case 1:
          text.insert(at, 1, alphabet[rng() % alphabet.size()]);
          break;
        case 2:
          text.erase(at, 1 + rng() % 8);
          break;
        default:
          text.resize(at);
          break;
      }
    }
    if (camera) {
      auto r = ParseCameraJson(text, Projection::kOrthographic, 16, 16);
      if (r.ok()) {
        ++parsed_ok;
      } else {
        ++failed;
        EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << text;
      }
    } else {
      auto r = ParseRenderParamsJson(text, Defaults(2));
      if (r.ok()) {
        ++parsed_ok;
        EXPECT_TRUE(render::ValidateRenderParams(*r, 2).ok()) << text;
      } else {
        ++failed;
        EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument) << text;
        EXPECT_FALSE(r.status().message().empty());
      }
    }
  }
  // Both outcomes occur (the mutations are neither all fatal nor all harmless).
  EXPECT_GT(parsed_ok, 10);
  EXPECT_GT(failed, 1000);
}

}  // namespace
}  // namespace octoscope::protocol
