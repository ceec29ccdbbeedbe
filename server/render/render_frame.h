// RenderFrame: a camera and render parameters converted to the ray casters' per-frame kernel
// arguments (kernels/render_format.h: OctoRenderFrame, one OctoChannelParams per enabled channel,
// their LUT entries), in level-0 voxel coordinates (docs/rendering.md, "Coordinates"). Shared by
// the renderer (volume_renderer.h) and the dense benchmark baseline (bench/baseline), so both cast
// exactly the same rays with the same transfer functions.
//
// Thread safety: a pure function of its arguments.
#ifndef OCTOSCOPE_RENDER_RENDER_FRAME_H_
#define OCTOSCOPE_RENDER_RENDER_FRAME_H_

#include <array>
#include <cstdint>
#include <vector>

#include "../../kernels/render_format.h"
#include "render/camera.h"
#include "render/linear_algebra.h"
#include "render/render_params.h"

namespace octoscope::render {

struct PackedFrame {
  OctoRenderFrame frame{};
  // One entry per enabled channel, in channel order (at least one entry, all zero when none is
  // enabled: frame.active_channels says how many are real).
  std::vector<OctoChannelParams> channels;
  // float4 LUT entries, 256 per channel with a LUT, divided by 255 (at least one entry).
  std::vector<float> lut;
  bool all_identity = true;  // No enabled channel has a transform.
};

// The OCTO_MODE value (kernels/render_format.h) of `mode`, the ray casters' -DOCTO_MODE=.
int KernelModeDefine(RenderMode mode);

// The kernel arguments of `camera` and `params` for a volume of `volume_size` voxels at
// `spacing_um`; `lod_bias` (2^bias scales the footprint) and `skip_empty` as FrameOptions.
// REQUIRES: params validated for the volume (ValidateRenderParams).
PackedFrame PackRenderFrame(const Camera& camera, const RenderParams& params, double lod_bias,
                            bool skip_empty, const std::array<int64_t, 3>& volume_size,
                            const Vec3& spacing_um);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_RENDER_FRAME_H_
