#include "render/render_params.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

namespace octoscope::render {
namespace {

bool Finite(double v) { return std::isfinite(v); }

Status ValidateChannel(const ChannelParams& c, int index) {
  const std::string where = "channel " + std::to_string(index) + ": ";
  if (!Finite(c.window) || c.window <= 0) {
    return InvalidArgumentError(where + "window must be finite and > 0, got " +
                                std::to_string(c.window));
  }
  if (!Finite(c.level)) return InvalidArgumentError(where + "level must be finite");
  if (!Finite(c.gamma) || c.gamma <= 0) {
    return InvalidArgumentError(where + "gamma must be finite and > 0, got " +
                                std::to_string(c.gamma));
  }
  if (!Finite(c.opacity_scale) || c.opacity_scale < 0) {
    return InvalidArgumentError(where + "opacity scale must be finite and >= 0, got " +
                                std::to_string(c.opacity_scale));
  }
  for (double v : c.color) {
    if (!Finite(v) || v < 0 || v > 1) {
      return InvalidArgumentError(where + "colour components must lie in [0, 1]");
    }
  }
  if (!c.transform.IsAffine()) {
    return InvalidArgumentError(where +
                                "transform must be a finite affine matrix (last row 0 0 0 1)");
  }
  return Status::Ok();
}

}  // namespace

std::string_view RenderModeName(RenderMode mode) {
  switch (mode) {
    case RenderMode::kDvr:
      return "dvr";
    case RenderMode::kMip:
      return "mip";
    case RenderMode::kMinIp:
      return "minip";
  }
  return "?";
}

std::optional<RenderMode> RenderModeFromName(std::string_view name) {
  for (RenderMode m : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    if (RenderModeName(m) == name) return m;
  }
  return std::nullopt;
}

ChannelParams FullRangeChannel(volume::DataType stored_type) {
  ChannelParams c;
  const double max = volume::TypeMax(stored_type);
  c.window = max;
  c.level = max / 2;
  return c;
}

RenderParams DefaultRenderParams(int channel_count, volume::DataType stored_type, RenderMode mode) {
  RenderParams p;
  p.mode = mode;
  p.channels.assign(static_cast<size_t>(std::max(channel_count, 0)), FullRangeChannel(stored_type));
  return p;
}

std::array<double, 3> DefaultChannelColor(const volume::VolumeInfo& info, int channel) {
  const int count = info.channel_count();
  if (channel >= 0 && channel < count) {
    if (const auto& c = info.channels[channel].color; c.has_value() && (c->r || c->g || c->b)) {
      return {c->r / 255.0, c->g / 255.0, c->b / 255.0};
    }
  }
  if (count <= 1) return {1, 1, 1};
  if (count == 2)
    return channel == 0 ? std::array<double, 3>{0, 1, 0} : std::array<double, 3>{1, 0, 1};
  static constexpr std::array<std::array<double, 3>, 7> kFiji = {
      {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}, {0, 1, 1}, {1, 0, 1}, {1, 1, 0}}};
  return kFiji[static_cast<size_t>(channel) % kFiji.size()];
}

void SetWindow(ChannelParams& channel, double lo_stored, double hi_stored) {
  if (!(hi_stored > lo_stored)) hi_stored = lo_stored + 1;
  channel.window = hi_stored - lo_stored;
  channel.level = (hi_stored + lo_stored) / 2;
}

Status ValidateRenderParams(const RenderParams& params, int channel_count) {
  if (static_cast<int64_t>(params.channels.size()) != channel_count) {
    return InvalidArgumentError("render parameters describe " +
                                std::to_string(params.channels.size()) +
                                " channels, the volume has " + std::to_string(channel_count));
  }
  for (size_t i = 0; i < params.channels.size(); ++i) {
    OCTO_RETURN_IF_ERROR(ValidateChannel(params.channels[i], static_cast<int>(i)));
  }
  if (params.clip_planes.size() > static_cast<size_t>(kMaxClipPlanes)) {
    return InvalidArgumentError("at most " + std::to_string(kMaxClipPlanes) +
                                " clipping planes, got " +
                                std::to_string(params.clip_planes.size()));
  }
  for (size_t i = 0; i < params.clip_planes.size(); ++i) {
    const ClipPlane& p = params.clip_planes[i];
    if (!IsFinite(p.normal) || Length(p.normal) == 0 || !Finite(p.distance)) {
      return InvalidArgumentError("clipping plane " + std::to_string(i) +
                                  ": normal must be finite and non-zero, distance finite");
    }
  }
  if (!Finite(params.step_voxels) || params.step_voxels < kMinStepVoxels ||
      params.step_voxels > kMaxStepVoxels) {
    return InvalidArgumentError("step must lie in [1/64, 64] voxels, got " +
                                std::to_string(params.step_voxels));
  }
  for (double v : params.background) {
    if (!Finite(v) || v < 0 || v > 1) {
      return InvalidArgumentError("background components must lie in [0, 1]");
    }
  }
  return Status::Ok();
}

double WindowedValue(const ChannelParams& channel, double stored) {
  const double lo = channel.level - channel.window / 2;
  double t = (stored - lo) / channel.window;
  // Written so that NaN lands on 0 rather than propagating.
  t = t > 0 ? (t < 1 ? t : 1.0) : 0.0;
  if (channel.gamma != 1) t = std::pow(t, channel.gamma);
  return t;
}

std::array<double, 4> TransferFunction(const ChannelParams& channel, double t) {
  t = t > 0 ? (t < 1 ? t : 1.0) : 0.0;
  std::array<double, 4> rgba;
  if (channel.lut) {
    // Linear interpolation between entries; entry i sits at t = i / 255.
    const auto& lut = *channel.lut;
    const double x = t * (kLutEntries - 1);
    const int i0 = std::min(static_cast<int>(x), kLutEntries - 1);
    const int i1 = std::min(i0 + 1, kLutEntries - 1);
    const double f = x - i0;
    auto mix = [f](uint8_t a, uint8_t b) { return ((1 - f) * a + f * b) / 255.0; };
    rgba = {mix(lut[i0].r, lut[i1].r), mix(lut[i0].g, lut[i1].g), mix(lut[i0].b, lut[i1].b),
            mix(lut[i0].a, lut[i1].a)};
  } else {
    rgba = {channel.color[0] * t, channel.color[1] * t, channel.color[2] * t, t};
  }
  rgba[3] = std::clamp(rgba[3] * channel.opacity_scale, 0.0, 1.0);
  return rgba;
}

double CorrectOpacity(double alpha, double length_ratio) {
  if (alpha <= 0) return 0;
  if (alpha >= 1) return 1;
  // log1p/expm1 keep precision for the tiny alphas of fine steps.
  return -std::expm1(length_ratio * std::log1p(-alpha));
}

}  // namespace octoscope::render
