#include "render/reference_renderer.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <span>
#include <string>

#include "util/checked_math.h"

namespace octoscope::render {
namespace {

bool IsStoredType(volume::DataType t) {
  return t == volume::DataType::kUint8 || t == volume::DataType::kUint16;
}

double Clamp01(double v) { return v > 0 ? (v < 1 ? v : 1.0) : 0.0; }  // NaN -> 0.

// The sampling of one ray's interval: segment i covers voxel-space arc length
// [i * step, min((i + 1) * step, length)].
struct RayWalk {
  double t_enter = 0;
  double voxels_per_um = 1;  // |direction / spacing|: voxel-space length per physical µm.
  double step = 1;           // Voxels.
  double length = 0;         // Voxels.
  int64_t segments = 0;

  // Ray parameter of segment i's midpoint and its physical length. REQUIRES: 0 <= i < segments.
  void Segment(int64_t i, double* t, double* length_um) const {
    const double start = static_cast<double>(i) * step;
    const double seg = (i + 1 < segments) ? step : length - start;
    *t = t_enter + (start + seg / 2) / voxels_per_um;
    *length_um = seg / voxels_per_um;
  }
};

// One enabled channel, with what the inner loop needs precomputed.
struct ActiveChannel {
  int index;
  const ChannelParams* params;
  bool identity;  // transform is the identity: positions need no check.
};

}  // namespace

Result<ReferenceVolume> ReferenceVolume::FromStored(const std::array<int64_t, 3>& size,
                                                    const Vec3& spacing_um,
                                                    volume::DataType stored_type,
                                                    std::vector<std::vector<uint16_t>> channels) {
  if (size[0] < 1 || size[1] < 1 || size[2] < 1) {
    return InvalidArgumentError("reference volume: every size must be >= 1");
  }
  const auto voxels =
      CheckedProduct({static_cast<uint64_t>(size[0]), static_cast<uint64_t>(size[1]),
                      static_cast<uint64_t>(size[2])});
  if (!voxels || *voxels > (uint64_t{1} << 40)) {
    return ResourceExhaustedError("reference volume: too many voxels");
  }
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(spacing_um[i]) || spacing_um[i] <= 0) {
      return InvalidArgumentError("reference volume: spacing must be finite and > 0");
    }
  }
  if (!IsStoredType(stored_type)) {
    return InvalidArgumentError("reference volume: stored type must be uint8 or uint16");
  }
  if (channels.empty()) return InvalidArgumentError("reference volume: no channels");
  const uint16_t max = static_cast<uint16_t>(volume::TypeMax(stored_type));
  for (size_t c = 0; c < channels.size(); ++c) {
    if (channels[c].size() != *voxels) {
      return InvalidArgumentError("reference volume: channel " + std::to_string(c) + " has " +
                                  std::to_string(channels[c].size()) + " samples, expected " +
                                  std::to_string(*voxels));
    }
    if (*std::max_element(channels[c].begin(), channels[c].end()) > max) {
      return InvalidArgumentError("reference volume: channel " + std::to_string(c) +
                                  " holds values above the stored type's maximum");
    }
  }
  ReferenceVolume v;
  v.size_ = size;
  v.spacing_ = spacing_um;
  v.stored_type_ = stored_type;
  v.channels_ = std::move(channels);
  return v;
}

Result<ReferenceVolume> ReferenceVolume::Load(io::VolumeSource& source,
                                              const std::vector<volume::ValueMap>& maps,
                                              uint64_t max_bytes) {
  const volume::VolumeInfo& info = source.info();
  OCTO_RETURN_IF_ERROR(info.Validate());
  if (static_cast<int>(maps.size()) != info.channel_count()) {
    return InvalidArgumentError("reference volume: " + std::to_string(maps.size()) +
                                " value maps for " + std::to_string(info.channel_count()) +
                                " channels");
  }
  const volume::DataType stored_type = maps[0].stored_type;
  for (const volume::ValueMap& m : maps) {
    if (m.file_type != info.dtype || m.stored_type != stored_type || !IsStoredType(stored_type)) {
      return InvalidArgumentError("reference volume: value map " + m.ToString() +
                                  " does not fit the source's sample type " +
                                  std::string(volume::NumpyName(info.dtype)));
    }
  }
  const uint64_t plane = info.PlaneVoxels();
  const auto bytes = CheckedProduct(
      {plane, static_cast<uint64_t>(info.size[2]), static_cast<uint64_t>(info.channel_count()), 2});
  if (!bytes || *bytes > max_bytes) {
    return ResourceExhaustedError("reference volume: the volume needs more than " +
                                  std::to_string(max_bytes) + " bytes");
  }
  const size_t stored_bytes = volume::BytesPerSample(stored_type);
  std::vector<std::byte> file_plane(source.SlabBytes(1));
  std::vector<std::byte> stored_plane(plane * stored_bytes);
  std::vector<std::vector<uint16_t>> channels(info.channel_count());
  for (int c = 0; c < info.channel_count(); ++c) {
    std::vector<uint16_t>& out = channels[c];
    out.resize(plane * info.size[2]);
    for (int64_t z = 0; z < info.size[2]; ++z) {
      OCTO_RETURN_IF_ERROR(source.ReadSlab(c, z, 1, file_plane));
      volume::ConvertToStored(maps[c], file_plane, stored_plane);
      uint16_t* dst = out.data() + z * plane;
      if (stored_bytes == 1) {
        for (uint64_t i = 0; i < plane; ++i) dst[i] = static_cast<uint8_t>(stored_plane[i]);
      } else {
        std::memcpy(dst, stored_plane.data(), plane * 2);
      }
    }
  }
  return FromStored(info.size, PhysicalSpacing(info), stored_type, std::move(channels));
}

double ReferenceVolume::Sample(int channel, const Vec3& p) const {
  // Voxel centres sit at integer coordinates u = p / s - 0.5.
  int64_t i0[3], i1[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    const double hi = static_cast<double>(size_[a] - 1);
    double u = p[a] / spacing_[a] - 0.5;
    u = u > 0 ? (u < hi ? u : hi) : 0.0;
    const double fl = std::floor(u);
    i0[a] = static_cast<int64_t>(fl);
    i1[a] = std::min<int64_t>(i0[a] + 1, size_[a] - 1);
    f[a] = u - fl;
  }
  const std::vector<uint16_t>& d = channels_[channel];
  auto at = [&](int64_t x, int64_t y, int64_t z) -> double {
    return d[static_cast<size_t>((z * size_[1] + y) * size_[0] + x)];
  };
  const double c00 = at(i0[0], i0[1], i0[2]) * (1 - f[0]) + at(i1[0], i0[1], i0[2]) * f[0];
  const double c10 = at(i0[0], i1[1], i0[2]) * (1 - f[0]) + at(i1[0], i1[1], i0[2]) * f[0];
  const double c01 = at(i0[0], i0[1], i1[2]) * (1 - f[0]) + at(i1[0], i0[1], i1[2]) * f[0];
  const double c11 = at(i0[0], i1[1], i1[2]) * (1 - f[0]) + at(i1[0], i1[1], i1[2]) * f[0];
  const double c0 = c00 * (1 - f[1]) + c10 * f[1];
  const double c1 = c01 * (1 - f[1]) + c11 * f[1];
  return c0 * (1 - f[2]) + c1 * f[2];
}

std::optional<std::pair<double, double>> ClipRayToVolume(const Ray& ray, const Box3& box,
                                                         const std::vector<ClipPlane>& planes) {
  double t0 = 0;
  double t1 = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const double o = ray.origin[a];
    const double d = ray.direction[a];
    if (d == 0) {
      // Parallel to this slab: inside (faces included) or never.
      if (o < box.lo[a] || o > box.hi[a]) return std::nullopt;
      continue;
    }
    double ta = (box.lo[a] - o) / d;
    double tb = (box.hi[a] - o) / d;
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  for (const ClipPlane& plane : planes) {
    // Keep Dot(n, o + t d) <= distance.
    const double nd = Dot(plane.normal, ray.direction);
    const double rest = plane.distance - Dot(plane.normal, ray.origin);
    if (nd == 0) {
      if (rest < 0) return std::nullopt;
      continue;
    }
    const double t = rest / nd;
    if (nd > 0) {
      t1 = std::min(t1, t);
    } else {
      t0 = std::max(t0, t);
    }
  }
  if (!(t1 > t0) || !std::isfinite(t1)) return std::nullopt;
  return std::make_pair(t0, t1);
}

Result<RenderImage> RenderReference(const ReferenceVolume& volume, const Camera& camera,
                                    const RenderParams& params, RenderStats* stats) {
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, volume.channel_count()));
  const Box3 box = volume.bounds();
  const Vec3 spacing = volume.spacing();
  const double reference_um = std::min({spacing.x, spacing.y, spacing.z});
  // Transformed positions may leave the box by rounding only; anything further gives no sample.
  const double tolerance =
      1e-9 * std::max({box.hi.x - box.lo.x, box.hi.y - box.lo.y, box.hi.z - box.lo.z});

  std::vector<ActiveChannel> active;
  for (int c = 0; c < volume.channel_count(); ++c) {
    const ChannelParams& cp = params.channels[c];
    if (cp.enabled) active.push_back({c, &cp, cp.transform.IsIdentity()});
  }

  RenderStats local;
  local.channel_samples.assign(volume.channel_count(), 0);
  RenderImage image;
  image.width = camera.width();
  image.height = camera.height();
  image.rgba.assign(static_cast<size_t>(image.width) * image.height * 4, 0.0f);

  const double bg_a = params.background[3];
  const std::array<double, 3> bg_premultiplied = {
      params.background[0] * bg_a, params.background[1] * bg_a, params.background[2] * bg_a};

  // Reads channel `ch` at sample position p; false when its transformed position leaves the box.
  auto sample = [&](const ActiveChannel& ch, const Vec3& p, double* value) {
    Vec3 q = p;
    if (!ch.identity) {
      q = ch.params->transform.TransformPoint(p);
      for (int a = 0; a < 3; ++a) {
        if (!(q[a] >= box.lo[a] - tolerance && q[a] <= box.hi[a] + tolerance)) return false;
      }
    }
    *value = volume.Sample(ch.index, q);
    ++local.channel_samples[ch.index];
    return true;
  };

  for (int py = 0; py < image.height; ++py) {
    for (int px = 0; px < image.width; ++px) {
      ++local.rays;
      const Ray ray = camera.PixelRay(px, py);
      std::array<double, 4> out = {bg_premultiplied[0], bg_premultiplied[1], bg_premultiplied[2],
                                   bg_a};
      const auto interval = ClipRayToVolume(ray, box, params.clip_planes);
      if (interval) ++local.rays_hit;
      if (interval && !active.empty()) {
        RayWalk walk;
        walk.t_enter = interval->first;
        walk.voxels_per_um = Length(Div(ray.direction, spacing));
        walk.step = params.step_voxels;
        walk.length = (interval->second - interval->first) * walk.voxels_per_um;
        // The tolerance keeps an exact multiple of the step from growing a sliver segment.
        walk.segments =
            std::max<int64_t>(1, static_cast<int64_t>(std::ceil(walk.length / walk.step - 1e-9)));

        if (params.mode == RenderMode::kDvr) {
          double acc[3] = {0, 0, 0};
          double acc_a = 0;
          for (int64_t i = 0; i < walk.segments; ++i) {
            double t, length_um;
            walk.Segment(i, &t, &length_um);
            const Vec3 p = ray.At(t);
            ++local.steps;
            const double ratio = length_um / reference_um;
            double mix[3] = {0, 0, 0};
            double transmit = 1;
            for (const ActiveChannel& ch : active) {
              double v;
              if (!sample(ch, p, &v)) continue;
              const std::array<double, 4> rgba =
                  TransferFunction(*ch.params, WindowedValue(*ch.params, v));
              const double a = CorrectOpacity(rgba[3], ratio);
              for (int k = 0; k < 3; ++k) mix[k] += rgba[k] * a;
              transmit *= 1 - a;
            }
            const double mix_a = 1 - transmit;
            // Accumulation-level intermixing: premultiplied colours add, but never beyond the
            // mixed opacity (that would emit more light than the sample absorbs).
            for (int k = 0; k < 3; ++k) {
              acc[k] += (1 - acc_a) * std::min(mix[k], mix_a);
            }
            acc_a += (1 - acc_a) * mix_a;
            if (acc_a >= kEarlyTerminationAlpha) {
              ++local.early_terminated;
              break;
            }
          }
          for (int k = 0; k < 3; ++k) out[k] = acc[k] + (1 - acc_a) * out[k];
          out[3] = acc_a + (1 - acc_a) * out[3];
        } else {
          const bool max_mode = params.mode == RenderMode::kMip;
          std::vector<double> extreme(active.size(), max_mode ? -1.0 : 2.0);
          std::vector<bool> seen(active.size(), false);
          for (int64_t i = 0; i < walk.segments; ++i) {
            double t, length_um;
            walk.Segment(i, &t, &length_um);
            const Vec3 p = ray.At(t);
            ++local.steps;
            for (size_t k = 0; k < active.size(); ++k) {
              double v;
              if (!sample(active[k], p, &v)) continue;
              const double w = WindowedValue(*active[k].params, v);
              extreme[k] = max_mode ? std::max(extreme[k], w) : std::min(extreme[k], w);
              seen[k] = true;
            }
          }
          bool any = false;
          for (size_t k = 0; k < active.size(); ++k) {
            if (!seen[k]) continue;
            any = true;
            const std::array<double, 4> rgba = TransferFunction(*active[k].params, extreme[k]);
            for (int c = 0; c < 3; ++c) out[c] += rgba[c];
          }
          if (any) out[3] = 1;
        }
      }
      float* dst = &image.rgba[(static_cast<size_t>(py) * image.width + px) * 4];
      for (int k = 0; k < 4; ++k) dst[k] = static_cast<float>(Clamp01(out[k]));
    }
  }
  if (stats) *stats = std::move(local);
  return image;
}

Result<RenderImage> RenderReference(io::VolumeSource& source,
                                    const std::vector<volume::ValueMap>& maps, const Camera& camera,
                                    const RenderParams& params, RenderStats* stats) {
  OCTO_ASSIGN_OR_RETURN(ReferenceVolume volume, ReferenceVolume::Load(source, maps));
  return RenderReference(volume, camera, params, stats);
}

}  // namespace octoscope::render
