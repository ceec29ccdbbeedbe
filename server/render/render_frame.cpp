#include "render/render_frame.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace octoscope::render {

int KernelModeDefine(RenderMode mode) {
  switch (mode) {
    case RenderMode::kDvr:
      return OCTO_MODE_DVR;
    case RenderMode::kMip:
      return OCTO_MODE_MIP;
    case RenderMode::kMinIp:
      return OCTO_MODE_MINIP;
  }
  return OCTO_MODE_DVR;
}

namespace {

// The stored value at which the device's windowed value (float, as OctoWindowed) reaches
// `t_threshold` (after gamma), moved outwards by `margin` in the direction `sign`.
float WindowValueAt(const OctoChannelParams& ch, double t_threshold, double sign) {
  const double width = 1.0 / static_cast<double>(ch.inv_window);
  const double t = std::pow(t_threshold, 1.0 / static_cast<double>(ch.gamma));
  // Float rounding of the window arithmetic on the device: a margin of 1e-4 of the width.
  const double margin = 1e-4 * width + 1e-2;
  return static_cast<float>(static_cast<double>(ch.window_lo) + t * width + sign * margin);
}

// DVR value-range skipping (kernels/raycast.cl, OctoNodeInert): bounds outside which the
// channel's opacity is exactly 0, conservative (a zero-alpha gap inside the LUT is not used).
//  * opacity_scale 0 or a LUT without any positive alpha: nothing is visible.
//  * no LUT: alpha = t * scale, 0 exactly when v <= window_lo (then v - lo <= 0 in float).
//  * a LUT whose first positive alpha is entry a: x = 255 t <= a - 1 interpolates two zero
//    entries; whose last is entry b < 255: x >= b + 1 does.
void SetVisibleRange(const ChannelParams& cp, OctoChannelParams* ch) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  ch->visible_lo = -kInf;
  ch->visible_hi = kInf;
  if (!(cp.opacity_scale > 0)) {
    ch->visible_lo = kInf;
    return;
  }
  if (!cp.lut) {
    ch->visible_lo = ch->window_lo;
    return;
  }
  int first = -1;
  int last = -1;
  for (int i = 0; i < kLutEntries; ++i) {
    if ((*cp.lut)[i].a == 0) continue;
    if (first < 0) first = i;
    last = i;
  }
  if (first < 0) {
    ch->visible_lo = kInf;
    return;
  }
  if (first == 1) ch->visible_lo = ch->window_lo;
  if (first >= 2) ch->visible_lo = WindowValueAt(*ch, (first - 1) / 255.0, -1);
  if (last < kLutEntries - 1) ch->visible_hi = WindowValueAt(*ch, (last + 1) / 255.0, +1);
}

}  // namespace

PackedFrame PackRenderFrame(const Camera& camera, const RenderParams& params, double lod_bias,
                            bool skip_empty, const std::array<int64_t, 3>& volume_size,
                            const Vec3& spacing) {
  PackedFrame out;
  OctoRenderFrame& f = out.frame;
  const Vec3 inv{1 / spacing.x, 1 / spacing.y, 1 / spacing.z};
  const auto& n = volume_size;
  const Box3 box = PhysicalBounds({n[0], n[1], n[2]}, spacing);
  const double reference_um = std::min({spacing.x, spacing.y, spacing.z});

  // Orthographic rays start on the camera plane: move the origin along forward to the volume's
  // centre (small float coordinates) and start t at minus that shift.
  Vec3 origin = camera.position();
  double t_min = 0;
  const bool ortho = camera.projection() == Projection::kOrthographic;
  if (ortho) {
    const double shift = Dot(box.Center() - camera.position(), camera.forward());
    origin = origin + camera.forward() * shift;
    t_min = -shift;
  }
  auto put = [](float* dst, const Vec3& v) {
    for (int a = 0; a < 3; ++a) dst[a] = static_cast<float>(v[a]);
  };
  put(f.origin, Mul(origin, inv));
  put(f.forward, Mul(camera.forward(), inv));
  put(f.right, Mul(camera.right(), inv));
  put(f.up, Mul(camera.up(), inv));
  f.projection = ortho ? OCTO_PROJECTION_ORTHO : OCTO_PROJECTION_PERSPECTIVE;
  const double pixel_scale =
      ortho ? camera.ortho_height() / camera.height()
            : 2 * std::tan(camera.fov_y_degrees() * std::numbers::pi / 360.0) / camera.height();
  f.pixel_scale = static_cast<float>(pixel_scale);
  f.t_min = static_cast<float>(t_min);
  // Footprint in finest voxels (ortho) or per µm of distance (perspective), times 2^bias.
  f.lod_scale = static_cast<float>(pixel_scale * std::exp2(lod_bias) / reference_um);
  f.inv_reference = static_cast<float>(1 / reference_um);
  for (int a = 0; a < 3; ++a) f.lod_spacing[a] = static_cast<float>(spacing[a] / reference_um);

  // Physical plane n . p <= d is (n * s) . p_vox <= d in voxel space.
  f.clip_count = static_cast<int>(params.clip_planes.size());
  for (size_t k = 0; k < params.clip_planes.size(); ++k) {
    put(f.clip[k], Mul(params.clip_planes[k].normal, spacing));
    f.clip[k][3] = static_cast<float>(params.clip_planes[k].distance);
  }
  const double bg_a = params.background[3];
  for (int k = 0; k < 3; ++k) f.background[k] = static_cast<float>(params.background[k] * bg_a);
  f.background[3] = static_cast<float>(bg_a);
  for (int a = 0; a < 3; ++a) f.volume[a] = static_cast<float>(n[a]);
  f.step = static_cast<float>(params.step_voxels);
  f.width = camera.width();
  f.height = camera.height();

  // Enabled channels only, with voxel-space transforms S^-1 T S and their LUTs.
  for (size_t c = 0; c < params.channels.size(); ++c) {
    const ChannelParams& cp = params.channels[c];
    if (!cp.enabled) continue;
    OctoChannelParams ch{};
    const Mat4& m = cp.transform;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j)
        ch.transform[i * 4 + j] = static_cast<float>(m(i, j) * spacing[j] * inv[i]);
      ch.transform[i * 4 + 3] = static_cast<float>(m(i, 3) * inv[i]);
    }
    ch.identity = m.IsIdentity() ? 1 : 0;
    out.all_identity = out.all_identity && m.IsIdentity();
    for (int k = 0; k < 3; ++k) ch.color[k] = static_cast<float>(cp.color[k]);
    ch.window_lo = static_cast<float>(cp.level - cp.window / 2);
    ch.inv_window = static_cast<float>(1 / cp.window);
    ch.gamma = static_cast<float>(cp.gamma);
    ch.opacity_scale = static_cast<float>(cp.opacity_scale);
    ch.channel = static_cast<int>(c);
    ch.lut = -1;
    if (cp.lut) {
      ch.lut = static_cast<int>(out.lut.size() / (4 * kLutEntries));
      for (const volume::Rgba& e : *cp.lut) {
        for (uint8_t v : {e.r, e.g, e.b, e.a}) out.lut.push_back(static_cast<float>(v / 255.0));
      }
    }
    SetVisibleRange(cp, &ch);
    out.channels.push_back(ch);
  }
  f.active_channels = static_cast<int>(out.channels.size());
  f.all_identity = out.all_identity ? 1 : 0;
  f.skip_empty = skip_empty ? 1 : 0;
  if (out.channels.empty()) out.channels.emplace_back();
  if (out.lut.empty()) out.lut.assign(4, 0.0f);
  return out;
}

}  // namespace octoscope::render
