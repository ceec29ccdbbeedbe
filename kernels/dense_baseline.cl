/* The benchmark baseline of the ray caster (bench/baseline/dense_kernel.h; docs/benchmarks.md,
 * "Rendering"): the plainest OpenCL kernel doing the renderer's level-0 work. The whole volume is
 * ONE plain array in device memory (x fastest, channels interleaved per voxel as in the bricks);
 * no octree, no paging, no level of detail, no empty-space skipping.
 *
 * Per pixel (one work item; the host launches 8x8 work groups): the renderer's ray and clipping
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
      const float3 p = entry + u * (start + 0.5f * seg);
      /* Channels without a transform share one footprint. */
      const OctoDenseFootprint shared = OctoDenseFootprintAt(p, n, channels_stored);
#if OCTO_MODE == OCTO_MODE_DVR
      const OctoRatio ratio =
          j + 1u < segments ? ratio_full : OctoOpacityRatio(seg / vpu * f.inv_reference);
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
        ++samples;
#if OCTO_MODE == OCTO_MODE_DVR
        OctoMixChannel(&channels[k], lut, v, ratio, &mix_rgb, &transmit);
#elif OCTO_MODE == OCTO_MODE_MIP
        extreme[k] = fmax(extreme[k], v);
#else
        extreme[k] = fmin(extreme[k], v);
#endif
      }
#if OCTO_MODE == OCTO_MODE_DVR
      acc = OctoCompositeUnder(acc, mix_rgb, transmit);
      if (acc.w >= 0.999f) break; /* Early termination, as the renderer. */
#endif
    }
  }
  OctoAddSamples(counters, samples);
  atomic_inc(&counters[OCTO_COUNTER_FINISHED]);
  image[py * f.width + px] = OctoFinishPixel(f, channels, lut, acc, extreme);
}
