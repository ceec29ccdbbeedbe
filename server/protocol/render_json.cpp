#include "protocol/render_json.h"

#include <cmath>
#include <cstdio>
#include <exception>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "protocol/json_fields.h"
#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;
using render::Mat4;
using render::Vec3;

// The documents of this file as JSON objects.
Result<json> ParseObject(std::string_view text, std::string_view what) {
  // Hostile nesting is refused while parsing: no valid document nests deeper than a LUT
  // (object > array > array > number).
  return ParseJsonObject(text, what, kMaxRenderJsonBytes, kMaxRenderJsonDepth);
}

Result<Vec3> GetVec3(const json& j, const std::string& path) {
  OCTO_ASSIGN_OR_RETURN(std::vector<double> v, GetNumbers(j, path, 3));
  return Vec3{v[0], v[1], v[2]};
}

Result<Mat4> GetMatrix(const json& j, const std::string& path) {
  OCTO_ASSIGN_OR_RETURN(std::vector<double> v, GetNumbers(j, path, 16));
  Mat4 m;
  for (int i = 0; i < 16; ++i) m.m[i] = v[i];
  return m;
}

// A per-channel transform: 16 numbers, or {"translate", "scale"} meaning p' = scale * p +
// translate.
Result<Mat4> GetTransform(const json& j, const std::string& path) {
  if (j.is_array()) {
    OCTO_ASSIGN_OR_RETURN(Mat4 m, GetMatrix(j, path));
    if (!m.IsAffine()) return FieldError(path, "must be affine (last row 0, 0, 0, 1)");
    return m;
  }
  if (!j.is_object()) {
    return FieldError(path, "must be 16 numbers or {\"translate\", \"scale\"}, got " + TypeOf(j));
  }
  OCTO_RETURN_IF_ERROR(CheckKeys(j, path, {"translate", "scale"}));
  Vec3 translate{0, 0, 0}, scale{1, 1, 1};
  if (auto it = j.find("translate"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(translate, GetVec3(*it, Join(path, "translate")));
  }
  if (auto it = j.find("scale"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(scale, GetVec3(*it, Join(path, "scale")));
  }
  return Mat4::Translation(translate) * Mat4::Scale(scale);
}

Result<std::array<volume::Rgba, render::kLutEntries>> GetLut(const json& j,
                                                             const std::string& path) {
  OCTO_RETURN_IF_ERROR(CheckArray(j, path, render::kLutEntries));
  std::array<volume::Rgba, render::kLutEntries> lut;
  for (size_t i = 0; i < lut.size(); ++i) {
    const std::string entry = Index(path, i);
    OCTO_RETURN_IF_ERROR(CheckArray(j[i], entry, 4));
    uint8_t c[4];
    for (size_t k = 0; k < 4; ++k) {
      const json& v = j[i][k];
      if (!v.is_number_integer() || v.get<int64_t>() < 0 || v.get<int64_t>() > 255 ||
          (v.is_number_unsigned() && v.get<uint64_t>() > 255)) {
        return FieldError(Index(entry, k),
                          "must be an integer in 0..255, got " +
                              (v.is_primitive() ? Printable(v.dump(), 40) : TypeOf(v)));
      }
      c[k] = static_cast<uint8_t>(v.get<int64_t>());
    }
    lut[i] = volume::Rgba{c[0], c[1], c[2], c[3]};
  }
  return lut;
}

Status ParseChannel(const json& j, const std::string& path, render::ChannelParams& c) {
  if (!j.is_object()) return FieldError(path, "must be an object, got " + TypeOf(j));
  OCTO_RETURN_IF_ERROR(CheckKeys(
      j, path,
      {"enabled", "color", "window", "level", "gamma", "opacity_scale", "lut", "transform"}));
  if (auto it = j.find("enabled"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.enabled, GetBool(*it, Join(path, "enabled")));
  }
  if (auto it = j.find("color"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(std::vector<double> rgb, GetNumbers(*it, Join(path, "color"), 3, 0, 1));
    c.color = {rgb[0], rgb[1], rgb[2]};
  }
  if (auto it = j.find("window"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.window, GetNumber(*it, Join(path, "window")));
    if (!(c.window > 0)) return FieldError(Join(path, "window"), "must be > 0");
  }
  if (auto it = j.find("level"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.level, GetNumber(*it, Join(path, "level")));
  }
  if (auto it = j.find("gamma"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.gamma, GetNumber(*it, Join(path, "gamma")));
    if (!(c.gamma > 0)) return FieldError(Join(path, "gamma"), "must be > 0");
  }
  if (auto it = j.find("opacity_scale"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.opacity_scale, GetNumber(*it, Join(path, "opacity_scale")));
    if (!(c.opacity_scale >= 0)) return FieldError(Join(path, "opacity_scale"), "must be >= 0");
  }
  if (auto it = j.find("lut"); it != j.end()) {
    if (it->is_null()) {
      c.lut.reset();
    } else {
      OCTO_ASSIGN_OR_RETURN(c.lut, GetLut(*it, Join(path, "lut")));
    }
  }
  if (auto it = j.find("transform"); it != j.end()) {
    OCTO_ASSIGN_OR_RETURN(c.transform, GetTransform(*it, Join(path, "transform")));
  }
  return Status::Ok();
}

json Vec3Json(const Vec3& v) { return json::array({v.x, v.y, v.z}); }

}  // namespace

Result<render::Camera> ParseCameraJson(std::string_view text, render::Projection default_projection,
                                       int width, int height) {
  OCTO_ASSIGN_OR_RETURN(json doc, ParseObject(text, "camera"));
  OCTO_RETURN_IF_ERROR(CheckKeys(
      doc, "",
      {"projection", "position", "target", "up", "fov_y_degrees", "ortho_height", "view_matrix"}));
  render::Projection projection = default_projection;
  if (auto it = doc.find("projection"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::string name, GetString(*it, "projection"));
    auto p = render::ProjectionFromName(name);
    if (!p) {
      return FieldError("projection", "is \"" + Printable(name, 40) +
                                          "\", expected \"ortho\" or \"perspective\"");
    }
    projection = *p;
  }
  double fov = 30;
  if (auto it = doc.find("fov_y_degrees"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(fov, GetNumber(*it, "fov_y_degrees"));
    if (!(fov > 0 && fov < 180)) return FieldError("fov_y_degrees", "must be in (0, 180)");
  }
  std::optional<double> ortho_height;
  if (auto it = doc.find("ortho_height"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(ortho_height, GetNumber(*it, "ortho_height"));
    if (!(*ortho_height > 0)) return FieldError("ortho_height", "must be > 0");
  }
  auto in_camera = [](Result<render::Camera> camera) -> Result<render::Camera> {
    if (camera.ok()) return camera;
    return InvalidArgumentError("camera: " + camera.status().message());
  };

  const bool has_matrix = doc.contains("view_matrix");
  if (has_matrix) {
    for (const char* key : {"position", "target", "up"}) {
      if (doc.contains(key)) {
        return InvalidArgumentError(std::string("camera: \"view_matrix\" and \"") + key +
                                    "\" are alternatives; give one form");
      }
    }
    OCTO_ASSIGN_OR_RETURN(Mat4 view, GetMatrix(doc["view_matrix"], "view_matrix"));
    if (!ortho_height) {
      if (projection == render::Projection::kOrthographic) {
        return FieldError("ortho_height", "is required for an orthographic \"view_matrix\" camera");
      }
      ortho_height = 1;  // Unused by perspective cameras, but validated.
    }
    return in_camera(
        render::Camera::FromViewMatrix(projection, view, width, height, fov, *ortho_height));
  }
  for (const char* key : {"position", "target"}) {
    if (!doc.contains(key)) {
      return InvalidArgumentError(std::string("camera: missing \"") + key +
                                  "\" (or give \"view_matrix\")");
    }
  }
  OCTO_ASSIGN_OR_RETURN(Vec3 position, GetVec3(doc["position"], "position"));
  OCTO_ASSIGN_OR_RETURN(Vec3 target, GetVec3(doc["target"], "target"));
  Vec3 up{0, -1, 0};
  if (auto it = doc.find("up"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(up, GetVec3(*it, "up"));
  }
  if (!ortho_height) {
    // What a perspective camera would see at the target: switching projection keeps the framing.
    ortho_height = 2 * render::Length(target - position) * std::tan(fov * std::numbers::pi / 360);
    if (!(*ortho_height > 0) || !std::isfinite(*ortho_height)) ortho_height = 1;
  }
  return in_camera(
      render::Camera::LookAt(projection, position, target, up, width, height, fov, *ortho_height));
}

std::string CameraToJson(const render::Camera& camera) {
  // The target sits at the distance where the default ortho_height rule gives the same height.
  const double focal =
      camera.ortho_height() / (2 * std::tan(camera.fov_y_degrees() * std::numbers::pi / 360));
  nlohmann::ordered_json j;
  j["projection"] = std::string(render::ProjectionName(camera.projection()));
  j["position"] = Vec3Json(camera.position());
  j["target"] = Vec3Json(camera.position() + camera.forward() * focal);
  j["up"] = Vec3Json(camera.up());
  j["fov_y_degrees"] = camera.fov_y_degrees();
  j["ortho_height"] = camera.ortho_height();
  return j.dump();
}

Result<render::RenderParams> ParseRenderParamsJson(std::string_view text,
                                                   const render::RenderParams& defaults) {
  OCTO_ASSIGN_OR_RETURN(json doc, ParseObject(text, "render parameters"));
  OCTO_RETURN_IF_ERROR(
      CheckKeys(doc, "", {"mode", "step_voxels", "background", "clip_planes", "channels"}));
  render::RenderParams p = defaults;
  if (auto it = doc.find("mode"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::string name, GetString(*it, "mode"));
    auto mode = render::RenderModeFromName(name);
    if (!mode) {
      return FieldError("mode", "is \"" + Printable(name, 40) + "\", expected dvr, mip or minip");
    }
    p.mode = *mode;
  }
  if (auto it = doc.find("step_voxels"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(p.step_voxels, GetNumberIn(*it, "step_voxels", render::kMinStepVoxels,
                                                     render::kMaxStepVoxels));
  }
  if (auto it = doc.find("background"); it != doc.end()) {
    OCTO_ASSIGN_OR_RETURN(std::vector<double> bg, GetNumbers(*it, "background", 4, 0, 1));
    p.background = {bg[0], bg[1], bg[2], bg[3]};
  }
  if (auto it = doc.find("clip_planes"); it != doc.end()) {
    if (!it->is_array()) return FieldError("clip_planes", "must be an array, got " + TypeOf(*it));
    if (it->size() > static_cast<size_t>(render::kMaxClipPlanes)) {
      return FieldError("clip_planes", "has " + std::to_string(it->size()) + " planes, at most " +
                                           std::to_string(render::kMaxClipPlanes));
    }
    p.clip_planes.clear();
    for (size_t i = 0; i < it->size(); ++i) {
      const std::string path = Index("clip_planes", i);
      const json& plane = (*it)[i];
      if (!plane.is_object()) return FieldError(path, "must be an object, got " + TypeOf(plane));
      OCTO_RETURN_IF_ERROR(CheckKeys(plane, path, {"normal", "distance"}));
      render::ClipPlane clip;
      if (auto n = plane.find("normal"); n != plane.end()) {
        OCTO_ASSIGN_OR_RETURN(clip.normal, GetVec3(*n, Join(path, "normal")));
        if (render::Length(clip.normal) == 0) {
          return FieldError(Join(path, "normal"), "must not be zero");
        }
      }
      if (auto d = plane.find("distance"); d != plane.end()) {
        OCTO_ASSIGN_OR_RETURN(clip.distance, GetNumber(*d, Join(path, "distance")));
      }
      p.clip_planes.push_back(clip);
    }
  }
  if (auto it = doc.find("channels"); it != doc.end()) {
    if (!it->is_array()) return FieldError("channels", "must be an array, got " + TypeOf(*it));
    if (it->size() != defaults.channels.size()) {
      return FieldError("channels", "has " + std::to_string(it->size()) +
                                        " entries, the volume has " +
                                        std::to_string(defaults.channels.size()) + " channels");
    }
    for (size_t i = 0; i < it->size(); ++i) {
      OCTO_RETURN_IF_ERROR(ParseChannel((*it)[i], Index("channels", i), p.channels[i]));
    }
  }
  if (Status s = render::ValidateRenderParams(p, static_cast<int>(defaults.channels.size()));
      !s.ok()) {
    return InvalidArgumentError("render parameters: " + s.message());
  }
  return p;
}

std::string RenderParamsToJson(const render::RenderParams& p) {
  nlohmann::ordered_json j;
  j["mode"] = std::string(render::RenderModeName(p.mode));
  j["step_voxels"] = p.step_voxels;
  j["background"] = p.background;
  j["clip_planes"] = nlohmann::ordered_json::array();
  for (const render::ClipPlane& plane : p.clip_planes) {
    nlohmann::ordered_json jp;
    jp["normal"] = Vec3Json(plane.normal);
    jp["distance"] = plane.distance;
    j["clip_planes"].push_back(jp);
  }
  j["channels"] = nlohmann::ordered_json::array();
  for (const render::ChannelParams& c : p.channels) {
    nlohmann::ordered_json jc;
    jc["enabled"] = c.enabled;
    jc["color"] = c.color;
    jc["window"] = c.window;
    jc["level"] = c.level;
    jc["gamma"] = c.gamma;
    jc["opacity_scale"] = c.opacity_scale;
    if (c.lut) {
      jc["lut"] = nlohmann::ordered_json::array();
      for (const volume::Rgba& e : *c.lut) jc["lut"].push_back({e.r, e.g, e.b, e.a});
    }
    jc["transform"] = c.transform.m;
    j["channels"].push_back(jc);
  }
  return j.dump();
}

}  // namespace octoscope::protocol
