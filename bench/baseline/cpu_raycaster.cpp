#include "baseline/cpu_raycaster.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <utility>

#include "render/reference_renderer.h"
#include "util/checked_math.h"

namespace octoscope::bench {

using render::Box3;
using render::Camera;
using render::ChannelParams;
using render::ClipRayToVolume;
using render::kEarlyTerminationAlpha;
using render::kLutEntries;
using render::Mat4;
using render::Ray;
using render::RenderImage;
using render::RenderMode;
using render::RenderParams;
using render::Vec3;

namespace {

// One enabled channel, with everything the inner loop needs in float.
struct ChannelPlan {
  int index = 0;
  const uint16_t* data = nullptr;
  bool identity = true;
  // Transformed channels: voxel coordinates u_c = m * u + b (the physical transform conjugated by
  // the spacing) and the box in those coordinates, widened by a rounding tolerance.
  float m[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  float b[3] = {0, 0, 0};
  float box_lo[3] = {0, 0, 0};
  float box_hi[3] = {0, 0, 0};
  // Window: t = clamp((v - lo) * inv_window, 0, 1) ^ gamma.
  float lo = 0;
  float inv_window = 1;
  float gamma = 1;
  // Transfer function: LUT (straight RGBA in [0, 1]) or colour ramp; alpha times opacity_scale.
  std::vector<std::array<float, 4>> lut;
  float color[3] = {1, 1, 1};
  float opacity_scale = 1;
};

// The volume's addressing, in the types the inner loop uses.
struct Grid {
  int64_t n[3];
  float hi[3];       // n - 1: the last voxel centre.
  size_t stride[3];  // 1, nx, nx * ny.
};

float Windowed(const ChannelPlan& ch, float v) {
  float t = (v - ch.lo) * ch.inv_window;
  // Written so that NaN lands on 0, as WindowedValue does.
  t = t > 0 ? (t < 1 ? t : 1.0f) : 0.0f;
  if (ch.gamma != 1) t = std::pow(t, ch.gamma);
  return t;
}

std::array<float, 4> Transfer(const ChannelPlan& ch, float t) {
  t = t > 0 ? (t < 1 ? t : 1.0f) : 0.0f;
  std::array<float, 4> rgba;
  if (!ch.lut.empty()) {
    // Linear interpolation between entries; entry i sits at t = i / 255.
    const float x = t * (kLutEntries - 1);
    const int i0 = std::min(static_cast<int>(x), kLutEntries - 1);
    const int i1 = std::min(i0 + 1, kLutEntries - 1);
    const float f = x - static_cast<float>(i0);
    for (int k = 0; k < 4; ++k) rgba[k] = ch.lut[i0][k] + (ch.lut[i1][k] - ch.lut[i0][k]) * f;
  } else {
    rgba = {ch.color[0] * t, ch.color[1] * t, ch.color[2] * t, t};
  }
  rgba[3] = std::clamp(rgba[3] * ch.opacity_scale, 0.0f, 1.0f);
  return rgba;
}

float CorrectOpacityF(float alpha, float ratio) {
  if (alpha <= 0) return 0;
  if (alpha >= 1) return 1;
  // log1p/expm1 keep precision for the tiny alphas of fine steps (as CorrectOpacity).
  return -std::expm1(ratio * std::log1p(-alpha));
}

// The 2x2x2 footprint of voxel position u (clamped to the edge voxels): first sample offset,
// per-axis offsets to the second sample (0 at the last voxel) and fractions.
struct Footprint {
  size_t o;
  size_t d[3];
  float f[3];
};

inline Footprint FootprintAt(const Grid& g, const float u[3]) {
  Footprint fp;
  size_t o = 0;
  for (int a = 0; a < 3; ++a) {
    float c = u[a] > 0 ? (u[a] < g.hi[a] ? u[a] : g.hi[a]) : 0.0f;
    const float fl = std::floor(c);
    const int64_t i0 = static_cast<int64_t>(fl);
    fp.f[a] = c - fl;
    fp.d[a] = i0 < g.n[a] - 1 ? g.stride[a] : 0;
    o += static_cast<size_t>(i0) * g.stride[a];
  }
  fp.o = o;
  return fp;
}

inline float Trilinear(const uint16_t* d, const Footprint& fp) {
  const uint16_t* p = d + fp.o;
  const size_t dx = fp.d[0], dy = fp.d[1], dz = fp.d[2];
  const float v000 = p[0], v100 = p[dx], v010 = p[dy], v110 = p[dy + dx];
  const float v001 = p[dz], v101 = p[dz + dx], v011 = p[dz + dy], v111 = p[dz + dy + dx];
  const float c00 = v000 + (v100 - v000) * fp.f[0];
  const float c10 = v010 + (v110 - v010) * fp.f[0];
  const float c01 = v001 + (v101 - v001) * fp.f[0];
  const float c11 = v011 + (v111 - v011) * fp.f[0];
  const float c0 = c00 + (c10 - c00) * fp.f[1];
  const float c1 = c01 + (c11 - c01) * fp.f[1];
  return c0 + (c1 - c0) * fp.f[2];
}

// Reads channel `ch` at voxel position u (the identity channels' footprint `shared` already
// computed); false when a transformed position leaves the box.
inline bool SampleChannel(const Grid& g, const ChannelPlan& ch, const float u[3],
                          const Footprint& shared, float* value) {
  if (ch.identity) {
    *value = Trilinear(ch.data, shared);
    return true;
  }
  float q[3];
  for (int a = 0; a < 3; ++a) {
    q[a] = ch.m[3 * a] * u[0] + ch.m[3 * a + 1] * u[1] + ch.m[3 * a + 2] * u[2] + ch.b[a];
    if (!(q[a] >= ch.box_lo[a] && q[a] <= ch.box_hi[a])) return false;
  }
  *value = Trilinear(ch.data, FootprintAt(g, q));
  return true;
}

struct RenderJob {
  const Camera* camera;
  const RenderParams* params;
  const std::vector<ChannelPlan>* active;
  Grid grid;
  Box3 box;
  Vec3 spacing;
  double reference_um;
  bool any_identity;
  RenderImage* image;
};

// Renders rows first_row, first_row + row_step, ... of job.image.
void RenderRows(const RenderJob& job, int first_row, int row_step, CpuRaycastStats* stats) {
  const RenderParams& params = *job.params;
  const std::vector<ChannelPlan>& active = *job.active;
  const Grid& g = job.grid;
  const double bg_a = params.background[3];
  const float bg[4] = {static_cast<float>(params.background[0] * bg_a),
                       static_cast<float>(params.background[1] * bg_a),
                       static_cast<float>(params.background[2] * bg_a), static_cast<float>(bg_a)};
  const bool dvr = params.mode == RenderMode::kDvr;
  const bool max_mode = params.mode == RenderMode::kMip;
  std::vector<float> extreme(active.size());
  std::vector<char> seen(active.size());
  uint64_t steps = 0, samples = 0, rays = 0;
  const int width = job.image->width;

  for (int py = first_row; py < job.image->height; py += row_step) {
    for (int px = 0; px < width; ++px) {
      ++rays;
      float out[4] = {bg[0], bg[1], bg[2], bg[3]};
      const Ray ray = job.camera->PixelRay(px, py);
      const auto interval = ClipRayToVolume(ray, job.box, params.clip_planes);
      if (interval && !active.empty()) {
        // Ray setup in double (once per ray), as the reference: segments in voxel-space length.
        const Vec3 voxel_dir = Div(ray.direction, job.spacing);
        const double voxels_per_um = Length(voxel_dir);
        const double step = params.step_voxels;
        const double length = (interval->second - interval->first) * voxels_per_um;
        const int64_t segments =
            std::max<int64_t>(1, static_cast<int64_t>(std::ceil(length / step - 1e-9)));
        const Vec3 entry = Div(ray.At(interval->first), job.spacing);
        const float base[3] = {static_cast<float>(entry.x - 0.5), static_cast<float>(entry.y - 0.5),
                               static_cast<float>(entry.z - 0.5)};
        const Vec3 inc_d = voxel_dir * (step / voxels_per_um);
        const float inc[3] = {static_cast<float>(inc_d.x), static_cast<float>(inc_d.y),
                              static_cast<float>(inc_d.z)};
        // The last segment is shortened to end at the exit: its own midpoint and length.
        const double last_start = static_cast<double>(segments - 1) * step;
        const double last_len = length - last_start;
        const Vec3 last_d = entry + voxel_dir * ((last_start + last_len / 2) / voxels_per_um);
        const float last_u[3] = {static_cast<float>(last_d.x - 0.5),
                                 static_cast<float>(last_d.y - 0.5),
                                 static_cast<float>(last_d.z - 0.5)};
        const float ratio_full = static_cast<float>(step / voxels_per_um / job.reference_um);
        const float ratio_last = static_cast<float>(last_len / voxels_per_um / job.reference_um);

        if (dvr) {
          float acc[3] = {0, 0, 0};
          float acc_a = 0;
          for (int64_t i = 0; i < segments; ++i) {
            // Midpoint from the entry, never accumulated.
            float u[3];
            const bool last = i + 1 == segments;
            const float k = static_cast<float>(i) + 0.5f;
            for (int a = 0; a < 3; ++a) u[a] = last ? last_u[a] : base[a] + inc[a] * k;
            ++steps;
            Footprint shared{};
            if (job.any_identity) shared = FootprintAt(g, u);
            const float ratio = last ? ratio_last : ratio_full;
            float mix[3] = {0, 0, 0};
            float transmit = 1;
            for (const ChannelPlan& ch : active) {
              float v;
              if (!SampleChannel(g, ch, u, shared, &v)) continue;
              ++samples;
              const std::array<float, 4> rgba = Transfer(ch, Windowed(ch, v));
              const float a = CorrectOpacityF(rgba[3], ratio);
              if (a <= 0) continue;
              for (int c = 0; c < 3; ++c) mix[c] += rgba[c] * a;
              transmit *= 1 - a;
            }
            const float mix_a = 1 - transmit;
            // Intermixing: colours never exceed the mixed opacity (render_params.h).
            for (int c = 0; c < 3; ++c) acc[c] += (1 - acc_a) * std::min(mix[c], mix_a);
            acc_a += (1 - acc_a) * mix_a;
            if (acc_a >= static_cast<float>(kEarlyTerminationAlpha)) break;
          }
          for (int c = 0; c < 3; ++c) out[c] = acc[c] + (1 - acc_a) * out[c];
          out[3] = acc_a + (1 - acc_a) * out[3];
        } else {
          std::fill(extreme.begin(), extreme.end(), max_mode ? -1.0f : 1e9f);
          std::fill(seen.begin(), seen.end(), 0);
          for (int64_t i = 0; i < segments; ++i) {
            float u[3];
            const bool last = i + 1 == segments;
            const float k = static_cast<float>(i) + 0.5f;
            for (int a = 0; a < 3; ++a) u[a] = last ? last_u[a] : base[a] + inc[a] * k;
            ++steps;
            Footprint shared{};
            if (job.any_identity) shared = FootprintAt(g, u);
            for (size_t c = 0; c < active.size(); ++c) {
              float v;
              if (!SampleChannel(g, active[c], u, shared, &v)) continue;
              ++samples;
              // Stored extremes: windowing is monotone, so it is applied once at the end.
              extreme[c] = max_mode ? std::max(extreme[c], v) : std::min(extreme[c], v);
              seen[c] = 1;
            }
          }
          bool any = false;
          for (size_t c = 0; c < active.size(); ++c) {
            if (!seen[c]) continue;
            any = true;
            const std::array<float, 4> rgba = Transfer(active[c], Windowed(active[c], extreme[c]));
            for (int k = 0; k < 3; ++k) out[k] += rgba[k];
          }
          if (any) out[3] = 1;
        }
      }
      float* dst = &job.image->rgba[(static_cast<size_t>(py) * width + px) * 4];
      for (int k = 0; k < 4; ++k) {
        const float v = out[k];
        dst[k] = v > 0 ? (v < 1 ? v : 1.0f) : 0.0f;  // NaN -> 0.
      }
    }
  }
  stats->rays += rays;
  stats->steps += steps;
  stats->samples += samples;
}

// The plan of one enabled channel.
ChannelPlan PlanChannel(int index, const ChannelParams& cp, const uint16_t* data,
                        const std::array<int64_t, 3>& size, const Vec3& spacing) {
  ChannelPlan ch;
  ch.index = index;
  ch.data = data;
  ch.identity = cp.transform.IsIdentity();
  if (!ch.identity) {
    // u_c = S^-1 (L S (u + 0.5) + t) - 0.5 with S = diag(spacing).
    const Mat4& t = cp.transform;
    for (int r = 0; r < 3; ++r) {
      double offset = t(r, 3);
      for (int c = 0; c < 3; ++c) {
        const double m = t(r, c) * spacing[c] / spacing[r];
        ch.m[3 * r + c] = static_cast<float>(m);
        offset += t(r, c) * spacing[c] * 0.5;
      }
      ch.b[r] = static_cast<float>(offset / spacing[r] - 0.5);
      // The box [0, n s] in these coordinates, widened by float rounding of positions.
      const float tolerance = 1e-4f * static_cast<float>(std::max<int64_t>(size[r], 1));
      ch.box_lo[r] = -0.5f - tolerance;
      ch.box_hi[r] = static_cast<float>(size[r]) - 0.5f + tolerance;
    }
  }
  ch.lo = static_cast<float>(cp.level - cp.window / 2);
  ch.inv_window = static_cast<float>(1.0 / cp.window);
  ch.gamma = static_cast<float>(cp.gamma);
  if (cp.lut) {
    ch.lut.resize(kLutEntries);
    for (int i = 0; i < kLutEntries; ++i) {
      const volume::Rgba& e = (*cp.lut)[i];
      ch.lut[i] = {e.r / 255.0f, e.g / 255.0f, e.b / 255.0f, e.a / 255.0f};
    }
  }
  for (int k = 0; k < 3; ++k) ch.color[k] = static_cast<float>(cp.color[k]);
  ch.opacity_scale = static_cast<float>(cp.opacity_scale);
  return ch;
}

}  // namespace

Result<CpuRaycaster> CpuRaycaster::Create(const std::array<int64_t, 3>& size,
                                          const Vec3& spacing_um, volume::DataType stored_type,
                                          std::vector<std::vector<uint16_t>> channels) {
  if (size[0] < 1 || size[1] < 1 || size[2] < 1) {
    return InvalidArgumentError("cpu raycaster: every size must be >= 1");
  }
  const auto voxels =
      CheckedProduct({static_cast<uint64_t>(size[0]), static_cast<uint64_t>(size[1]),
                      static_cast<uint64_t>(size[2])});
  if (!voxels || *voxels > (uint64_t{1} << 40)) {
    return ResourceExhaustedError("cpu raycaster: too many voxels");
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(spacing_um[a]) || spacing_um[a] <= 0) {
      return InvalidArgumentError("cpu raycaster: spacing must be finite and > 0");
    }
  }
  if (stored_type != volume::DataType::kUint8 && stored_type != volume::DataType::kUint16) {
    return InvalidArgumentError("cpu raycaster: stored type must be uint8 or uint16");
  }
  if (channels.empty()) return InvalidArgumentError("cpu raycaster: no channels");
  const uint16_t max = static_cast<uint16_t>(volume::TypeMax(stored_type));
  for (size_t c = 0; c < channels.size(); ++c) {
    if (channels[c].size() != *voxels) {
      return InvalidArgumentError("cpu raycaster: channel " + std::to_string(c) + " has " +
                                  std::to_string(channels[c].size()) + " samples, expected " +
                                  std::to_string(*voxels));
    }
    if (*std::max_element(channels[c].begin(), channels[c].end()) > max) {
      return InvalidArgumentError("cpu raycaster: channel " + std::to_string(c) +
                                  " holds values above the stored type's maximum");
    }
  }
  CpuRaycaster r;
  r.size_ = size;
  r.spacing_ = spacing_um;
  r.stored_type_ = stored_type;
  r.channels_ = std::move(channels);
  return r;
}

Result<RenderImage> CpuRaycaster::Render(const Camera& camera, const RenderParams& params,
                                         int threads, CpuRaycastStats* stats) const {
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, channel_count()));
  const auto start = std::chrono::steady_clock::now();

  // Plan the enabled channels once per image.
  std::vector<ChannelPlan> active;
  bool any_identity = false;
  for (int c = 0; c < channel_count(); ++c) {
    const ChannelParams& cp = params.channels[c];
    if (!cp.enabled) continue;
    active.push_back(PlanChannel(c, cp, channels_[c].data(), size_, spacing_));
    any_identity = any_identity || active.back().identity;
  }

  RenderImage image;
  image.width = camera.width();
  image.height = camera.height();
  image.rgba.assign(static_cast<size_t>(image.width) * image.height * 4, 0.0f);

  RenderJob job;
  job.camera = &camera;
  job.params = &params;
  job.active = &active;
  for (int a = 0; a < 3; ++a) {
    job.grid.n[a] = size_[a];
    job.grid.hi[a] = static_cast<float>(size_[a] - 1);
  }
  job.grid.stride[0] = 1;
  job.grid.stride[1] = static_cast<size_t>(size_[0]);
  job.grid.stride[2] = static_cast<size_t>(size_[0] * size_[1]);
  job.box = bounds();
  job.spacing = spacing_;
  job.reference_um = std::min({spacing_.x, spacing_.y, spacing_.z});
  job.any_identity = any_identity;
  job.image = &image;

  // One thread per hardware thread (never more than rows), rows interleaved.
  int n = threads > 0 ? threads : static_cast<int>(std::thread::hardware_concurrency());
  n = std::clamp(n, 1, image.height);
  std::vector<CpuRaycastStats> per_thread(n);
  std::vector<std::thread> workers;
  workers.reserve(n - 1);
  for (int k = 1; k < n; ++k) {
    workers.emplace_back(RenderRows, std::cref(job), k, n, &per_thread[k]);
  }
  RenderRows(job, 0, n, &per_thread[0]);
  for (std::thread& w : workers) w.join();

  if (stats) {
    CpuRaycastStats total;
    for (const CpuRaycastStats& s : per_thread) {
      total.rays += s.rays;
      total.steps += s.steps;
      total.samples += s.samples;
    }
    total.threads = n;
    total.ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    *stats = total;
  }
  return image;
}

}  // namespace octoscope::bench
