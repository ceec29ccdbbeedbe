/* Ray casting of a DeviceOctree (server/render/volume_renderer.h; docs/rendering.md): one work
 * item per pixel, with exactly the definitions of the CPU reference renderer
 * (server/render/reference_renderer.cpp) in float precision.
 *
 * Compile-time configuration (-D): OCTO_MODE (OCTO_MODE_DVR / _MIP / _MINIP) and OCTO_REFINE
 * (0: full frame, one pass, missing bricks replaced by coarser data; 1: refinement, a ray pauses
 * at the first sample whose wanted brick is missing and resumes in the next pass).
 *
 * Per ray: clip [t_min, inf) to the box [0, n] and the planes (as ClipRayToVolume); the level of
 * detail from the pixel footprint (orthographic: one level; perspective: bands of constant level,
 * split where the footprint reaches a power of two); each band walked in segments of
 * step * 2^level voxels (arc length in voxel space) whose midpoints are band_entry + (i + 0.5) dt
 * (the last segment shortened to the band's end), never accumulated. Per sample and enabled
 * channel: its transformed position (outside the box: no sample), clamped into the valid extent
 * of the level (so clamp-to-edge equals the reference's and no virtual voxel is read), the octree
 * node (OctoFindNode; without transforms reused while the sample stays in the wanted node's box),
 * trilinear brick sample or node average, transfer function, compositing.
 */
#include "feedback.h"
#include "node_format.h"
#include "octree_sampling.cl"
#include "ray_common.cl"
#include "render_format.h"

#ifndef OCTO_REFINE
#define OCTO_REFINE 0
#endif

/* Full frame: a resident ancestor more than this many levels above the wanted node is too coarse;
 * the wanted node's average is used instead. */
#define OCTO_MAX_FALLBACK_LEVELS 2

/* floor(log2(footprint)) clamped to the tree's levels; ilogb is exact at powers of two. */
int OctoLevelOf(float footprint, OctoTreeGeometry g) {
  return clamp(ilogb(fmax(footprint, 1e-30f)), 0, g.root_level);
}

/* p (level 0) clamped so that its level-`level` coordinate lies in [0.5, LevelSize - 0.5]: the
 * centres of the level's valid voxels (LevelSize = ceil(n / 2^level)). */
float3 OctoClampToLevel(float3 p, int level, OctoTreeGeometry g) {
  const int3 n = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
  const int3 size = (n + (1 << level) - 1) >> level;
  /* Scaling by powers of two is exact: the same as dividing by 2^level. */
  const float3 q = clamp(p * ldexp(1.0f, -level), 0.5f, convert_float3(size) - 0.5f);
  return q * ldexp(1.0f, level);
}

/* Whether the wanted node of `hit` has a brick that is not resident (a deeper node than `hit`'s
 * is never renderable; the root may be `hit` without being renderable). */
bool OctoWantedMissing(OctoNodeHit hit) {
  return hit.node != hit.wanted || (OctoNodeHasBrick(hit.word0) && !OctoNodeInBuffer(hit.word0));
}

/* OctoMarkSlotUsed that also counts the frame's distinct slots (the first work item to stamp a
 * slot counts it; the plain read keeps the atomic off the common path). */
void OctoMarkSlotCounted(__global uint* slot_used, uint slot, uint frame,
                         volatile __global uint* counters) {
  if (slot_used[slot] != frame && atomic_xchg(&slot_used[slot], frame) != frame) {
    atomic_inc(&counters[OCTO_COUNTER_SLOTS_USED]);
  }
}

/* The first sample of a resident hit's brick, in the allocation holding its slot (slot 0 of
 * allocation 0 when the hit has no resident brick; then it is never read). */
__global const ushort* OctoHitBrick(OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g, OctoNodeHit hit) {
  uint local_slot;
  __global const ushort* allocation =
      OctoBrickAllocation(OCTO_BRICK_BUFFER_ARGS, hit.slot, &local_slot);
  return allocation + (ulong)local_slot * OctoBrickSamples(g);
}

/* Where a sample's channel values come from: a trilinear read of a resident brick or a node's
 * averages (the same for every channel that reads the same node at the same position). */
typedef struct OctoSource {
  __global const ushort* brick; /* From OctoHitBrick; read only with from_brick. */
  OctoTrilinear tri;
  ulong average_node;
  bool from_brick;
} OctoSource;

/* The source of the values at q (already clamped to `level`) as `hit` represents them (`brick`:
 * from OctoHitBrick). With `fresh` (the first use of this hit by the ray; requests and slot stamps
 * are idempotent within a frame, so repeating them per sample would only cost), marks the slot
 * used and, in full-frame mode, requests the wanted node. Full frame applies the fallback rule. */
OctoSource OctoResolveSource(__global const ushort* brick, OctoTreeGeometry g, OctoNodeHit hit,
                             float3 q, int level, bool fresh, volatile __global uint* request_flags,
                             volatile __global uint* request_list, uint capacity,
                             __global uint* slot_used, uint frame,
                             volatile __global uint* counters) {
  OctoSource src;
  src.brick = brick;
  src.from_brick = false;
  src.average_node = hit.node;
#if !OCTO_REFINE
  if (OctoWantedMissing(hit)) {
    if (fresh) OctoRequestNode(request_flags, request_list, capacity, hit.wanted, frame);
    if (hit.level - hit.wanted_level > OCTO_MAX_FALLBACK_LEVELS) {
      src.average_node = hit.wanted;
      return src;
    }
  }
#else
  (void)request_flags;
  (void)request_list;
  (void)capacity;
#endif
  if (!OctoNodeInBuffer(hit.word0)) return src;
  /* A coarser node than the sample's level: its own valid extent bounds the footprint (at the
   * same level q is already clamped: clamping again changes nothing). */
  const float3 p = hit.level == level ? q : OctoClampToLevel(q, hit.level, g);
  if (fresh) OctoMarkSlotCounted(slot_used, hit.slot, frame, counters);
  src.tri = OctoTrilinearAt(g, hit.index, hit.level, p);
  src.from_brick = true;
  return src;
}

/* Channel c from `src`. */
float OctoSourceRead(__global const uint* nodes, OctoTreeGeometry g, OctoSource src, int c) {
  if (src.from_brick) return OctoTrilinearRead(src.brick, src.tri, c);
  return OctoNodeAverage(nodes, src.average_node, g, c);
}

__kernel void RayCast(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g,
                      OctoRenderFrame f, __global const OctoChannelParams* channels,
                      __global const float4* lut, volatile __global uint* request_flags,
                      volatile __global uint* request_list, uint request_capacity,
                      __global uint* slot_used, uint frame, __global float4* image,
                      volatile __global uint* counters, __global uint* ray_next,
                      __global float4* ray_acc, __global float* ray_extreme) {
  /* 2-D range over the image, rounded up to whole tiles: neighbouring rays of a work group read
   * the same bricks. */
  const int px = (int)get_global_id(0);
  const int py = (int)get_global_id(1);
  if (px >= f.width || py >= f.height) return;
  const int pixel = py * f.width + px;
#if OCTO_REFINE
  uint first = ray_next[pixel];
  if (first == OCTO_RAY_DONE) return; /* Finished in an earlier pass. */
#else
  (void)ray_next;
  (void)ray_acc;
  (void)ray_extreme;
  const uint first = 0u;
#endif

  /* The pixel's ray, clipped to the box and the planes. */
  const OctoRay ray = OctoPixelRay(f, px, py);
  const float3 o = ray.o;
  const float3 d = ray.d;
  const float t0 = ray.t0;
  const float t1 = ray.t1;
  const float cos_forward = ray.cos_forward;
  const bool empty = ray.empty;

  /* Ray state: accumulated premultiplied colour (DVR) or per-channel extremum (MIP/MinIP). */
  float4 acc = (float4)(0.0f);
  float extreme[OCTO_MAX_ACTIVE_CHANNELS];
#if OCTO_MODE != OCTO_MODE_DVR
  for (int k = 0; k < f.active_channels; ++k) {
#if OCTO_REFINE
    extreme[k] = ray_extreme[(size_t)pixel * (size_t)f.active_channels + (size_t)k];
#else
    /* "Not sampled": outside the stored range [0, 65535], and any stored value replaces it. */
    extreme[k] = OCTO_MODE == OCTO_MODE_MIP ? -1.0f : INFINITY;
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
  uint i = first; /* Global sample index over all bands (the refinement's ray state). */
  if (!empty) {
    /* Arc length in voxel space: |d_vox| voxels per µm; positions entry + u * arc. */
    const float vpu = length(d);
    const float3 u = d / vpu;
    const float3 entry = o + d * t0;
    const float len = (t1 - t0) * vpu;
    const float rounding = OCTO_SLIVER_ULPS * FLT_EPSILON * (fabs(t0) + fabs(t1)) * vpu;
    const bool perspective = f.projection == OCTO_PROJECTION_PERSPECTIVE;
    /* Perspective footprint per µm of t along the ray: footprint(t) = fp_per_t * t. */
    const float fp_per_t = f.lod_scale * cos_forward;
    const float entry_abs = fmax(fabs(entry.x), fmax(fabs(entry.y), fabs(entry.z)));

    /* The screen decides the level; it is constant along a band of the ray (the whole ray when
     * orthographic), and a band of level L is sampled every step * 2^L voxels (the level's voxel
     * size): a finer step would only re-read the same interpolated data. */
    int level = OctoLevelOf(perspective ? fp_per_t * t0 : f.lod_scale, g);
    float band_start = 0.0f; /* Arc where the current band begins. */
    uint band_base = 0u;     /* Global index of its first sample. */
    float band_end = len;
    float dt = f.step;
    uint band_n = 0u;
    bool last_band = true;
    bool band_ready = false;

    /* The node hit of the previous sample (all_identity only), valid for every position inside
     * its wanted node's box (level-0 coordinates) at the same level: the traversal would take the
     * same path and stop at the same nodes. */
    OctoNodeHit shared_hit;
    __global const ushort* shared_brick = bricks0;
    bool cached = false;
    int cached_level = -1;
    float3 cache_lo = (float3)(0.0f);
    float3 cache_hi = (float3)(0.0f);
    for (;;) {
      if (!band_ready) {
        /* The band of `level` ends where the footprint reaches 2^(level + 1). */
        band_end = len;
        if (perspective && level < g.root_level) {
          band_end = fmin(len, (ldexp(2.0f, level) / fp_per_t - t0) * vpu);
        }
        band_end = fmax(band_end, band_start);
        last_band = band_end >= len;
        dt = f.step * ldexp(1.0f, level);
        /* Segments of dt, the last shortened to the band's end; a float sliver is no segment. A
         * ray always has at least one. */
        const float floor_n = (band_base == 0u && last_band) ? 1.0f : 0.0f;
        band_n = (uint)fmax(floor_n, ceil((band_end - band_start - rounding) / dt));
        band_ready = true;
      }
      if (i >= band_base + band_n) {
        if (last_band) break;
        band_base += band_n;
        band_start = band_end;
        ++level;
        band_ready = false;
        continue;
      }
      /* Segment j of the band: its midpoint computed from its index (never accumulated). */
      const uint j = i - band_base;
      const float start = band_start + (float)j * dt;
      const float seg = (j + 1u < band_n) ? dt : band_end - start;
      const float arc = start + 0.5f * seg;
      const float3 p = entry + u * arc;

      /* Without transforms every channel reads the same node: traverse once, and only when the
       * sample left the previous hit's wanted box. */
      float3 shared_q = p;
      bool fresh = true;
      if (f.all_identity) {
        shared_q = OctoClampToLevel(p, level, g);
        if (cached && cached_level == level && all(shared_q >= cache_lo) &&
            all(shared_q < cache_hi)) {
          fresh = false;
        } else {
          shared_hit = OctoFindNode(nodes, g, shared_q, level);
          shared_brick = OctoHitBrick(OCTO_BRICK_BUFFER_ARGS, g, shared_hit);
          const float3 size =
              convert_float3(OctoBrickSize(g)) * ldexp(1.0f, shared_hit.wanted_level);
          cache_lo =
              convert_float3(OctoNodeIndex(shared_q, shared_hit.wanted_level, g).xyz) * size;
          cache_hi = cache_lo + size;
          cached = true;
          cached_level = level;
        }
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
      /* Opacity corrected by the segment's physical length, whatever the level's step. */
      const float ratio = seg / vpu * f.inv_reference;
#endif
      /* All channels at one position read one source: resolve it once. */
      OctoSource shared_src;
      if (f.all_identity) {
        shared_src = OctoResolveSource(shared_brick, g, shared_hit, shared_q, level, fresh,
                                       request_flags, request_list, request_capacity, slot_used,
                                       frame, counters);
      }
      for (int k = 0; k < f.active_channels; ++k) {
        OctoSource src;
        if (f.all_identity) {
          src = shared_src;
        } else {
          float3 q;
          if (!OctoChannelPosition(&channels[k], p, f, &q)) continue;
          q = OctoClampToLevel(q, level, g);
          const OctoNodeHit hit = OctoFindNode(nodes, g, q, level);
          src = OctoResolveSource(OctoHitBrick(OCTO_BRICK_BUFFER_ARGS, g, hit), g, hit, q, level,
                                  true, request_flags, request_list, request_capacity, slot_used,
                                  frame, counters);
        }
        const float v = OctoSourceRead(nodes, g, src, channels[k].channel);
        ++samples;
#if OCTO_MODE == OCTO_MODE_DVR
        /* Per-sample intermixing: premultiplied colours add, alphas combine. */
        if (OctoMixChannel(&channels[k], lut, v, ratio, &mix_rgb, &transmit) != 0.0f) {
          transparent = false;
        }
#elif OCTO_MODE == OCTO_MODE_MIP
        /* Stored-value extremum: the window (width > 0, gamma > 0) is monotone, so it is applied
         * once when the pixel is finished. */
        extreme[k] = fmax(extreme[k], v);
#else
        extreme[k] = fmin(extreme[k], v);
#endif
      }
      uint next = j + 1u; /* Band-local. */
#if OCTO_MODE == OCTO_MODE_DVR
      acc = OctoCompositeUnder(acc, mix_rgb, transmit);
      if (acc.w >= 0.999f) break; /* Early termination. */
      const bool skippable = transparent;
#else
      /* Later samples of a brickless leaf repeat this value: they cannot change an extremum. */
      const bool skippable = true;
#endif
      /* Empty space: a brickless leaf gives the same value everywhere in its box, so jump to the
       * first midpoint beyond the box, within the band (the level, hence the leaf, is the same
       * there; the next band starts over). */
      if (skippable && f.skip_empty && f.all_identity && !OctoNodeHasBrick(shared_hit.word0) &&
          OctoNodeChildGroup(shared_hit.word0) == 0u && shared_hit.node == shared_hit.wanted) {
        const float3 size = convert_float3(OctoBrickSize(g)) * ldexp(1.0f, shared_hit.level);
        const float3 lo = convert_float3(shared_hit.index.xyz) * size;
        const float3 hi = lo + size;
        float arc_exit = INFINITY;
        if (u.x != 0.0f) arc_exit = fmin(arc_exit, ((u.x > 0.0f ? hi.x : lo.x) - entry.x) / u.x);
        if (u.y != 0.0f) arc_exit = fmin(arc_exit, ((u.y > 0.0f ? hi.y : lo.y) - entry.y) / u.y);
        if (u.z != 0.0f) arc_exit = fmin(arc_exit, ((u.z > 0.0f ? hi.z : lo.z) - entry.z) / u.z);
        arc_exit = fmin(arc_exit, band_end);
        /* A margin for rounding: a midpoint near the face is sampled rather than skipped. */
        const float margin = 1e-3f + 1e-5f * (arc_exit + entry_abs);
        const float target = ceil((arc_exit - margin - band_start) / dt - 0.5f);
        if (target > (float)next) next = target >= (float)band_n ? band_n : (uint)target;
      }
      i = band_base + next;
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
