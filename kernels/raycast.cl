/* Ray casting of a DeviceOctree (server/render/volume_renderer.h; docs/rendering.md): one work
 * item per pixel, with exactly the definitions of the CPU reference renderer
 * (server/render/reference_renderer.cpp) in float precision.
 *
 * Compile-time configuration (-D): OCTO_MODE (OCTO_MODE_DVR / _MIP / _MINIP) and OCTO_REFINE
 * (0: full frame, one pass, missing bricks replaced by coarser data; 1: refinement, a ray pauses
 * at the first sample whose wanted brick is missing and resumes in the next pass).
 *
 * Per ray: clip [t_min, inf) to the box [0, n] and the planes (as ClipRayToVolume), walk
 * segments of `step` voxels (arc length in voxel space) whose midpoints are entry + (i + 0.5) dt
 * (the last segment shortened to the exit), never accumulated. Per sample: the level of detail
 * from the pixel footprint; per enabled channel: its transformed position (outside the box: no
 * sample), clamped into the valid extent of the level (so clamp-to-edge equals the reference's
 * and no virtual voxel is read), the octree node (OctoFindNode), trilinear brick sample or node
 * average, transfer function, compositing.
 */
#include "feedback.h"
#include "node_format.h"
#include "octree_sampling.cl"
#include "render_format.h"

#ifndef OCTO_MODE
#define OCTO_MODE OCTO_MODE_DVR
#endif
#ifndef OCTO_REFINE
#define OCTO_REFINE 0
#endif

/* Float rounding of the interval (a few ulps of the t values) must not grow or drop a sliver
 * segment where the reference (double, 1e-9) would not: lengths within this many ulps of |t| of
 * a step multiple count as that multiple. */
#define OCTO_SLIVER_ULPS 4.0f

/* Full frame: a resident ancestor more than this many levels above the wanted node is too coarse;
 * the wanted node's average is used instead. */
#define OCTO_MAX_FALLBACK_LEVELS 2

/* WindowedValue of render_params.h: window, clamp to [0, 1], gamma. */
float OctoWindowed(__global const OctoChannelParams* ch, float v) {
  float t = clamp((v - ch->window_lo) * ch->inv_window, 0.0f, 1.0f);
  if (ch->gamma != 1.0f) t = pow(t, ch->gamma);
  return t;
}

/* TransferFunction of render_params.h: straight RGBA, alpha scaled and clamped. */
float4 OctoTransfer(__global const OctoChannelParams* ch, __global const float4* lut, float t) {
  t = clamp(t, 0.0f, 1.0f);
  float4 rgba;
  if (ch->lut >= 0) {
    /* Linear interpolation between entries; entry i sits at t = i / 255. */
    const float x = t * (float)(OCTO_LUT_ENTRIES - 1);
    const int i0 = min((int)x, OCTO_LUT_ENTRIES - 1);
    const int i1 = min(i0 + 1, OCTO_LUT_ENTRIES - 1);
    __global const float4* entries = lut + (size_t)ch->lut * OCTO_LUT_ENTRIES;
    rgba = mix(entries[i0], entries[i1], x - (float)i0);
  } else {
    rgba = (float4)(ch->color[0] * t, ch->color[1] * t, ch->color[2] * t, t);
  }
  rgba.w = clamp(rgba.w * ch->opacity_scale, 0.0f, 1.0f);
  return rgba;
}

/* CorrectOpacity of render_params.h: 1 - (1 - a)^ratio, precise for tiny alphas. */
float OctoCorrectOpacity(float a, float ratio) {
  if (a <= 0.0f) return 0.0f;
  if (a >= 1.0f) return 1.0f;
  return -expm1(ratio * log1p(-a));
}

/* floor(log2(footprint)) clamped to the tree's levels; ilogb is exact at powers of two. */
int OctoLevelOf(float footprint, OctoTreeGeometry g) {
  return clamp(ilogb(fmax(footprint, 1e-30f)), 0, g.root_level);
}

/* p (level 0) clamped so that its level-`level` coordinate lies in [0.5, LevelSize - 0.5]: the
 * centres of the level's valid voxels (LevelSize = ceil(n / 2^level)). */
float3 OctoClampToLevel(float3 p, int level, OctoTreeGeometry g) {
  const int3 n = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
  const int3 size = (n + (1 << level) - 1) >> level;
  const float scale = ldexp(1.0f, level);
  const float3 q = clamp(p / scale, 0.5f, convert_float3(size) - 0.5f);
  return q * scale;
}

/* The position of a channel's sample: transform * p; false when it leaves the volume box. */
bool OctoChannelPosition(__global const OctoChannelParams* ch, float3 p, OctoRenderFrame f,
                         float3* q) {
  if (ch->identity) {
    *q = p;
    return true;
  }
  const __global float* m = ch->transform;
  const float3 r = (float3)(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                            m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
  /* Rounding may leave the box by a hair; anything further gives no sample. */
  const float3 box = (float3)(f.volume[0], f.volume[1], f.volume[2]);
  const float tolerance = 1e-5f * fmax(box.x, fmax(box.y, box.z));
  if (!(all(r >= -tolerance) && all(r <= box + tolerance))) return false;
  *q = r;
  return true;
}

/* Whether the wanted node of `hit` has a brick that is not resident (a deeper node than `hit`'s
 * is never renderable; the root may be `hit` without being renderable). */
bool OctoWantedMissing(OctoNodeHit hit) {
  return hit.node != hit.wanted || (OctoNodeHasBrick(hit.word0) && !OctoNodeInBuffer(hit.word0));
}

/* The value of channel c at q (already clamped to `level`) as `hit` represents it; marks the slot
 * used and, in full-frame mode, requests the wanted node and applies the fallback rule. */
float OctoReadChannel(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g,
                      OctoNodeHit hit, float3 q, int c, volatile __global uint* request_flags,
                      volatile __global uint* request_list, uint capacity, __global uint* slot_used,
                      uint frame) {
#if !OCTO_REFINE
  if (OctoWantedMissing(hit)) {
    OctoRequestNode(request_flags, request_list, capacity, hit.wanted, frame);
    if (hit.level - hit.wanted_level > OCTO_MAX_FALLBACK_LEVELS) {
      return OctoNodeAverage(nodes, hit.wanted, g, c);
    }
  }
#else
  (void)request_flags;
  (void)request_list;
  (void)capacity;
#endif
  if (!OctoNodeInBuffer(hit.word0)) return OctoNodeAverage(nodes, hit.node, g, c);
  /* A coarser node than the sample's level: its own valid extent bounds the footprint. */
  const float3 p = OctoClampToLevel(q, hit.level, g);
  uint local_slot;
  __global const ushort* bricks =
      OctoBrickAllocation(OCTO_BRICK_BUFFER_ARGS, hit.slot, &local_slot);
  OctoMarkSlotUsed(slot_used, hit.slot, frame);
  return OctoSampleBrick(bricks, g, local_slot, hit.index, hit.level, p, c);
}

/* Adds n to the 64-bit sample counter held as two uint words (carry on wrap-around). */
void OctoAddSamples(volatile __global uint* counters, uint n) {
  if (n == 0u) return;
  const uint old = atomic_add(&counters[OCTO_COUNTER_SAMPLES_LO], n);
  if (old + n < old) atomic_inc(&counters[OCTO_COUNTER_SAMPLES_HI]);
}

/* The pixel of the current ray state (DVR: composited over the background; MIP/MinIP: the
 * extrema's colours added onto it), clamped to [0, 1]. */
float4 OctoFinishPixel(OctoRenderFrame f, __global const OctoChannelParams* channels,
                       __global const float4* lut, float4 acc, const float* extreme) {
  const float4 bg = (float4)(f.background[0], f.background[1], f.background[2], f.background[3]);
  float4 out;
#if OCTO_MODE == OCTO_MODE_DVR
  (void)channels;
  (void)lut;
  (void)extreme;
  out = acc + (1.0f - acc.w) * bg;
#else
  (void)acc;
  out = bg;
  bool any = false;
  for (int k = 0; k < f.active_channels; ++k) {
    const float e = extreme[k];
    if (!(e >= 0.0f && e <= 1.0f)) continue; /* Never sampled. */
    any = true;
    out.xyz += OctoTransfer(&channels[k], lut, e).xyz;
  }
  if (any) out.w = 1.0f;
#endif
  return clamp(out, 0.0f, 1.0f);
}

__kernel void RayCast(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g,
                      OctoRenderFrame f, __global const OctoChannelParams* channels,
                      __global const float4* lut, volatile __global uint* request_flags,
                      volatile __global uint* request_list, uint request_capacity,
                      __global uint* slot_used, uint frame, __global float4* image,
                      volatile __global uint* counters, __global uint* ray_next,
                      __global float4* ray_acc, __global float* ray_extreme) {
  const int pixel = (int)get_global_id(0);
  if (pixel >= f.width * f.height) return;
#if OCTO_REFINE
  uint first = ray_next[pixel];
  if (first == OCTO_RAY_DONE) return; /* Finished in an earlier pass. */
#else
  (void)ray_next;
  (void)ray_acc;
  (void)ray_extreme;
  const uint first = 0u;
#endif
  const int px = pixel % f.width;
  const int py = pixel / f.width;

  /* The pixel's ray (Camera::PixelRay), in voxel space with the physical parameter t. */
  const float3 forward = (float3)(f.forward[0], f.forward[1], f.forward[2]);
  const float3 right = (float3)(f.right[0], f.right[1], f.right[2]);
  const float3 up = (float3)(f.up[0], f.up[1], f.up[2]);
  const float dx = ((float)px + 0.5f - 0.5f * (float)f.width) * f.pixel_scale;
  const float dy = (0.5f * (float)f.height - ((float)py + 0.5f)) * f.pixel_scale;
  float3 o = (float3)(f.origin[0], f.origin[1], f.origin[2]);
  float3 d;
  float cos_forward = 1.0f; /* Cosine between the ray and forward (perspective distance). */
  if (f.projection == OCTO_PROJECTION_ORTHO) {
    o += right * dx + up * dy;
    d = forward;
  } else {
    /* |forward + right dx + up dy| = sqrt(1 + dx^2 + dy^2) for the orthonormal physical frame. */
    cos_forward = rsqrt(1.0f + dx * dx + dy * dy);
    d = (forward + right * dx + up * dy) * cos_forward;
  }

  /* Clip to the box [0, n] (faces inclusive) and the planes, exactly like ClipRayToVolume. */
  float t0 = f.t_min;
  float t1 = INFINITY;
  bool hit_box = true;
  const float3 box = (float3)(f.volume[0], f.volume[1], f.volume[2]);
  for (int a = 0; a < 3; ++a) {
    const float oa = a == 0 ? o.x : (a == 1 ? o.y : o.z);
    const float da = a == 0 ? d.x : (a == 1 ? d.y : d.z);
    const float hi = a == 0 ? box.x : (a == 1 ? box.y : box.z);
    if (da == 0.0f) {
      if (oa < 0.0f || oa > hi) hit_box = false;
      continue;
    }
    const float ta = (0.0f - oa) / da;
    const float tb = (hi - oa) / da;
    t0 = fmax(t0, fmin(ta, tb));
    t1 = fmin(t1, fmax(ta, tb));
  }
  for (int k = 0; k < f.clip_count; ++k) {
    const float3 n = (float3)(f.clip[k][0], f.clip[k][1], f.clip[k][2]);
    const float nd = dot(n, d);
    const float rest = f.clip[k][3] - dot(n, o);
    if (nd == 0.0f) {
      if (rest < 0.0f) hit_box = false;
      continue;
    }
    const float t = rest / nd;
    if (nd > 0.0f) {
      t1 = fmin(t1, t);
    } else {
      t0 = fmax(t0, t);
    }
  }
  const bool empty = !hit_box || !(t1 > t0) || !isfinite(t1) || f.active_channels == 0;

  /* Ray state: accumulated premultiplied colour (DVR) or per-channel extremum (MIP/MinIP). */
  float4 acc = (float4)(0.0f);
  float extreme[OCTO_MAX_ACTIVE_CHANNELS];
#if OCTO_MODE != OCTO_MODE_DVR
  for (int k = 0; k < f.active_channels; ++k) {
#if OCTO_REFINE
    extreme[k] = ray_extreme[(size_t)pixel * (size_t)f.active_channels + (size_t)k];
#else
    /* "Not sampled": outside [0, 1], and any windowed value replaces it. */
    extreme[k] = OCTO_MODE == OCTO_MODE_MIP ? -1.0f : 2.0f;
#endif
  }
#else
  extreme[0] = 0.0f;
#endif
#if OCTO_REFINE && OCTO_MODE == OCTO_MODE_DVR
  acc = ray_acc[pixel];
#endif

  uint samples = 0u;
  bool paused = false;
  uint i = first;
  if (!empty) {
    /* Arc length in voxel space: |d_vox| voxels per µm; positions entry + u * arc. */
    const float vpu = length(d);
    const float3 u = d / vpu;
    const float3 entry = o + d * t0;
    const float len = (t1 - t0) * vpu;
    const float rounding = OCTO_SLIVER_ULPS * FLT_EPSILON * (fabs(t0) + fabs(t1)) * vpu;
    const uint segments = (uint)fmax(1.0f, ceil((len - rounding) / f.step));
    const bool perspective = f.projection == OCTO_PROJECTION_PERSPECTIVE;
    while (i < segments) {
      /* Segment i's midpoint, computed from its index (never accumulated). */
      const float start = (float)i * f.step;
      const float seg = (i + 1u < segments) ? f.step : len - start;
      const float arc = start + 0.5f * seg;
      const float3 p = entry + u * arc;
      /* The screen decides the level: the pixel footprint at the sample's distance. */
      const float footprint =
          perspective ? f.lod_scale * (t0 + arc / vpu) * cos_forward : f.lod_scale;
      const int level = OctoLevelOf(footprint, g);

      /* Without transforms every channel reads the same node: traverse once. */
      OctoNodeHit shared_hit;
      float3 shared_q = p;
      if (f.all_identity) {
        shared_q = OctoClampToLevel(p, level, g);
        shared_hit = OctoFindNode(nodes, g, shared_q, level);
      }
#if OCTO_REFINE
      /* Refinement samples only the wanted level: a missing brick pauses the ray here. */
      bool missing = false;
      for (int k = 0; k < f.active_channels; ++k) {
        OctoNodeHit hit;
        if (f.all_identity) {
          if (k > 0) break;
          hit = shared_hit;
        } else {
          float3 q;
          if (!OctoChannelPosition(&channels[k], p, f, &q)) continue;
          hit = OctoFindNode(nodes, g, OctoClampToLevel(q, level, g), level);
        }
        if (OctoWantedMissing(hit)) {
          OctoRequestNode(request_flags, request_list, request_capacity, hit.wanted, frame);
          missing = true;
        }
      }
      if (missing) {
        paused = true;
        break;
      }
#endif

#if OCTO_MODE == OCTO_MODE_DVR
      float3 mix_rgb = (float3)(0.0f);
      float transmit = 1.0f;
      bool transparent = true;
      const float ratio = seg / vpu * f.inv_reference;
#endif
      for (int k = 0; k < f.active_channels; ++k) {
        OctoNodeHit hit;
        float3 q;
        if (f.all_identity) {
          hit = shared_hit;
          q = shared_q;
        } else {
          if (!OctoChannelPosition(&channels[k], p, f, &q)) continue;
          q = OctoClampToLevel(q, level, g);
          hit = OctoFindNode(nodes, g, q, level);
        }
        const float v =
            OctoReadChannel(nodes, OCTO_BRICK_BUFFER_ARGS, g, hit, q, channels[k].channel,
                            request_flags, request_list, request_capacity, slot_used, frame);
        ++samples;
        const float w = OctoWindowed(&channels[k], v);
#if OCTO_MODE == OCTO_MODE_DVR
        /* Per-sample intermixing: premultiplied colours add, alphas combine. */
        const float4 rgba = OctoTransfer(&channels[k], lut, w);
        if (rgba.w != 0.0f) transparent = false;
        const float a = OctoCorrectOpacity(rgba.w, ratio);
        mix_rgb += rgba.xyz * a;
        transmit *= 1.0f - a;
#elif OCTO_MODE == OCTO_MODE_MIP
        extreme[k] = fmax(extreme[k], w);
#else
        extreme[k] = fmin(extreme[k], w);
#endif
      }
      uint next = i + 1u;
#if OCTO_MODE == OCTO_MODE_DVR
      const float mix_a = 1.0f - transmit;
      /* Colours never beyond the mixed opacity (render_params.h). */
      acc.xyz += (1.0f - acc.w) * fmin(mix_rgb, (float3)(mix_a));
      acc.w += (1.0f - acc.w) * mix_a;
      if (acc.w >= 0.999f) {
        i = segments; /* Early termination. */
        break;
      }
      const bool skippable = transparent;
#else
      /* Later samples of a brickless leaf repeat this value: they cannot change an extremum. */
      const bool skippable = true;
#endif
      /* Empty space: a brickless leaf gives the same value everywhere in its box, so jump to the
       * first midpoint beyond the box (as long as the level cannot grow past the leaf's). */
      if (skippable && f.skip_empty && f.all_identity && !OctoNodeHasBrick(shared_hit.word0) &&
          OctoNodeChildGroup(shared_hit.word0) == 0u && shared_hit.node == shared_hit.wanted) {
        const float3 size = convert_float3(OctoBrickSize(g)) * ldexp(1.0f, shared_hit.level);
        const float3 lo = convert_float3(shared_hit.index.xyz) * size;
        const float3 hi = lo + size;
        float arc_exit = INFINITY;
        if (u.x != 0.0f) arc_exit = fmin(arc_exit, ((u.x > 0.0f ? hi.x : lo.x) - entry.x) / u.x);
        if (u.y != 0.0f) arc_exit = fmin(arc_exit, ((u.y > 0.0f ? hi.y : lo.y) - entry.y) / u.y);
        if (u.z != 0.0f) arc_exit = fmin(arc_exit, ((u.z > 0.0f ? hi.z : lo.z) - entry.z) / u.z);
        arc_exit = fmin(arc_exit, len);
        const int exit_level =
            perspective ? OctoLevelOf(f.lod_scale * (t0 + arc_exit / vpu) * cos_forward, g) : level;
        if (exit_level <= shared_hit.level) {
          /* A margin for rounding: a midpoint near the face is sampled rather than skipped. */
          const float margin =
              1e-3f + 1e-5f * (arc_exit + fmax(fabs(entry.x), fmax(fabs(entry.y), fabs(entry.z))));
          const float target = ceil((arc_exit - margin) / f.step - 0.5f);
          if (target > (float)next) next = target >= (float)segments ? segments : (uint)target;
        }
      }
      i = next;
    }
  }
  OctoAddSamples(counters, samples);
#if OCTO_REFINE
  if (paused) {
    ray_next[pixel] = i;
#if OCTO_MODE == OCTO_MODE_DVR
    ray_acc[pixel] = acc;
#else
    for (int k = 0; k < f.active_channels; ++k) {
      ray_extreme[(size_t)pixel * (size_t)f.active_channels + (size_t)k] = extreme[k];
    }
#endif
  } else {
    ray_next[pixel] = OCTO_RAY_DONE;
    atomic_inc(&counters[OCTO_COUNTER_FINISHED]);
  }
#else
  (void)paused;
  atomic_inc(&counters[OCTO_COUNTER_FINISHED]);
#endif
  image[pixel] = OctoFinishPixel(f, channels, lut, acc, extreme);
}
