/* The benchmark baseline of the ray caster (bench/baseline/dense_kernel.h; docs/benchmarks.md,
 * "Rendering"): the plainest OpenCL kernel doing the renderer's level-0 work. The whole volume is
 * ONE plain array in device memory (x fastest, channels interleaved per voxel as in the bricks);
 * no octree, no paging, no level of detail, no empty-space skipping.
 *
 * DenseRayCast, per pixel (one work item; the host launches 8x8 work groups; DensePacketRayCast
 * below casts eight rays per work item on CPUs): the renderer's ray and clipping
 * (OctoPixelRay), segments of f.step voxels from the entry with midpoints entry + (i + 0.5) dt
 * (never accumulated; the last one shortened to the exit, a float sliver none), per enabled
 * channel its transformed position (outside the box: no sample), clamped to the voxel centres
 * [0.5, n - 0.5] (clamp to edge), a trilinear read of 8 voxels, then the renderer's transfer
 * function and compositing (DVR with early termination; MIP/MinIP over stored values).
 * Its images equal the renderer's at level 0 (tests/bench/dense_kernel_test.cpp).
 *
 * Compile-time configuration (-D): OCTO_MODE (OCTO_MODE_DVR / _MIP / _MINIP) and
 * OCTO_DENSE_ACTIVE, the number of enabled channels (at least 1; the host passes
 * max(1, f.active_channels)), so the channel loops and the ray state have a fixed size, as a
 * hand-written kernel for one dataset would.
 */
#include "ray_common.cl"
#include "render_format.h"

#ifndef OCTO_DENSE_ACTIVE
#define OCTO_DENSE_ACTIVE 1
#endif

/* The 2x2x2 voxels around p (level-0 voxel coordinates, voxel v covers [v, v + 1)), clamped to
 * the edge voxels: first voxel's offset, offsets to the second voxel per axis (0 at the last
 * voxel; in ushort units, channels interleaved), and the fractions. */
typedef struct OctoDenseFootprint {
  ulong o;
  uint dx;
  uint dy;
  uint dz;
  float3 f;
} OctoDenseFootprint;

OctoDenseFootprint OctoDenseFootprintAt(float3 p, int3 n, uint channels) {
  /* Voxel centres at integers: [0, n - 1] after the clamp. */
  const float3 c = clamp(p, 0.5f, convert_float3(n) - 0.5f) - 0.5f;
  const float3 lo = floor(c);
  const int3 i0 = convert_int3(lo);
  OctoDenseFootprint fp;
  fp.f = c - lo;
  const uint sx = (uint)n.x * channels;
  const ulong sy = (ulong)sx * (ulong)n.y;
  fp.dx = i0.x < n.x - 1 ? channels : 0u;
  fp.dy = i0.y < n.y - 1 ? sx : 0u;
  fp.dz = i0.z < n.z - 1 ? (uint)sy : 0u;
  fp.o = (ulong)i0.z * sy + (ulong)i0.y * sx + (ulong)i0.x * channels;
  return fp;
}

/* Channel c trilinearly from the footprint: 8 loads. */
float OctoDenseRead(__global const ushort* volume, OctoDenseFootprint fp, int c) {
  __global const ushort* p = volume + fp.o + (ulong)c;
  const float v000 = (float)p[0];
  const float v100 = (float)p[fp.dx];
  const float v010 = (float)p[fp.dy];
  const float v110 = (float)p[fp.dy + fp.dx];
  const float v001 = (float)p[fp.dz];
  const float v101 = (float)p[fp.dz + fp.dx];
  const float v011 = (float)p[fp.dz + fp.dy];
  const float v111 = (float)p[fp.dz + fp.dy + fp.dx];
  const float v00 = mix(v000, v100, fp.f.x);
  const float v10 = mix(v010, v110, fp.f.x);
  const float v01 = mix(v001, v101, fp.f.x);
  const float v11 = mix(v011, v111, fp.f.x);
  return mix(mix(v00, v10, fp.f.y), mix(v01, v11, fp.f.y), fp.f.z);
}

/* N footprints at once (lane by lane OctoDenseFootprintAt's), channel c of their reads, and N full
 * segments into the ray state (N = 4, 8; OCTO_TAKE_SAMPLES, as the renderer): a hand-written kernel
 * would vectorise along the ray as the renderer does, as wide as the renderer's runs. Forced
 * inline, as the renderer's N-sample helpers (octree_sampling.cl). OpenCL C has no templates:
 * OCTO_DEFINE_DENSE_N writes the family once per width. */
#define OCTO_DENSE_GATHER_4(volume, o, d)                                                          \
  (float4)((float)(volume)[(o).s0 + (d).s0], (float)(volume)[(o).s1 + (d).s1],                     \
           (float)(volume)[(o).s2 + (d).s2], (float)(volume)[(o).s3 + (d).s3])
#define OCTO_DENSE_GATHER_8(volume, o, d)                                                          \
  (float8)(OCTO_DENSE_GATHER_4(volume, (o).lo, (d).lo),                                            \
           OCTO_DENSE_GATHER_4(volume, (o).hi, (d).hi))
#define OCTO_DEFINE_DENSE_N(N)                                                                     \
  typedef struct OctoDenseFootprint##N {                                                           \
    ulong##N o;                                                                                    \
    uint##N dx;                                                                                    \
    uint##N dy;                                                                                    \
    uint##N dz;                                                                                    \
    float##N fx;                                                                                   \
    float##N fy;                                                                                   \
    float##N fz;                                                                                   \
  } OctoDenseFootprint##N;                                                                         \
  __attribute__((always_inline)) OctoDenseFootprint##N OctoDenseFootprintAt##N(                    \
      float##N px, float##N py, float##N pz, int3 n, uint channels) {                              \
    const float##N cx = clamp(px, 0.5f, (float)n.x - 0.5f) - 0.5f;                                 \
    const float##N cy = clamp(py, 0.5f, (float)n.y - 0.5f) - 0.5f;                                 \
    const float##N cz = clamp(pz, 0.5f, (float)n.z - 0.5f) - 0.5f;                                 \
    const float##N lx = floor(cx);                                                                 \
    const float##N ly = floor(cy);                                                                 \
    const float##N lz = floor(cz);                                                                 \
    const int##N ix = convert_int##N(lx);                                                          \
    const int##N iy = convert_int##N(ly);                                                          \
    const int##N iz = convert_int##N(lz);                                                          \
    OctoDenseFootprint##N fp;                                                                      \
    fp.fx = cx - lx;                                                                               \
    fp.fy = cy - ly;                                                                               \
    fp.fz = cz - lz;                                                                               \
    const uint sx = (uint)n.x * channels;                                                          \
    const ulong sy = (ulong)sx * (ulong)n.y;                                                       \
    fp.dx = select((uint##N)(0u), (uint##N)(channels), ix < n.x - 1);                              \
    fp.dy = select((uint##N)(0u), (uint##N)(sx), iy < n.y - 1);                                    \
    fp.dz = select((uint##N)(0u), (uint##N)((uint)sy), iz < n.z - 1);                              \
    fp.o = convert_ulong##N(iz) * sy + convert_ulong##N(iy) * (ulong)sx +                          \
           convert_ulong##N(ix) * (ulong)channels;                                                 \
    return fp;                                                                                     \
  }                                                                                                \
  __attribute__((always_inline)) float##N OctoDenseRead##N(__global const ushort* volume,          \
                                                           OctoDenseFootprint##N fp, int c) {      \
    const ulong##N o = fp.o + (ulong)c;                                                            \
    const uint##N zero = (uint##N)(0u);                                                            \
    const float##N v000 = OCTO_DENSE_GATHER_##N(volume, o, zero);                                  \
    const float##N v100 = OCTO_DENSE_GATHER_##N(volume, o, fp.dx);                                 \
    const float##N v010 = OCTO_DENSE_GATHER_##N(volume, o, fp.dy);                                 \
    const float##N v110 = OCTO_DENSE_GATHER_##N(volume, o, fp.dy + fp.dx);                         \
    const float##N v001 = OCTO_DENSE_GATHER_##N(volume, o, fp.dz);                                 \
    const float##N v101 = OCTO_DENSE_GATHER_##N(volume, o, fp.dz + fp.dx);                         \
    const float##N v011 = OCTO_DENSE_GATHER_##N(volume, o, fp.dz + fp.dy);                         \
    const float##N v111 = OCTO_DENSE_GATHER_##N(volume, o, fp.dz + fp.dy + fp.dx);                 \
    const float##N v00 = mix(v000, v100, fp.fx);                                                   \
    const float##N v10 = mix(v010, v110, fp.fx);                                                   \
    const float##N v01 = mix(v001, v101, fp.fx);                                                   \
    const float##N v11 = mix(v011, v111, fp.fx);                                                   \
    return mix(mix(v00, v10, fp.fy), mix(v01, v11, fp.fy), fp.fz);                                 \
  }                                                                                                \
  /* Full segments j .. j + N - 1 (arc: their midpoints' arcs) into the ray state; true when       \
   * the ray terminates (DVR). */                                                                  \
  __attribute__((always_inline)) bool OctoDenseStep##N(                                            \
      __global const ushort* volume, uint channels_stored, int3 n,                                 \
      __global const OctoChannelParams* channels, __global const float4* lut,                      \
      float3 entry, float3 u, float##N arc, OctoRatio ratio, float4* acc, float* extreme,          \
      uint* samples) {                                                                             \
    (void)lut;                                                                                     \
    (void)ratio;                                                                                   \
    (void)acc;                                                                                     \
    (void)extreme;                                                                                 \
    const OctoDenseFootprint##N fp = OctoDenseFootprintAt##N(                                      \
        entry.x + u.x * arc, entry.y + u.y * arc, entry.z + u.z * arc, n, channels_stored);        \
    float##N v[OCTO_DENSE_ACTIVE];                                                                 \
    for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) {                                                  \
      v[k] = OctoDenseRead##N(volume, fp, channels[k].channel);                                    \
    }                                                                                              \
    uint taken_lanes;                                                                              \
    uint* taken = &taken_lanes;                                                                    \
    OCTO_TAKE_SAMPLES(N, OCTO_DENSE_ACTIVE, OCTO_DENSE_ACTIVE)                                     \
    return false;                                                                                  \
  }
OCTO_DEFINE_DENSE_N(4)
#if OCTO_RUN_LANES >= 8
OCTO_DEFINE_DENSE_N(8)
#endif

/* One segment of a ray, one at a time (DenseRayCast's loop after its N-wide steps, and each
 * packet lane's last segment): every enabled channel at the midpoint p (a transformed channel at
 * its own position; outside the box: no sample) read and mixed into the ray state with the
 * segment's opacity ratio. Returns true when the ray terminates (DVR). */
bool OctoDenseSegment(__global const ushort* volume, uint channels_stored, int3 n,
                      OctoRenderFrame f, __global const OctoChannelParams* channels,
                      __global const float4* lut, float3 p, OctoRatio ratio, float4* acc,
                      float* extreme, uint* samples) {
  (void)lut;
  (void)ratio;
  (void)acc;
  /* Channels without a transform share one footprint. */
  const OctoDenseFootprint shared = OctoDenseFootprintAt(p, n, channels_stored);
#if OCTO_MODE == OCTO_MODE_DVR
  float3 mix_rgb = (float3)(0.0f);
  float transmit = 1.0f;
#endif
  for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) {
    OctoDenseFootprint fp = shared;
    if (!channels[k].identity) {
      float3 q;
      if (!OctoChannelPosition(&channels[k], p, f, &q)) continue;
      fp = OctoDenseFootprintAt(q, n, channels_stored);
    }
    const float v = OctoDenseRead(volume, fp, channels[k].channel);
    ++*samples;
#if OCTO_MODE == OCTO_MODE_DVR
    OctoMixChannel(&channels[k], lut, v, ratio, &mix_rgb, &transmit);
#elif OCTO_MODE == OCTO_MODE_MIP
    extreme[k] = fmax(extreme[k], v);
#else
    extreme[k] = fmin(extreme[k], v);
#endif
  }
#if OCTO_MODE == OCTO_MODE_DVR
  *acc = OctoCompositeUnder(*acc, mix_rgb, transmit);
  return acc->w >= 0.999f; /* Early termination, as the renderer. */
#else
  return false;
#endif
}

/* volume: n.x * n.y * n.z * channels samples (f.volume = n); channels: one entry per enabled
 * channel; image: width * height float4; counters: OCTO_COUNTER_WORDS (finished rays, samples). */
__kernel void DenseRayCast(__global const ushort* volume, uint channels_stored, OctoRenderFrame f,
                           __global const OctoChannelParams* channels, __global const float4* lut,
                           __global float4* image, volatile __global uint* counters) {
  const int px = (int)get_global_id(0);
  const int py = (int)get_global_id(1);
  if (px >= f.width || py >= f.height) return;
  const OctoRay ray = OctoPixelRay(f, px, py);
  const int3 n = convert_int3((float3)(f.volume[0], f.volume[1], f.volume[2]));

  float4 acc = (float4)(0.0f);
  float extreme[OCTO_DENSE_ACTIVE];
  for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) {
    /* "Not sampled": outside [0, 65535]; any stored value replaces it. */
    extreme[k] = OCTO_MODE == OCTO_MODE_MIP ? -1.0f : INFINITY;
  }
  uint samples = 0u;
  if (!ray.empty) {
    /* Arc length in voxel space: |d| voxels per µm. */
    const float vpu = length(ray.d);
    const float3 u = ray.d / vpu;
    const float3 entry = ray.o + ray.d * ray.t0;
    const float len = (ray.t1 - ray.t0) * vpu;
    const float rounding = OCTO_SLIVER_ULPS * FLT_EPSILON * (fabs(ray.t0) + fabs(ray.t1)) * vpu;
    const float dt = f.step;
    const uint segments = (uint)fmax(1.0f, ceil((len - rounding) / dt));
    /* DVR's opacity correction of full segments (unused by MIP/MinIP). */
    const OctoRatio ratio_full = OctoOpacityRatio(dt / vpu * f.inv_reference);
    bool all_identity = true;
    for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) all_identity = all_identity && channels[k].identity;
    uint j = 0u;
    bool terminated = false;
    /* Full segments eight (where OCTO_RUN_LANES is 8), then four at a time when no channel has
     * a transform (the same expressions lane by lane as the loop below; lane indices j + l exact
     * in float), the ray state updated in sample order. */
#if OCTO_RUN_LANES >= 8
    for (; all_identity && !terminated && j + 8u < segments; j += 8u) {
      const float8 arc8 =
          ((float)j + (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f)) * dt + 0.5f * dt;
      terminated = OctoDenseStep8(volume, channels_stored, n, channels, lut, entry, u, arc8,
                                  ratio_full, &acc, extreme, &samples);
    }
#endif
    for (; all_identity && !terminated && j + 4u < segments; j += 4u) {
      const float4 arc4 = ((float)j + (float4)(0.0f, 1.0f, 2.0f, 3.0f)) * dt + 0.5f * dt;
      terminated = OctoDenseStep4(volume, channels_stored, n, channels, lut, entry, u, arc4,
                                  ratio_full, &acc, extreme, &samples);
    }
    for (; !terminated && j < segments; ++j) {
      const float start = (float)j * dt;
      const float seg = j + 1u < segments ? dt : len - start;
      const OctoRatio ratio =
          j + 1u < segments ? ratio_full : OctoOpacityRatio(seg / vpu * f.inv_reference);
      terminated = OctoDenseSegment(volume, channels_stored, n, f, channels, lut,
                                    entry + u * (start + 0.5f * seg), ratio, &acc, extreme,
                                    &samples);
    }
  }
  OctoAddSamples(counters, samples);
  atomic_inc(&counters[OCTO_COUNTER_FINISHED]);
  image[py * f.width + px] = OctoFinishPixel(f, channels, lut, acc, extreme);
}

#if OCTO_RUN_LANES >= 8
/* OctoCorrectOpacity4 of eight lanes, each with its own ratio (ratio: OctoRatio.ratio,
 * squarings: OctoRatio.squarings per lane): the same operations lane by lane. */
float8 OctoCorrectOpacity8(float8 a, float8 ratio, int8 squarings) {
  const int4 s4 = max(squarings.lo, squarings.hi);
  const int most = max(max(s4.x, s4.y), max(s4.z, s4.w));
  float8 squared = a;
  for (int s = 0; s < most; ++s) {
    squared = select(squared, squared * (2.0f - squared), squarings > s);
  }
  if (all(squarings >= 0)) return squared;
  return select(OCTO_CORRECT_GENERAL(float8, a, ratio), squared, squarings >= 0);
}

/* The same rays as DenseRayCast, eight per work item: a block of 4 x 2 pixels marched in
 * lockstep, segment by segment, each ray a lane of float8s. Along one ray DVR's compositing is a
 * chain of dependent steps; across rays it is vector work, so a hand-written CPU kernel would
 * vectorise there (measured: docs/benchmarks.md). The host takes it where OCTO_RUN_LANES is 8 and
 * no channel has a transform. Per lane the operations are DenseRayCast's: the full segments
 * (j < segments - 1) in the loop, lanes past their own end or terminated masked, then each lane's
 * last segment (shortened to the exit) as DenseRayCast's scalar loop takes it. The work item
 * (bx, by) covers pixels [4 bx, 4 bx + 4) x [2 by, 2 by + 2). */
__kernel void DensePacketRayCast(__global const ushort* volume, uint channels_stored,
                                 OctoRenderFrame f, __global const OctoChannelParams* channels,
                                 __global const float4* lut, __global float4* image,
                                 volatile __global uint* counters) {
  const int x0 = 4 * (int)get_global_id(0);
  const int y0 = 2 * (int)get_global_id(1);
  if (x0 >= f.width || y0 >= f.height) return;
  const int3 n = convert_int3((float3)(f.volume[0], f.volume[1], f.volume[2]));
  const float dt = f.step;

  /* Each lane's ray (a lane off the image or missing the box takes no segment). */
  float ex[8], ey[8], ez[8], ux[8], uy[8], uz[8], len[8], vpu[8], ratio[8];
  int squarings[8];
  int segments[8];
  int most = 0;
  for (int l = 0; l < 8; ++l) {
    const int px = x0 + (l & 3);
    const int py = y0 + (l >> 2);
    ex[l] = ey[l] = ez[l] = ux[l] = uy[l] = uz[l] = len[l] = 0.0f;
    vpu[l] = ratio[l] = 1.0f;
    squarings[l] = 0;
    segments[l] = 0;
    if (px >= f.width || py >= f.height) continue;
    const OctoRay ray = OctoPixelRay(f, px, py);
    if (ray.empty) continue;
    vpu[l] = length(ray.d);
    const float3 u = ray.d / vpu[l];
    const float3 entry = ray.o + ray.d * ray.t0;
    len[l] = (ray.t1 - ray.t0) * vpu[l];
    const float rounding =
        OCTO_SLIVER_ULPS * FLT_EPSILON * (fabs(ray.t0) + fabs(ray.t1)) * vpu[l];
    segments[l] = (int)fmax(1.0f, ceil((len[l] - rounding) / dt));
    const OctoRatio full = OctoOpacityRatio(dt / vpu[l] * f.inv_reference);
    ratio[l] = full.ratio;
    squarings[l] = full.squarings;
    ex[l] = entry.x;
    ey[l] = entry.y;
    ez[l] = entry.z;
    ux[l] = u.x;
    uy[l] = u.y;
    uz[l] = u.z;
    most = max(most, segments[l]);
  }
  const float8 entry_x = vload8(0, ex), entry_y = vload8(0, ey), entry_z = vload8(0, ez);
  const float8 u_x = vload8(0, ux), u_y = vload8(0, uy), u_z = vload8(0, uz);
  const int8 full_segments = vload8(0, segments) - 1;
#if OCTO_MODE == OCTO_MODE_DVR
  const float8 lane_ratio = vload8(0, ratio);
  const int8 lane_squarings = vload8(0, squarings);
#endif

  float8 acc_r = (float8)(0.0f), acc_g = (float8)(0.0f), acc_b = (float8)(0.0f);
  float8 acc_a = (float8)(0.0f);
  float8 ext[OCTO_DENSE_ACTIVE];
  for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) {
    ext[k] = (float8)(OCTO_MODE == OCTO_MODE_MIP ? -1.0f : INFINITY);
  }
  uint samples = 0u;
  OctoRatio unit; /* OctoShade4 shades only; the lanes' own ratios correct below. */
  unit.ratio = 1.0f;
  unit.squarings = 0;
  (void)unit;
  /* The full segments, all lanes at once. */
  for (int j = 0; j + 1 < most; ++j) {
    int8 active = full_segments > j;
#if OCTO_MODE == OCTO_MODE_DVR
    active &= acc_a < 0.999f;
#endif
    if (!any(active)) break;
    const float arc = (float)j * dt + 0.5f * dt;
    const OctoDenseFootprint8 fp = OctoDenseFootprintAt8(
        entry_x + u_x * arc, entry_y + u_y * arc, entry_z + u_z * arc, n, channels_stored);
    const uint lanes = (uint)(-(active.s0 + active.s1 + active.s2 + active.s3 + active.s4 +
                                active.s5 + active.s6 + active.s7));
    samples += lanes * (uint)OCTO_DENSE_ACTIVE;
#if OCTO_MODE == OCTO_MODE_DVR
    float8 mix_r = (float8)(0.0f), mix_g = (float8)(0.0f), mix_b = (float8)(0.0f);
    float8 transmit = (float8)(1.0f);
#endif
    for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) {
      const float8 v = OctoDenseRead8(volume, fp, channels[k].channel);
#if OCTO_MODE == OCTO_MODE_DVR
      /* OctoShade4's operations on both halves: transfer function, gamma, opacity. */
      float4 r0, g0, b0, r1, g1, b1;
      const float4 a0 = OctoShade4(&channels[k], lut, v.lo, unit, &r0, &g0, &b0);
      const float4 a1 = OctoShade4(&channels[k], lut, v.hi, unit, &r1, &g1, &b1);
      const float8 a = OctoCorrectOpacity8((float8)(a0, a1), lane_ratio, lane_squarings);
      mix_r += (float8)(r0, r1) * a;
      mix_g += (float8)(g0, g1) * a;
      mix_b += (float8)(b0, b1) * a;
      transmit *= 1.0f - a;
#elif OCTO_MODE == OCTO_MODE_MIP
      ext[k] = select(ext[k], fmax(ext[k], v), active);
#else
      ext[k] = select(ext[k], fmin(ext[k], v), active);
#endif
    }
#if OCTO_MODE == OCTO_MODE_DVR
    /* OctoCompositeUnder, lane by lane. */
    const float8 mix_a = 1.0f - transmit;
    const float8 behind = 1.0f - acc_a;
    acc_r = select(acc_r, acc_r + behind * fmin(mix_r, mix_a), active);
    acc_g = select(acc_g, acc_g + behind * fmin(mix_g, mix_a), active);
    acc_b = select(acc_b, acc_b + behind * fmin(mix_b, mix_a), active);
    acc_a = select(acc_a, acc_a + behind * mix_a, active);
#endif
  }

  /* Each lane's last segment, as DenseRayCast's scalar loop takes it, then its pixel. */
  float ar[8], ag[8], ab[8], aa[8];
  vstore8(acc_r, 0, ar);
  vstore8(acc_g, 0, ag);
  vstore8(acc_b, 0, ab);
  vstore8(acc_a, 0, aa);
  float extreme_lanes[OCTO_DENSE_ACTIVE][8];
  for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) vstore8(ext[k], 0, extreme_lanes[k]);
  uint finished = 0u;
  for (int l = 0; l < 8; ++l) {
    const int px = x0 + (l & 3);
    const int py = y0 + (l >> 2);
    if (px >= f.width || py >= f.height) continue;
    float4 acc = (float4)(ar[l], ag[l], ab[l], aa[l]);
    float extreme[OCTO_DENSE_ACTIVE];
    for (int k = 0; k < OCTO_DENSE_ACTIVE; ++k) extreme[k] = extreme_lanes[k][l];
#if OCTO_MODE == OCTO_MODE_DVR
    const bool open = acc.w < 0.999f; /* Not terminated in the loop. */
#else
    const bool open = true;
#endif
    if (segments[l] > 0 && open) {
      const float start = (float)(segments[l] - 1) * dt;
      const float seg = len[l] - start;
      const float3 entry = (float3)(ex[l], ey[l], ez[l]);
      const float3 u = (float3)(ux[l], uy[l], uz[l]);
      OctoDenseSegment(volume, channels_stored, n, f, channels, lut,
                       entry + u * (start + 0.5f * seg),
                       OctoOpacityRatio(seg / vpu[l] * f.inv_reference), &acc, extreme, &samples);
    }
    image[py * f.width + px] = OctoFinishPixel(f, channels, lut, acc, extreme);
    ++finished;
  }
  OctoAddSamples(counters, samples);
  atomic_add(&counters[OCTO_COUNTER_FINISHED], finished);
}
#endif
