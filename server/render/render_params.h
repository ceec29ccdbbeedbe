// RenderParams: everything but the camera that decides what a rendered image looks like — the
// compositing mode, one transfer function per channel, clipping planes, the per-channel sample
// transforms (chromatic-aberration correction), the sampling step and the background. Shared by
// the OpenCL renderer and the CPU reference renderer, which must agree on every definition here.
//
// Coordinates: "physical" space is micrometres with the volume's corner at the origin: voxel
// (i, j, k) has its centre at ((i + 0.5) sx, (j + 0.5) sy, (k + 0.5) sz) and the volume fills the
// box [0, nx sx] x [0, ny sy] x [0, nz sz] (an axis of unknown spacing counts as 1 µm).
//
// Transfer function of one channel, for a (trilinearly interpolated) stored sample value v:
//   t   = clamp((v - (level - window / 2)) / window, 0, 1) ^ gamma        (WindowedValue)
//   rgb = lut ? lut(t).rgb : color * t                                     (TransferFunction)
//   a   = clamp((lut ? lut(t).a : t) * opacity_scale, 0, 1)
// i.e. without a LUT the channel is a linear ramp from transparent black to opaque `color`. A LUT
// is read with linear interpolation between its 256 entries at position t * 255.
//
// DVR: a is the opacity of a slab one reference length thick (the smallest voxel spacing); a
// sample covering a physical length l uses 1 - (1 - a)^(l / reference). Channels are intermixed
// per sample (accumulation level): premultiplied colours add (clamped to the mixed alpha), alphas
// combine as 1 - prod(1 - a_c); samples composite front to back until alpha >= 0.999.
// MIP / MinIP: per channel the max / min along the ray of t; its rgb (alpha ignored) adds over the
// channels and the background, clamped to 1.
//
// Thread safety: plain value types; functions are pure.
#ifndef OCTOSCOPE_RENDER_RENDER_PARAMS_H_
#define OCTOSCOPE_RENDER_RENDER_PARAMS_H_

#include <array>
#include <optional>
#include <string_view>
#include <vector>

#include "render/linear_algebra.h"
#include "util/status.h"
#include "volume/data_type.h"
#include "volume/volume_info.h"

namespace octoscope::render {

enum class RenderMode {
  kDvr,    // Direct volume rendering: emission-absorption, front to back.
  kMip,    // Maximum intensity projection.
  kMinIp,  // Minimum intensity projection.
};

std::string_view RenderModeName(RenderMode mode);  // "dvr", "mip", "minip".
std::optional<RenderMode> RenderModeFromName(std::string_view name);

inline constexpr int kMaxClipPlanes = 3;
inline constexpr int kLutEntries = 256;
// DVR rays stop once their accumulated opacity reaches this.
inline constexpr double kEarlyTerminationAlpha = 0.999;
// Allowed sampling steps, in voxels.
inline constexpr double kMinStepVoxels = 1.0 / 64;
inline constexpr double kMaxStepVoxels = 64;

// One channel's appearance. Invariants (ValidateRenderParams): window > 0; gamma > 0;
// opacity_scale >= 0; colour components in [0, 1]; transform affine; everything finite.
struct ChannelParams {
  // A disabled channel contributes nothing and is never sampled.
  bool enabled = true;
  std::array<double, 3> color{1, 1, 1};  // Linear RGB in [0, 1]; used when there is no LUT.
  // Window width and centre in stored units (the octree's uint8/uint16 values; a ValueMap turns
  // file units into stored units). The default covers the full uint16 range.
  double window = 65535;
  double level = 32767.5;
  double gamma = 1;
  double opacity_scale = 1;
  std::optional<std::array<volume::Rgba, kLutEntries>> lut;  // Replaces colour and ramp.
  // Chromatic-aberration correction: each sample position p (physical) of this channel is read
  // from the volume at transform * p. Positions that land outside the volume's box give no sample
  // of this channel (they contribute nothing).
  Mat4 transform;
};

// A half-space: a position p (physical) is kept when Dot(normal, p) <= distance. The normal need
// not be unit length (distance is then in units of |normal| µm). Invariant: normal finite and
// non-zero; distance finite.
struct ClipPlane {
  Vec3 normal{0, 0, 1};
  double distance = 0;
};

struct RenderParams {
  RenderMode mode = RenderMode::kDvr;
  std::vector<ChannelParams> channels;  // One per volume channel.
  std::vector<ClipPlane> clip_planes;   // At most kMaxClipPlanes; all of them must keep a sample.
  // Distance between samples along a ray measured in voxel index space (a step of 1 advances one
  // voxel along any axis-aligned ray, whatever the spacing). In [kMinStepVoxels, kMaxStepVoxels].
  double step_voxels = 1;
  // Straight (not premultiplied) RGBA in [0, 1]; DVR composites over it, MIP/MinIP add onto it.
  std::array<double, 4> background{0, 0, 0, 0};
};

// A channel showing the stored type's full range as a grey ramp (window [0, TypeMax]).
// REQUIRES: stored_type is kUint8 or kUint16.
ChannelParams FullRangeChannel(volume::DataType stored_type);

// `channel_count` full-range grey channels, everything else default.
RenderParams DefaultRenderParams(int channel_count, volume::DataType stored_type, RenderMode mode);

// The colour channel `channel` of `info` shows by default: the file's own colour when it names a
// visible one, else distinct defaults the way Fiji's composite mode and napari assign them — one
// channel grey; two green and magenta; more red, green, blue, grey, cyan, magenta, yellow
// (repeating) — so that channels without colours never render as one white blob.
std::array<double, 3> DefaultChannelColor(const volume::VolumeInfo& info, int channel);

// Sets the channel's window so that stored values lo..hi map to t = 0..1 (auto-contrast from a
// histogram's percentiles). hi <= lo widens to one stored unit.
void SetWindow(ChannelParams& channel, double lo_stored, double hi_stored);

// Checks the invariants above and that there is one ChannelParams per channel.
Status ValidateRenderParams(const RenderParams& params, int channel_count);

// t in [0, 1] for stored value `stored` (see the header comment). Never NaN for finite input.
double WindowedValue(const ChannelParams& channel, double stored);

// Straight RGBA of the transfer function at t in [0, 1] (alpha already scaled and clamped).
std::array<double, 4> TransferFunction(const ChannelParams& channel, double t);

// The opacity of a sample covering `length_ratio` reference lengths: 1 - (1 - alpha)^ratio.
double CorrectOpacity(double alpha, double length_ratio);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_RENDER_PARAMS_H_
