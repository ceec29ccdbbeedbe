/* What every ray caster of a frame shares (kernels/raycast.cl, the renderer; kernels/
 * dense_baseline.cl, its benchmark baseline): the pixel's ray and its clipping, the transfer
 * function, opacity correction, channel transforms, the sample counter and the final pixel, each
 * exactly as render_params.h / camera.h define them (docs/rendering.md), in float.
 *
 * Compile-time configuration (-D): OCTO_MODE (OCTO_MODE_DVR / _MIP / _MINIP), OCTO_RUN_LANES
 * (4 or 8: the widest N-sample step of the ray casters, render::RunLanes for the device).
 */
#ifndef OCTOSCOPE_KERNELS_RAY_COMMON_CL_
#define OCTOSCOPE_KERNELS_RAY_COMMON_CL_

#include "render_format.h"

#ifndef OCTO_MODE
#define OCTO_MODE OCTO_MODE_DVR
#endif
#ifndef OCTO_RUN_LANES
#define OCTO_RUN_LANES 4
#endif

/* Float rounding of the interval (a few ulps of the t values) must not grow or drop a sliver
 * segment where the reference (double, 1e-9) would not: lengths within this many ulps of |t| of
 * a step multiple count as that multiple. */
#define OCTO_SLIVER_ULPS 4.0f

/* A pixel's ray in voxel space with the physical parameter t, clipped to [t0, t1]. */
typedef struct OctoRay {
  float3 o;
  float3 d;
  float t0;
  float t1;
  float cos_forward; /* Cosine between the ray and forward (perspective distance). */
  bool empty;        /* Misses the box or the planes, or no channel is enabled. */
} OctoRay;

/* The ray of pixel (px, py) (Camera::PixelRay), clipped to the box [0, n] (faces inclusive) and
 * the planes exactly like ClipRayToVolume. */
__attribute__((always_inline)) OctoRay OctoPixelRay(OctoRenderFrame f, int px, int py) {
  const float3 forward = (float3)(f.forward[0], f.forward[1], f.forward[2]);
  const float3 right = (float3)(f.right[0], f.right[1], f.right[2]);
  const float3 up = (float3)(f.up[0], f.up[1], f.up[2]);
  const float dx = ((float)px + 0.5f - 0.5f * (float)f.width) * f.pixel_scale;
  const float dy = (0.5f * (float)f.height - ((float)py + 0.5f)) * f.pixel_scale;
  float3 o = (float3)(f.origin[0], f.origin[1], f.origin[2]);
  float3 d;
  float cos_forward = 1.0f;
  if (f.projection == OCTO_PROJECTION_ORTHO) {
    o += right * dx + up * dy;
    d = forward;
  } else {
    /* |forward + right dx + up dy| = sqrt(1 + dx^2 + dy^2) for the orthonormal physical frame. */
    cos_forward = rsqrt(1.0f + dx * dx + dy * dy);
    d = (forward + right * dx + up * dy) * cos_forward;
  }

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
  OctoRay r;
  r.o = o;
  r.d = d;
  r.t0 = t0;
  r.t1 = t1;
  r.cos_forward = cos_forward;
  r.empty = !hit_box || !(t1 > t0) || !isfinite(t1) || f.active_channels == 0;
  return r;
}

/* Four windowed values (in [0, 1]) raised to `gamma` > 0, lane by lane. The one implementation
 * of the gamma: the scalar path (OctoWindowed) takes lane 0 of the same call, so a sample's value
 * does not depend on whether a single step or an N-sample step takes it (a vector builtin may
 * round differently from the scalar one), and the four lanes go through one vector call instead
 * of four scalar ones. exp2(gamma log2 t) rather than pow: t in [0, 1] needs none of pow's other
 * special cases, and on PoCL it is 1.5x faster in a DVR frame, with the same error against the
 * double-precision reference. */
float4 OctoGamma4(float4 t, float gamma) {
  /* 0 and 1 kept as they are: gamma may round to 0 or infinity in float, where 0 * log2(0) and
   * infinity * log2(1) are NaN (pow gives t there). */
  return select(exp2(gamma * log2(t)), t, (t == 0.0f) | (t == 1.0f));
}

/* WindowedValue of render_params.h: window, clamp to [0, 1], gamma. */
float OctoWindowed(__global const OctoChannelParams* ch, float v) {
  float t = clamp((v - ch->window_lo) * ch->inv_window, 0.0f, 1.0f);
  if (ch->gamma != 1.0f) t = OctoGamma4((float4)(t), ch->gamma).s0;
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

/* A segment's opacity-correction ratio (its length over the reference spacing), prepared once
 * per sample for all its channels: `squarings` = s >= 0 when the ratio is 2^s (within 8 ulps:
 * full segments of level s at the reference step), else -1. */
typedef struct OctoRatio {
  float ratio;
  int squarings;
} OctoRatio;

OctoRatio OctoOpacityRatio(float ratio) {
  OctoRatio r;
  r.ratio = ratio;
  r.squarings = -1;
  int e = 0;
  const float m = frexp(ratio, &e); /* ratio = m * 2^e, m in [0.5, 1). */
  const float tolerance = 4.0f * FLT_EPSILON;
  if (m - 0.5f <= tolerance) {
    r.squarings = e - 1;
  } else if (1.0f - m <= tolerance) {
    r.squarings = e; /* Just below 2^e. */
  }
  if (r.squarings > 24) r.squarings = -1;
  return r;
}

/* CorrectOpacity of render_params.h for four alphas in [0, 1]: 1 - (1 - a)^ratio; 0 and 1 stay
 * exact. A ratio of 2^s is s squarings of the transparency, written b <- 1 - (1 - b)^2 = b (2 - b)
 * so tiny alphas keep their precision: a few multiplies. Any other ratio (samples not 2^s
 * reference spacings apart: anisotropic voxels seen obliquely, a step such as 1.5) takes
 * 1 - exp2(ratio * log2(1 - a)) as vector calls: cheaper than log1p/expm1 (the DVR inner loop's
 * dearest part; exp2/log2 are hardware on GPUs) and off by a few ulps of 1 times max(ratio, 1)
 * (the rounding of 1 - a, carried through the power): per reference spacing, what compositing's
 * own 1 - a loses (OpacityCorrectionMatchesTheDoubleFormula; no image moved against the
 * reference, even at the finest step: docs/benchmarks.md). The one implementation: the scalar
 * path (OctoCorrectOpacity) takes lane 0 of the same call, as OctoGamma4. */
/* The general case lane by lane (T: the vector type of `a`; `ratio` a float or a T), 0 and 1
 * kept exact. fmax: exp2 may round a little above 1 (3 ulps allowed), never a negative alpha.
 * Also the dense baseline's eight-lane correction (OctoCorrectOpacity8). */
#define OCTO_CORRECT_GENERAL(T, a, ratio)                                                          \
  select(select(fmax(1.0f - exp2((ratio) * log2(1.0f - (a))), 0.0f), (T)(1.0f), (a) >= 1.0f),      \
         (T)(0.0f), (a) <= 0.0f)
float4 OctoCorrectOpacity4(float4 a, OctoRatio r) {
  if (r.squarings >= 0) {
    for (int s = 0; s < r.squarings; ++s) a *= 2.0f - a;
    return a;
  }
  /* Transparent (and opaque) samples need no correction: without skipping most samples are. */
  if (!any((a > 0.0f) & (a < 1.0f))) return a;
  return OCTO_CORRECT_GENERAL(float4, a, r.ratio);
}

/* The same for one alpha (any value: clamped into [0, 1] first). GPU compilers split vectors into
 * scalars, so there the unused lanes of this call (and of OctoWindowed's) are dead code. */
float OctoCorrectOpacity(float a, OctoRatio r) {
  return OctoCorrectOpacity4((float4)(clamp(a, 0.0f, 1.0f)), r).s0;
}

/* How far a channel's transformed position may leave the volume box by the rounding of
 * transform * p, per axis: 8 ulps of the sum of its terms' bounds over the box (p in the box).
 * Anything further gives no sample; a wider tolerance would take samples the reference (1e-9 of
 * the box in double) leaves out. Rounding already in p (its entry point is computed from the
 * camera) is not covered: there a decision can differ from the reference's by about an ulp of
 * the camera's distance, on both paths alike. */
float3 OctoChannelTolerance(__global const float* m, float3 box) {
  const float3 span = (float3)(fabs(m[0]) * box.x + fabs(m[1]) * box.y + fabs(m[2]) * box.z,
                               fabs(m[4]) * box.x + fabs(m[5]) * box.y + fabs(m[6]) * box.z,
                               fabs(m[8]) * box.x + fabs(m[9]) * box.y + fabs(m[10]) * box.z) +
                      fabs((float3)(m[3], m[7], m[11]));
  return 8.0f * FLT_EPSILON * span;
}

/* A channel transform (row-major 3 x 4, render_format.h) applied to a point: m * (p, 1); and to
 * a direction: its linear part only. */
float3 OctoTransformPoint(const __global float* m, float3 p) {
  return (float3)(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                  m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                  m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
}
float3 OctoTransformDirection(const __global float* m, float3 v) {
  return (float3)(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
                  m[8] * v.x + m[9] * v.y + m[10] * v.z);
}

/* The position of a channel's sample: transform * p; false when it leaves the volume box. */
bool OctoChannelPosition(__global const OctoChannelParams* ch, float3 p, OctoRenderFrame f,
                         float3* q) {
  if (ch->identity) {
    *q = p;
    return true;
  }
  const __global float* m = ch->transform;
  const float3 r = OctoTransformPoint(m, p);
  const float3 box = (float3)(f.volume[0], f.volume[1], f.volume[2]);
  const float3 tolerance = OctoChannelTolerance(m, box);
  if (!(all(r >= -tolerance) && all(r <= box + tolerance))) return false;
  *q = r;
  return true;
}

/* N positions at once (N = 4, 8; lane by lane OctoChannelPosition's, the same expressions):
 * the transformed positions in *rx, *ry, *rz; false when any lane leaves the volume box. */
#define OCTO_DEFINE_CHANNEL_POSITIONS_N(N)                                                         \
  __attribute__((always_inline)) bool OctoChannelPositions##N(                                     \
      __global const OctoChannelParams* ch, float##N px, float##N py, float##N pz,                 \
      OctoRenderFrame f, float##N* rx, float##N* ry, float##N* rz) {                               \
    if (ch->identity) {                                                                            \
      *rx = px;                                                                                    \
      *ry = py;                                                                                    \
      *rz = pz;                                                                                    \
      return true;                                                                                 \
    }                                                                                              \
    const __global float* m = ch->transform;                                                       \
    *rx = m[0] * px + m[1] * py + m[2] * pz + m[3];                                                \
    *ry = m[4] * px + m[5] * py + m[6] * pz + m[7];                                                \
    *rz = m[8] * px + m[9] * py + m[10] * pz + m[11];                                              \
    const float3 box = (float3)(f.volume[0], f.volume[1], f.volume[2]);                            \
    const float3 tolerance = OctoChannelTolerance(m, box);                                         \
    return all((*rx >= -tolerance.x) & (*ry >= -tolerance.y) & (*rz >= -tolerance.z) &             \
               (*rx <= box.x + tolerance.x) & (*ry <= box.y + tolerance.y) &                       \
               (*rz <= box.z + tolerance.z));                                                      \
  }
OCTO_DEFINE_CHANNEL_POSITIONS_N(4)
#if OCTO_RUN_LANES >= 8
OCTO_DEFINE_CHANNEL_POSITIONS_N(8)
#endif

/* DVR: channel value v (stored) of a sample mixed into the sample's premultiplied colour sum and
 * transparency product (per-sample intermixing), its opacity corrected by `ratio`
 * (OctoOpacityRatio of the segment length over the reference spacing). Returns the channel's
 * uncorrected alpha. */
float OctoMixChannel(__global const OctoChannelParams* ch, __global const float4* lut, float v,
                     OctoRatio ratio, float3* mix_rgb, float* transmit) {
  const float4 rgba = OctoTransfer(ch, lut, OctoWindowed(ch, v));
  const float a = OctoCorrectOpacity(rgba.w, ratio);
  *mix_rgb += rgba.xyz * a;
  *transmit *= 1.0f - a;
  return rgba.w;
}

/* Quarter q (lanes 4q .. 4q + 3) of an N-lane vector, and the largest (smallest) lane: exact,
 * so any order of fmax (fmin) gives the sequential result. */
float4 OctoQuarter4(float4 v, uint q) {
  (void)q;
  return v;
}
float4 OctoQuarter8(float8 v, uint q) { return q == 0u ? v.lo : v.hi; }
float OctoMax4(float4 v) { return fmax(fmax(v.s0, v.s1), fmax(v.s2, v.s3)); }
float OctoMax8(float8 v) { return OctoMax4(fmax(v.lo, v.hi)); }
float OctoMin4(float4 v) { return fmin(fmin(v.s0, v.s1), fmin(v.s2, v.s3)); }
float OctoMin8(float8 v) { return OctoMin4(fmin(v.lo, v.hi)); }

/* Four samples' transfer function and opacity correction for one channel, lane by lane the
 * values OctoMixChannel mixes: straight colour in *r, *g, *b, the corrected alpha returned. The
 * plain colour ramp, the gamma and the opacity correction are vector operations (the same
 * operations per lane as the scalar path's: OctoGamma4, OctoCorrectOpacity4); LUTs go lane by
 * lane through OctoTransfer. */
float4 OctoShade4(__global const OctoChannelParams* ch, __global const float4* lut, float4 v,
                  OctoRatio ratio, float4* r, float4* g, float4* b) {
  float4 t = clamp((v - ch->window_lo) * ch->inv_window, 0.0f, 1.0f);
  if (ch->gamma != 1.0f) t = OctoGamma4(t, ch->gamma);
  float4 a;
  if (ch->lut >= 0) {
    const float4 c0 = OctoTransfer(ch, lut, t.s0);
    const float4 c1 = OctoTransfer(ch, lut, t.s1);
    const float4 c2 = OctoTransfer(ch, lut, t.s2);
    const float4 c3 = OctoTransfer(ch, lut, t.s3);
    *r = (float4)(c0.x, c1.x, c2.x, c3.x);
    *g = (float4)(c0.y, c1.y, c2.y, c3.y);
    *b = (float4)(c0.z, c1.z, c2.z, c3.z);
    a = (float4)(c0.w, c1.w, c2.w, c3.w);
  } else {
    t = clamp(t, 0.0f, 1.0f);
    *r = ch->color[0] * t;
    *g = ch->color[1] * t;
    *b = ch->color[2] * t;
    a = clamp(t * ch->opacity_scale, 0.0f, 1.0f);
  }
  return OctoCorrectOpacity4(a, ratio); /* a is in [0, 1]. */
}

/* DVR: the sample's mixed channels (premultiplied colour sum, product of transparencies)
 * composited under `acc`; colours never beyond the mixed opacity (render_params.h). */
float4 OctoCompositeUnder(float4 acc, float3 mix_rgb, float transmit) {
  const float mix_a = 1.0f - transmit;
  acc.xyz += (1.0f - acc.w) * fmin(mix_rgb, (float3)(mix_a));
  acc.w += (1.0f - acc.w) * mix_a;
  return acc;
}

/* DVR: four samples of `active` channels (v[k]: channel k's values) shaded (OctoShade4) and
 * mixed per sample as vectors over the four lanes (OctoMixChannel's operations lane by lane),
 * then composited under *acc in sample order, stopping at early termination (then acc->w >=
 * 0.999). Returns the samples composited; adds their channel samples to *samples. */
__attribute__((always_inline)) uint OctoCompositeFour(__global const OctoChannelParams* channels,
                                                      __global const float4* lut, const float4* v,
                                                      int active, OctoRatio ratio, float4* acc,
                                                      uint* samples) {
  float4 mix_r = (float4)(0.0f);
  float4 mix_g = (float4)(0.0f);
  float4 mix_b = (float4)(0.0f);
  float4 transmit = (float4)(1.0f);
  for (int k = 0; k < active; ++k) {
    float4 r;
    float4 g;
    float4 b;
    const float4 a = OctoShade4(&channels[k], lut, v[k], ratio, &r, &g, &b);
    mix_r += r * a;
    mix_g += g * a;
    mix_b += b * a;
    transmit *= 1.0f - a;
  }
  /* The lanes one after another: each composites under the previous ones. */
#define OCTO_COMPOSITE_LANE(L, S)                                                                  \
  *samples += (uint)active;                                                                        \
  *acc = OctoCompositeUnder(*acc, (float3)(mix_r.S, mix_g.S, mix_b.S), transmit.S);                \
  if (acc->w >= 0.999f) return L + 1u;
  OCTO_COMPOSITE_LANE(0u, s0)
  OCTO_COMPOSITE_LANE(1u, s1)
  OCTO_COMPOSITE_LANE(2u, s2)
  OCTO_COMPOSITE_LANE(3u, s3)
#undef OCTO_COMPOSITE_LANE
  return 4u;
}

/* The ray state after N samples (N = 4, 8) of ACTIVE channels (at most STATE), v[k] channel k's
 * N values in sample order: DVR composites them four lanes at a time (OctoCompositeFour) up to
 * early termination, then returns true with *taken the samples used; MIP (MinIP) takes the
 * largest (smallest) lane. A statement for both ray casters' N-sample step functions, whose
 * parameters it names (channels, lut, ratio, acc, extreme, samples, taken); *taken is N unless
 * the ray terminated. A macro, not a function: as an inlined function PoCL compiled both
 * kernels' level-0 loops 5 % slower. */
#if OCTO_MODE == OCTO_MODE_DVR
#define OCTO_TAKE_SAMPLES(N, ACTIVE, STATE)                                                        \
  *taken = N;                                                                                      \
  for (uint q = 0u; q < (uint)(N) / 4u; ++q) {                                                     \
    float4 quarter[STATE];                                                                         \
    for (int k = 0; k < (ACTIVE); ++k) quarter[k] = OctoQuarter##N(v[k], q);                       \
    const uint done = OctoCompositeFour(channels, lut, quarter, (ACTIVE), ratio, acc, samples);    \
    if (acc->w >= 0.999f) {                                                                        \
      *taken = 4u * q + done;                                                                      \
      return true;                                                                                 \
    }                                                                                              \
  }
#elif OCTO_MODE == OCTO_MODE_MIP
#define OCTO_TAKE_SAMPLES(N, ACTIVE, STATE)                                                        \
  *taken = N;                                                                                      \
  for (int k = 0; k < (ACTIVE); ++k) extreme[k] = fmax(extreme[k], OctoMax##N(v[k]));             \
  *samples += (uint)(N) * (uint)(ACTIVE);
#else
#define OCTO_TAKE_SAMPLES(N, ACTIVE, STATE)                                                        \
  *taken = N;                                                                                      \
  for (int k = 0; k < (ACTIVE); ++k) extreme[k] = fmin(extreme[k], OctoMin##N(v[k]));             \
  *samples += (uint)(N) * (uint)(ACTIVE);
#endif

/* Adds n to the 64-bit counter held as the two uint words lo, lo + 1 (carry on wrap-around). */
void OctoAddCount64(volatile __global uint* counters, int lo, uint n) {
  if (n == 0u) return;
  const uint old = atomic_add(&counters[lo], n);
  if (old + n < old) atomic_inc(&counters[lo + 1]);
}

/* Adds n to the 64-bit sample counter. */
void OctoAddSamples(volatile __global uint* counters, uint n) {
  OctoAddCount64(counters, OCTO_COUNTER_SAMPLES_LO, n);
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
    if (!(e >= 0.0f && e <= 65535.0f)) continue; /* Never sampled. */
    any = true;
    out.xyz += OctoTransfer(&channels[k], lut, OctoWindowed(&channels[k], e)).xyz;
  }
  if (any) out.w = 1.0f;
#endif
  return clamp(out, 0.0f, 1.0f);
}

#endif /* OCTOSCOPE_KERNELS_RAY_COMMON_CL_ */
