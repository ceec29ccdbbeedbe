// Render JSON: the camera document and the render-parameter document that `octoscope render
// --view CAMERA.json --params PARAMS.json` reads (and the browser protocol will reuse). The full
// specification, with examples, is docs/render_json.md. In short:
//
//   camera: {"projection": "ortho"|"perspective", "position": [x, y, z], "target": [x, y, z],
//            "up": [x, y, z], "fov_y_degrees": 30, "ortho_height": h}     (µm, physical space)
//       or  {"view_matrix": [16 numbers, row-major world-to-camera, OpenGL convention], ...}
//   params: {"mode": "dvr"|"mip"|"minip", "step_voxels": 1, "background": [r, g, b, a],
//            "clip_planes": [{"normal": [x, y, z], "distance": d}],
//            "channels": [{"enabled": true, "color": [r, g, b], "window": w, "level": l,
//                          "gamma": 1, "opacity_scale": 1, "lut": [256 x [r, g, b, a]],
//                          "transform": [16 numbers] | {"translate": [..], "scale": [..]}}]}
//
// Parsing is strict: missing keys take their defaults, unknown keys, wrong types, non-finite
// numbers and wrong array lengths are kInvalidArgument errors whose message names the field path
// ("channels[1].window"). The image size is not part of either document (it comes from --size).
// Nothing throws out of these functions, whatever the input.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_RENDER_JSON_H_
#define OCTOSCOPE_PROTOCOL_RENDER_JSON_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "render/camera.h"
#include "render/render_params.h"
#include "util/result.h"

namespace octoscope::protocol {

// Documents larger than this are refused unparsed (a LUT per channel is ~4 KiB of JSON).
inline constexpr uint64_t kMaxRenderJsonBytes = uint64_t{4} << 20;
// Deepest nesting accepted (the documents need 4); deeper input is refused while parsing.
inline constexpr int kMaxRenderJsonDepth = 16;
// A sanity limit on "channels" (the volume's channel count must match anyway).
inline constexpr int kMaxRenderJsonChannels = 1024;

// Parses a camera document for a width x height image. "projection" defaults to
// `default_projection`, "up" to [0, -1, 0], "fov_y_degrees" to 30; "ortho_height" defaults to
// the height a perspective camera sees at the target (2 |target - position| tan(fov / 2)), and is
// required for an orthographic camera given by "view_matrix". Errors also when the camera is
// degenerate (Camera::LookAt / FromViewMatrix).
Result<render::Camera> ParseCameraJson(std::string_view text, render::Projection default_projection,
                                       int width, int height);

// The camera as a position/target/up document (target one focal distance ahead, see
// docs/render_json.md) that ParseCameraJson turns back into the same camera.
std::string CameraToJson(const render::Camera& camera);

// Parses a render-parameter document. `defaults` supplies every missing value, including the
// per-channel defaults; its channel count is the volume's, and a "channels" array must have
// exactly that many entries. The result passes ValidateRenderParams (else its error, as
// kInvalidArgument).
Result<render::RenderParams> ParseRenderParamsJson(std::string_view text,
                                                   const render::RenderParams& defaults);

// The complete document for `params` (every key; "lut" only when set).
std::string RenderParamsToJson(const render::RenderParams& params);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_RENDER_JSON_H_
