/* Ray casting of a DeviceOctree (server/render/volume_renderer.h; docs/rendering.md): one work
 * item per pixel, with exactly the definitions of the CPU reference renderer
 * (server/render/reference_renderer.cpp) in float precision.
 *
 * Compile-time configuration (-D): OCTO_MODE (OCTO_MODE_DVR / _MIP / _MINIP) and OCTO_REFINE
 * (0: full frame, one pass, missing bricks replaced by coarser data; 1: refinement, a ray pauses
 * at the first sample whose wanted brick is missing and resumes in the next pass). Optional
 * specialisation for one frame's channels (VolumeRenderer builds and caches one program per
 * variant; without them the run-time values of the frame are used): OCTO_ACTIVE (the number of
 * enabled channels, >= 1) with OCTO_CHANNELS (their volume channels, comma-separated), so the
 * channel loops have a fixed trip count and constant channel offsets; OCTO_IDENTITY (1 when no
 * enabled channel has a transform, 0 otherwise).
 *
 * Per ray: clip [t_min, inf) to the box [0, n] and the planes (as ClipRayToVolume); the level of
 * detail from the pixel footprint in the ray's LOD spacing (OctoLodSpacing; orthographic: one
 * level; perspective: bands of constant level, split where the footprint reaches a power of two);
 * each band walked in segments of
 * step * 2^level voxels (arc length in voxel space) whose midpoints are band_entry + (i + 0.5) dt
 * (the last segment shortened to the band's end), never accumulated. Per sample and enabled
 * channel: its transformed position (outside the box: no sample), clamped into the valid extent
 * of the level (so clamp-to-edge equals the reference's and no virtual voxel is read), the octree
 * node (OctoFindNode; reused while the sample stays in the wanted node's box: one hit for all
 * channels without transforms, one per channel with them), trilinear brick sample or node
 * average, transfer function, compositing. Inside a brick resident at the sample's level, samples
 * go eight or four at a time (brick runs; with transforms, transformed runs). Empty-space skipping
 * (docs/rendering.md) jumps over inert nodes (node value ranges), inert cells of resident bricks
 * (cell ranges) and brickless leaves, without changing the image; with transforms, over positions
 * where every channel lies in an inert node of its own, and over transformed runs' steps whose
 * lanes all lie in inert cells.
 */
#include "render_format.h"

/* DVR walks the coarse cells of the cell ranges, MIP and MinIP the fine ones (node_format.h).
 * Before every other include: node_format.h defaults to the fine cells. */
#ifndef OCTO_MODE
#define OCTO_MODE OCTO_MODE_DVR
#endif
#if OCTO_MODE == OCTO_MODE_DVR
#define OCTO_CELL_SIZE OCTO_COARSE_CELL_SIZE
#endif

#include "feedback.h"
#include "node_format.h"
#include "octree_sampling.cl"
#include "ray_common.cl"

#ifndef OCTO_REFINE
#define OCTO_REFINE 0
#endif

#ifdef OCTO_ACTIVE
#define OCTO_ACTIVE_N OCTO_ACTIVE
#define OCTO_STATE_CHANNELS OCTO_ACTIVE
__constant int kOctoChannels[OCTO_ACTIVE] = {OCTO_CHANNELS};
#define OCTO_CHANNEL_OF(k) kOctoChannels[k]
#else
#define OCTO_ACTIVE_N f.active_channels
#define OCTO_STATE_CHANNELS OCTO_MAX_ACTIVE_CHANNELS
#define OCTO_CHANNEL_OF(k) channels[k].channel
#endif
#ifdef OCTO_IDENTITY
#define OCTO_ALL_IDENTITY OCTO_IDENTITY
#else
#define OCTO_ALL_IDENTITY f.all_identity
#endif

/* Full frame: a resident ancestor more than this many levels above the wanted node is too coarse;
 * the wanted node's average is used instead. */
#define OCTO_MAX_FALLBACK_LEVELS 2

/* What a ray's footprint is measured in, in finest spacings (>= 1): the largest projection of a
 * voxel's axis onto the image plane, spacing_a * sqrt(1 - w_a^2) for the ray's unit physical
 * direction w (w_a = d_a * spacing_a; d in voxels per µm). A level is fine enough where none of
 * its voxels' axes looks larger than a pixel, so a coarse z seen from the side keeps finer levels
 * than z seen end on. Exactly 1 with isotropic voxels (each term is at most 1). */
float OctoLodSpacing(OctoRenderFrame f, float3 d) {
  if (f.lod_spacing[0] == 1.0f && f.lod_spacing[1] == 1.0f && f.lod_spacing[2] == 1.0f) {
    return 1.0f; /* Isotropic: what the rest gives, without its work. */
  }
  const float reference = 1.0f / f.inv_reference;
  const float3 rel = (float3)(f.lod_spacing[0], f.lod_spacing[1], f.lod_spacing[2]);
  const float3 w = d * rel * reference;
  const float3 seen = rel * sqrt(fmax(1.0f - w * w, 0.0f));
  return fmax(1.0f, fmax(seen.x, fmax(seen.y, seen.z)));
}

/* floor(log2(footprint)) clamped to the tree's levels; ilogb is exact at powers of two. */
int OctoLevelOf(float footprint, OctoTreeGeometry g) {
  return clamp(ilogb(fmax(footprint, 1e-30f)), 0, g.root_level);
}

/* p (level 0) clamped so that its level-`level` coordinate lies in [0.5, LevelSize - 0.5]: the
 * centres of the level's valid voxels (LevelSize = ceil(n / 2^level)). */
float3 OctoClampToLevel(float3 p, int level, OctoTreeGeometry g) {
  const int3 n = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
  const int3 size = OctoShiftRight3(n + (1 << level) - 1, level);
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

/* Whether node `node`'s subtree cannot change the ray (value-range skipping): DVR, every enabled
 * channel's range maps to zero opacity (max <= visible_lo or min >= visible_hi, computed on the
 * host from the transfer function); MIP (MinIP), every channel's running extremum is already at
 * least the range's max (at most its min) — "not sampled" never is — and MIP also once a channel
 * has a sample and the range's max is at most its window's low end. */
/* Whether values in the range word `range` (min bits 0..15, max bits 16..31) cannot change the
 * ray for enabled channel k (the test of OctoNodeInert for one channel). */
bool OctoRangeInert(uint range, __global const OctoChannelParams* channels, const float* extreme,
                    int k) {
  const float lo = (float)(range & 0xffffu);
  const float hi = (float)(range >> 16);
#if OCTO_MODE == OCTO_MODE_DVR
  (void)extreme;
  return hi <= channels[k].visible_lo || lo >= channels[k].visible_hi;
#elif OCTO_MODE == OCTO_MODE_MIP
  /* Once channel k has a sample (extreme >= 0), values at or below window_lo all display as
   * window 0 (OctoWindowed: v - window_lo <= 0 exactly in float), so they cannot change the
   * pixel either, even where they would raise the extremum itself. */
  (void)lo;
  return extreme[k] >= hi || (extreme[k] >= 0.0f && hi <= channels[k].window_lo);
#else
  (void)channels;
  (void)hi;
  return extreme[k] <= lo;
#endif
}

/* OctoNodeInert for the enabled channels [k_begin, k_end) only (all: 0, OCTO_ACTIVE_N). Forced
 * inline, as OctoInertNodeBox: constant bounds keep the all-channel loop fixed at build time. */
__attribute__((always_inline)) bool OctoNodeInert(
    __global const uint* nodes, ulong node, OctoTreeGeometry g, OctoRenderFrame f,
    __global const OctoChannelParams* channels, const float* extreme, int k_begin, int k_end) {
  (void)f; /* Only the unspecialised channel count reads it. */
  const ulong base = node * OctoNodeWords(g) + (ulong)OCTO_NODE_RANGE_WORD(OctoStoredChannels(g));
  for (int k = k_begin; k < k_end; ++k) {
    if (!OctoRangeInert(nodes[base + (ulong)OCTO_CHANNEL_OF(k)], channels, extreme, k)) {
      return false;
    }
  }
  return true;
}

/* The same for a cell of a resident brick (cell ranges; `words`: the cell's first word): no
 * sample whose brick-local position lies in the cell can change the ray. */
bool OctoCellInert(__global const uint* words, OctoRenderFrame f,
                   __global const OctoChannelParams* channels, const float* extreme) {
  (void)f;
  for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
    if (!OctoRangeInert(words[OCTO_CHANNEL_OF(k)], channels, extreme, k)) return false;
  }
  return true;
}

/* The box of the level-l node `index` (level-0 coordinates) shrunk by `shell` on each face inside
 * the volume. A face on the volume's boundary (at 0, or at or beyond the volume's size) moves out
 * to infinity instead: rays are clipped to the volume and positions clamped into it, so no sample
 * reads anything beyond it (a ray entering an inert region from outside skips from its first
 * sample). */
void OctoShrunkNodeBox(OctoTreeGeometry g, int3 index, int l, float3 shell, float3* lo,
                       float3* hi) {
  const float3 size = convert_float3(OctoBrickSize(g)) * ldexp(1.0f, l);
  const float3 node_lo = convert_float3(index) * size;
  const float3 node_hi = node_lo + size;
  const float3 n = convert_float3((int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]));
  *lo = select(node_lo + shell, (float3)(-INFINITY), index == 0);
  *hi = select(node_hi - shell, (float3)(INFINITY), isgreaterequal(node_hi, n));
}

/* Whether node `node` (brick index `index` at level l) is inert (OctoNodeInert) with p inside
 * its box shrunk by half a voxel of level `data_level` >= l, the coarsest level whose data a
 * sample inside may read (OctoShrunkNodeBox: level-0 coordinates in *lo, *hi); sets *near_face
 * when it is inert but p lies in that shell. Where that level's voxels do not tile the box (the
 * brick size not a multiple of 2^(data_level - l) along an axis), a voxel straddling the face
 * counts as outside. */
__attribute__((always_inline)) bool OctoInertNodeBox(
    __global const uint* nodes, OctoTreeGeometry g, ulong node, int3 index, int l, int data_level,
    float3 p, OctoRenderFrame f, __global const OctoChannelParams* channels, const float* extreme,
    int k_begin, int k_end, float3* lo, float3* hi, bool* near_face) {
  if (!OctoNodeInert(nodes, node, g, f, channels, extreme, k_begin, k_end)) return false;
  const int3 straddles = (OctoBrickSize(g) & ((1 << (data_level - l)) - 1)) != 0;
  const float3 shell =
      ldexp(0.5f, data_level) + select((float3)(0.0f), (float3)(ldexp(1.0f, data_level)), straddles);
  float3 box_lo;
  float3 box_hi;
  OctoShrunkNodeBox(g, index, l, shell, &box_lo, &box_hi);
  if (all(p > box_lo) && all(p < box_hi)) {
    *lo = box_lo;
    *hi = box_hi;
    return true;
  }
  *near_face = true;
  return false;
}

/* The coarsest node on p's path (root down to `level`) that is inert (OctoNodeInert) and whose
 * box, shrunk by half a voxel of the coarsest level a sample inside may read, contains p. A sample
 * inside that shrunk box reads voxels of the node's subtree only (trilinear footprints reach half
 * a voxel), or a node average inside it: values inside the subtree's range, so it cannot change
 * the ray. That level is the node's own, except in full frames below the path's deepest
 * renderable node: samples whose own bricks are missing fall back on it (OctoResolveSource), and
 * its interpolation reaches across the node's faces — a node under a brickless stand-in (whose
 * average is shown) or with none (the root's average) is not skipped. Returns whether there is
 * one, with its shrunk box (level-0 coordinates) in *lo, *hi; *near_face when some inert node of
 * the path has p in its shell instead.
 * Forced inline, as OctoPixelRay: PoCL passed the geometry and frame structs through the stack
 * per call, a store-forwarding stall on every call (5 % of a frame that skips everything). */
__attribute__((always_inline)) bool OctoInertBox(__global const uint* nodes, OctoTreeGeometry g,
                                                 float3 p, int level, OctoRenderFrame f,
                                                 __global const OctoChannelParams* channels,
                                                 const float* extreme, int k_begin, int k_end,
                                                 float3* lo, float3* hi, bool* near_face) {
  const int target = clamp(level, 0, g.root_level);
  const int4 target_index = OctoNodeIndex(p, target, g); /* Shifted per level (OctoFindNode). */
  ulong node = 0;
  int l = g.root_level;
  int4 index = (int4)(0);
  uint word0 = OctoNodeWord(nodes, 0, g, 0);
  int stand_in_level = -1; /* The deepest renderable node so far (-1: none). */
  bool stand_in_resident = false;
  *near_face = false;
  for (;;) {
    if (OctoNodeInBuffer(word0) || !OctoNodeHasBrick(word0)) {
      stand_in_level = l;
      stand_in_resident = OctoNodeInBuffer(word0);
    }
    int data_level = l;
    bool may_skip = true;
#if !OCTO_REFINE
    /* Refinement reads only the wanted level (it pauses where that is missing). */
    if (stand_in_level < 0) {
      may_skip = l == g.root_level;
    } else if (stand_in_level > l) {
      may_skip = stand_in_resident;
      data_level = stand_in_level;
    }
#endif
    if (may_skip && OctoInertNodeBox(nodes, g, node, index.xyz, l, data_level, p, f, channels,
                                     extreme, k_begin, k_end, lo, hi, near_face)) {
      return true;
    }
    const uint group = OctoNodeChildGroup(word0);
    if (l <= target || group == 0u) return false;
    /* Descend as OctoFindNode does (residency does not matter: ranges are always present). */
    const int4 child = (int4)(OctoShiftRight3(target_index.xyz, l - 1 - target), 0);
    const uint octant = (uint)((child.x & 1) * OCTO_OCTANT_X + (child.y & 1) * OCTO_OCTANT_Y +
                               (child.z & 1) * OCTO_OCTANT_Z);
    node = OctoChildNode(group, octant);
    index = child;
    --l;
    word0 = OctoNodeWord(nodes, node, g, 0);
  }
}

/* The band-local index of the first segment whose midpoint lies at or beyond the ray's exit from
 * the box [lo, hi] (the ray at `entry` + u * arc is inside it now), at most band_n: the segments
 * before it all have their midpoints inside the box. Takes 1 / u (infinite where u is 0) and
 * 1 / dt: multiplies instead of four divisions per box (called per brick and per cell). A margin
 * for rounding (far above the reciprocals' ulps): a midpoint near the face is sampled rather than
 * skipped. */
uint OctoFirstSegmentBeyond(float3 entry, float3 inv_u, float entry_abs, float3 lo, float3 hi,
                            float band_start, float band_end, float inv_dt, uint band_n) {
  float box_exit = INFINITY;
  if (isfinite(inv_u.x)) {
    box_exit = fmin(box_exit, ((inv_u.x > 0.0f ? hi.x : lo.x) - entry.x) * inv_u.x);
  }
  if (isfinite(inv_u.y)) {
    box_exit = fmin(box_exit, ((inv_u.y > 0.0f ? hi.y : lo.y) - entry.y) * inv_u.y);
  }
  if (isfinite(inv_u.z)) {
    box_exit = fmin(box_exit, ((inv_u.z > 0.0f ? hi.z : lo.z) - entry.z) * inv_u.z);
  }
  const float arc_exit = fmin(box_exit, band_end);
  const float margin = 1e-3f + 1e-5f * (arc_exit + entry_abs);
  /* The box holds the rest of the band: every later midpoint, the shortened last segment's too
   * (which the index formula below, made for full segments, would keep). */
  if (box_exit - margin >= band_end) return band_n;
  const float target = ceil((arc_exit - margin - band_start) * inv_dt - 0.5f);
  if (!(target > 0.0f)) return 0u;
  return target >= (float)band_n ? band_n : (uint)target;
}

/* N samples of a brick run at once (N = 4, 8), `arc` their midpoints' arcs: positions, footprints
 * and interpolation as N-lane vectors (the same expressions lane by lane as the run's single
 * sample), then the ray state (OCTO_TAKE_SAMPLES: DVR's transfer function, opacity and compositing
 * four lanes at a time, in sample order). Returns true when the ray terminates (DVR); *taken: the
 * samples taken (N unless it terminated). The run's constants as in RayCast. OpenCL C has no
 * templates: OCTO_DEFINE_RUN_STEP_N writes it once per width. */
#define OCTO_DEFINE_RUN_STEP_N(N)                                                                  \
  __attribute__((always_inline)) bool OctoRunStep##N(                                              \
      OctoRenderFrame f, OctoTreeGeometry g, __global const OctoChannelParams* channels,           \
      __global const float4* lut, __global const ushort* brick, float##N arc, float3 entry_l,      \
      float3 u_l, float3 valid_hi, int shift, float down, float3 hit_valid_hi,                     \
      float3 brick_origin, OctoRatio ratio, float4* acc, float* extreme, uint* samples,            \
      uint* taken) {                                                                               \
    (void)f;                                                                                       \
    (void)lut;                                                                                     \
    (void)ratio;                                                                                   \
    (void)acc;                                                                                     \
    (void)extreme;                                                                                 \
    float##N px = clamp(entry_l.x + u_l.x * arc, 0.5f, valid_hi.x);                                \
    float##N py = clamp(entry_l.y + u_l.y * arc, 0.5f, valid_hi.y);                                \
    float##N pz = clamp(entry_l.z + u_l.z * arc, 0.5f, valid_hi.z);                                \
    if (shift > 0) {                                                                               \
      px = clamp(px * down, 0.5f, hit_valid_hi.x);                                                 \
      py = clamp(py * down, 0.5f, hit_valid_hi.y);                                                 \
      pz = clamp(pz * down, 0.5f, hit_valid_hi.z);                                                 \
    }                                                                                              \
    const OctoTrilinear##N tri = OctoTrilinearLocal##N(                                            \
        g, px + 0.5f - brick_origin.x, py + 0.5f - brick_origin.y, pz + 0.5f - brick_origin.z);    \
    float##N v[OCTO_STATE_CHANNELS];                                                               \
    for (int k = 0; k < OCTO_ACTIVE_N; ++k) {                                                      \
      v[k] = OctoTrilinearRead##N(brick, tri, OCTO_CHANNEL_OF(k));                                 \
    }                                                                                              \
    OCTO_TAKE_SAMPLES(N, OCTO_ACTIVE_N, OCTO_STATE_CHANNELS)                                       \
    return false;                                                                                  \
  }
OCTO_DEFINE_RUN_STEP_N(4)
#if OCTO_RUN_LANES >= 8
OCTO_DEFINE_RUN_STEP_N(8)
#endif

/* Whether none of N samples can change the ray for enabled channel k (OctoRangeInert): each lane's
 * cell (cell ranges; `words`: its slot's cells, OctoCellOffset included) at brick-local level
 * position (bx, by, bz), inside the brick. A cell's range covers every voxel a trilinear sample
 * inside it reads (cell_ranges.h). */
#define OCTO_DEFINE_LANES_INERT_N(N)                                                               \
  __attribute__((always_inline)) bool OctoLanesInert##N(                                           \
      __global const uint* words, OctoTreeGeometry g, float##N bx, float##N by, float##N bz,       \
      __global const OctoChannelParams* channels, const float* extreme, int k) {                   \
    const int3 cells = OctoCellsPerAxis(g);                                                        \
    const int##N cx = min(convert_int##N(bx) / OCTO_CELL_SIZE, cells.x - 1);                       \
    const int##N cy = min(convert_int##N(by) / OCTO_CELL_SIZE, cells.y - 1);                       \
    const int##N cz = min(convert_int##N(bz) / OCTO_CELL_SIZE, cells.z - 1);                       \
    int lanes[N];                                                                                  \
    vstore##N((cz * cells.y + cy) * cells.x + cx, 0, lanes);                                       \
    const ulong stored = (ulong)OctoStoredChannels(g);                                             \
    const ulong channel = (ulong)OCTO_CHANNEL_OF(k);                                               \
    for (int l = 0; l < (N); ++l) {                                                                \
      if (!OctoRangeInert(words[(ulong)lanes[l] * stored + channel], channels, extreme, k)) {      \
        return false;                                                                              \
      }                                                                                            \
    }                                                                                              \
    return true;                                                                                   \
  }
OCTO_DEFINE_LANES_INERT_N(4)
#if OCTO_RUN_LANES >= 8
OCTO_DEFINE_LANES_INERT_N(8)
#endif

/* With channel transforms: N samples of a transformed run at once, every channel read from its
 * cached fast hit's brick (RayCast's ch_* state: bricks, their slots' cells, wanted boxes and
 * brick origins in the band's level coordinates; level_down = 2^-level). Per lane the same
 * expressions and tests as the single sample's (OctoChannelPosition, the clamp to the level, the
 * cached box): when any lane of any channel leaves the volume box or its channel's box, nothing is
 * taken (*taken 0) and the single-sample path goes on. With skipping, when every lane of every
 * channel lies in an inert cell (OctoLanesInert), the N samples are skipped (*taken N, added to
 * *skipped) instead of read: they could not change the ray. Otherwise as OctoRunStepN. */
#define OCTO_DEFINE_TRANSFORM_STEP_N(N)                                                            \
  __attribute__((always_inline)) bool OctoTransformStep##N(                                        \
      OctoRenderFrame f, OctoTreeGeometry g, __global const OctoChannelParams* channels,           \
      __global const float4* lut, __global const ushort* const* bricks,                            \
      __global const uint* const* cells, float##N arc, float3 entry, float3 u, float level_down,   \
      float3 valid_hi, const float3* lo, const float3* hi, const float3* origin, OctoRatio ratio,  \
      float4* acc, float* extreme, uint* samples, uint* skipped, uint* taken) {                    \
    (void)lut;                                                                                     \
    (void)ratio;                                                                                   \
    (void)acc;                                                                                     \
    const float##N px = entry.x + u.x * arc;                                                       \
    const float##N py = entry.y + u.y * arc;                                                       \
    const float##N pz = entry.z + u.z * arc;                                                       \
    OctoTrilinear##N tri[OCTO_STATE_CHANNELS];                                                     \
    bool inert = f.skip_empty != 0;                                                                \
    for (int k = 0; k < OCTO_ACTIVE_N; ++k) {                                                      \
      float##N rx;                                                                                 \
      float##N ry;                                                                                 \
      float##N rz;                                                                                 \
      *taken = 0u;                                                                                 \
      if (!OctoChannelPositions##N(&channels[k], px, py, pz, f, &rx, &ry, &rz)) return false;      \
      const float##N lx = clamp(rx * level_down, 0.5f, valid_hi.x);                                \
      const float##N ly = clamp(ry * level_down, 0.5f, valid_hi.y);                                \
      const float##N lz = clamp(rz * level_down, 0.5f, valid_hi.z);                                \
      if (!all((lx >= lo[k].x) & (ly >= lo[k].y) & (lz >= lo[k].z) & (lx < hi[k].x) &             \
               (ly < hi[k].y) & (lz < hi[k].z))) {                                                 \
        return false;                                                                              \
      }                                                                                            \
      if (inert) {                                                                                 \
        inert = OctoLanesInert##N(cells[k], g, lx - origin[k].x, ly - origin[k].y,                 \
                                  lz - origin[k].z, channels, extreme, k);                         \
      }                                                                                            \
      tri[k] = OctoTrilinearLocal##N(g, lx + 0.5f - origin[k].x, ly + 0.5f - origin[k].y,          \
                                     lz + 0.5f - origin[k].z);                                     \
    }                                                                                              \
    if (inert) {                                                                                   \
      *taken = N;                                                                                  \
      *skipped += (uint)(N) * (uint)OCTO_ACTIVE_N;                                                 \
      return false;                                                                                \
    }                                                                                              \
    float##N v[OCTO_STATE_CHANNELS];                                                               \
    for (int k = 0; k < OCTO_ACTIVE_N; ++k) {                                                      \
      v[k] = OctoTrilinearRead##N(bricks[k], tri[k], OCTO_CHANNEL_OF(k));                          \
    }                                                                                              \
    OCTO_TAKE_SAMPLES(N, OCTO_ACTIVE_N, OCTO_STATE_CHANNELS)                                       \
    return false;                                                                                  \
  }
OCTO_DEFINE_TRANSFORM_STEP_N(4)
#if OCTO_RUN_LANES >= 8
OCTO_DEFINE_TRANSFORM_STEP_N(8)
#endif

__kernel void RayCast(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g,
                      OctoRenderFrame f, __global const OctoChannelParams* channels,
                      __global const float4* lut, volatile __global uint* request_flags,
                      volatile __global uint* request_list, uint request_capacity,
                      __global uint* slot_used, __global const uint* cell_ranges, uint frame,
                      __global float4* image,
                      volatile __global uint* counters, __global uint* ray_next,
                      __global float4* ray_acc, __global float* ray_extreme,
                      __global const uint* tiles_in, __global uint* tiles_out,
                      volatile __global uint* tile_stamp, uint tile_offset, uint tile_count,
                      int all_tiles) {
#if OCTO_REFINE
  /* A 1-D range of OCTO_TILE^2 work items per tile of the slice [tile_offset, tile_offset +
   * tile_count) of the tile list (the tiles that still have unfinished rays; all tiles in the
   * first sweep): finished rays cost nothing, and a tile's rays are neighbours that share
   * bricks. */
  const uint gid = (uint)get_global_id(0);
  if (gid / (OCTO_TILE * OCTO_TILE) >= tile_count) return;
  const uint entry_index = tile_offset + gid / (OCTO_TILE * OCTO_TILE);
  const uint tile = all_tiles ? entry_index : tiles_in[entry_index];
  const uint tiles_x = (uint)(f.width + OCTO_TILE - 1) / OCTO_TILE;
  const uint within = gid % (OCTO_TILE * OCTO_TILE);
  const int px = (int)((tile % tiles_x) * OCTO_TILE + within % OCTO_TILE);
  const int py = (int)((tile / tiles_x) * OCTO_TILE + within / OCTO_TILE);
  if (px >= f.width || py >= f.height) return;
  const int pixel = py * f.width + px;
  uint first = ray_next[pixel];
  if (first == OCTO_RAY_DONE) return; /* Finished in an earlier pass. */
#else
  /* 2-D range over the image, rounded up to whole tiles: neighbouring rays of a work group read
   * the same bricks. */
  const int px = (int)get_global_id(0);
  const int py = (int)get_global_id(1);
  if (px >= f.width || py >= f.height) return;
  const int pixel = py * f.width + px;
  (void)ray_next;
  (void)ray_acc;
  (void)ray_extreme;
  (void)tiles_in;
  (void)tiles_out;
  (void)tile_stamp;
  (void)tile_offset;
  (void)tile_count;
  (void)all_tiles;
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
  float extreme[OCTO_STATE_CHANNELS];
#if OCTO_MODE != OCTO_MODE_DVR
  for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
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
  uint skipped = 0u; /* Channel samples skipped by value ranges. */
  bool paused = false;
  uint i = first; /* Global sample index over all bands (the refinement's ray state). */
  if (!empty) {
    /* Arc length in voxel space: |d_vox| voxels per µm; positions entry + u * arc. */
    const float vpu = length(d);
    const float3 u = d / vpu;
    const float3 inv_u = 1.0f / u; /* Infinite where u is 0 (OctoFirstSegmentBeyond). */
    const float3 entry = o + d * t0;
    const float len = (t1 - t0) * vpu;
    const float rounding = OCTO_SLIVER_ULPS * FLT_EPSILON * (fabs(t0) + fabs(t1)) * vpu;
    const bool perspective = f.projection == OCTO_PROJECTION_PERSPECTIVE;
    /* Footprints in this ray's LOD spacings; perspective: per µm of t along the ray,
     * footprint(t) = fp_per_t * t. */
    const float lod_scale = f.lod_scale / OctoLodSpacing(f, d);
    const float fp_per_t = lod_scale * cos_forward;
    const float entry_abs = fmax(fabs(entry.x), fmax(fabs(entry.y), fabs(entry.z)));

    /* The screen decides the level; it is constant along a band of the ray (the whole ray when
     * orthographic), and a band of level L is sampled every step * 2^L voxels (the level's voxel
     * size): a finer step would only re-read the same interpolated data. */
    int level = OctoLevelOf(perspective ? fp_per_t * t0 : lod_scale, g);
    float band_start = 0.0f; /* Arc where the current band begins. */
    uint band_base = 0u;     /* Global index of its first sample. */
    float band_end = len;
    float dt = f.step;
    float inv_dt = 1.0f / dt;
    /* DVR's opacity correction of full segments (unused by MIP/MinIP). */
    OctoRatio band_ratio = OctoOpacityRatio(f.step / vpu * f.inv_reference);
    bool terminated = false; /* DVR: early termination inside a brick run. */
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
    /* Its wanted box in the band's level coordinates; `fast`: the hit is the wanted node itself,
     * resident at the sample's level, so a sample inside the box reads its brick at brick-local
     * coordinates level_pos + 0.5 - brick_origin (no traversal, no per-sample node logic). */
    float3 cache_lo = (float3)(0.0f);
    float3 cache_hi = (float3)(0.0f);
    bool fast = false;
    /* Full frames: `fallback` — the wanted node (at the sample's level) is missing and the hit is
     * a resident ancestor at most OCTO_MAX_FALLBACK_LEVELS above, read at its own level
     * (OctoResolveSource); its samples in the wanted box march in the same tight loop, `shift`
     * levels up (0 when fast), its valid voxel centres up to hit_valid_hi. */
    bool fallback = false;
    int shift = 0;
    /* `fast` only: the hit's node is inert, with its box shrunk by half a voxel (level 0). */
    bool hit_inert = false;
    float3 hit_inert_lo = (float3)(0.0f);
    float3 hit_inert_hi = (float3)(0.0f);
    float3 hit_valid_hi = (float3)(0.0f);
    float3 brick_origin = (float3)(0.0f); /* In the hit's level coordinates. */
    int last_cell = -1; /* The brick's cell whose range was tested last (-1: none). */
    /* The band's level coordinates: position = entry_l + u_l * arc, clamped to the level's valid
     * voxel centres [0.5, valid_hi] (OctoClampToLevel; scaling by 2^-level is exact). */
    float3 entry_l = entry;
    float3 u_l = u;
    float3 valid_hi = (float3)(0.0f);
    /* With transforms: per enabled channel, the node hit of its previous sample and that hit's
     * wanted box (band level coordinates), reused as shared_hit is while the channel's position
     * stays inside at the same level (ch_level -1: none yet). */
    OctoNodeHit ch_hit[OCTO_STATE_CHANNELS];
    __global const ushort* ch_brick[OCTO_STATE_CHANNELS];
    float3 ch_lo[OCTO_STATE_CHANNELS];
    float3 ch_hi[OCTO_STATE_CHANNELS];
    float3 ch_origin[OCTO_STATE_CHANNELS]; /* The hit's brick origin, level coordinates. */
    int ch_level[OCTO_STATE_CHANNELS];
    for (int k = 0; k < OCTO_ACTIVE_N; ++k) ch_level[k] = -1;
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
        inv_dt = 1.0f / dt;
        band_ratio = OctoOpacityRatio(dt / vpu * f.inv_reference);
        /* Segments of dt, the last shortened to the band's end; a float sliver is no segment. A
         * ray always has at least one. */
        const float floor_n = (band_base == 0u && last_band) ? 1.0f : 0.0f;
        band_n = (uint)fmax(floor_n, ceil((band_end - band_start - rounding) / dt));
        const float level_scale = ldexp(1.0f, -level);
        entry_l = entry * level_scale;
        u_l = u * level_scale;
        const int3 n = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
        valid_hi = convert_float3(OctoShiftRight3(n + (1 << level) - 1, level)) - 0.5f;
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
      float3 level_pos = p;
      bool fresh = true;
      if (OCTO_ALL_IDENTITY) {
        level_pos = clamp(entry_l + u_l * arc, 0.5f, valid_hi);
        shared_q = level_pos * ldexp(1.0f, level);
        if (cached && cached_level == level && all(level_pos >= cache_lo) &&
            all(level_pos < cache_hi)) {
          fresh = false;
        } else {
          /* The node first: in a brick resident at the sample's level only that node's own range
           * is tested (an inert ancestor makes it inert too), and its cell ranges (below) do the
           * finer skipping, cheaper than the walk from the root. */
          shared_hit = OctoFindNode(nodes, g, shared_q, level);
          fast = OctoNodeInBuffer(shared_hit.word0) && shared_hit.node == shared_hit.wanted &&
                 shared_hit.level == level;
          /* A fast hit whose node is inert: its box shrunk by half a voxel (no sample inside
           * reads a voxel outside the node) is jumped over below while the hit stays cached;
           * samples in the shell are left to the cells, whose ranges cover their footprints. */
          hit_inert = f.skip_empty && fast &&
                      OctoNodeInert(nodes, shared_hit.node, g, f, channels, extreme, 0,
                                    OCTO_ACTIVE_N);
          /* Value ranges, other hits, and inert fast hits below the root (an inert ancestor
           * reaches further): jump over the coarsest inert node around p (before anything is
           * requested). A sample in an inert node's shell is taken; other hits are then not
           * cached (the next sample checks again), a fast hit is (its cells take the shell). */
          bool near_face = false;
          if (f.skip_empty && (!fast || (hit_inert && shared_hit.level < g.root_level))) {
            float3 inert_lo;
            float3 inert_hi;
            bool in_shell = false;
            if (OctoInertBox(nodes, g, p, level, f, channels, extreme, 0, OCTO_ACTIVE_N,
                             &inert_lo, &inert_hi, &in_shell)) {
              const uint target =
                  OctoFirstSegmentBeyond(entry, inv_u, entry_abs, inert_lo, inert_hi, band_start,
                                         band_end, inv_dt, band_n);
              if (target > j) {
                /* A skipped resident brick still counts as used (eviction order). */
                if (fast) OctoMarkSlotCounted(slot_used, shared_hit.slot, frame, counters);
                skipped += (target - j) * (uint)OCTO_ACTIVE_N;
                i = band_base + target;
                cached = false; /* shared_hit may have changed. */
                continue;
              }
            }
            near_face = in_shell && !fast;
          }
          if (hit_inert) {
            OctoShrunkNodeBox(g, shared_hit.index.xyz, level, (float3)(ldexp(0.5f, level)),
                              &hit_inert_lo, &hit_inert_hi);
          }
          shared_brick = OctoHitBrick(OCTO_BRICK_BUFFER_ARGS, g, shared_hit);
          const float3 size =
              convert_float3(OctoBrickSize(g)) * ldexp(1.0f, shared_hit.wanted_level - level);
          cache_lo =
              convert_float3(OctoNodeIndex(shared_q, shared_hit.wanted_level, g).xyz) * size;
          cache_hi = cache_lo + size;
          cached = !near_face;
          cached_level = level;
          shift = shared_hit.level - level;
          fallback = !OCTO_REFINE && !fast && OctoNodeInBuffer(shared_hit.word0) &&
                     shared_hit.wanted_level == level && shift > 0 &&
                     shift <= OCTO_MAX_FALLBACK_LEVELS;
          if (fallback) {
            const int3 n = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
            hit_valid_hi =
                convert_float3(OctoShiftRight3(n + (1 << shared_hit.level) - 1, shared_hit.level)) -
                0.5f;
          }
          brick_origin = convert_float3(shared_hit.index.xyz * OctoBrickSize(g));
          last_cell = -1;
        }
      }
      /* An inert fast hit: jump to the first midpoint beyond its shrunk box when p is inside
       * (the brick still counts as used: eviction order). */
      if (OCTO_ALL_IDENTITY && fast && hit_inert && all(p > hit_inert_lo) &&
          all(p < hit_inert_hi)) {
        const uint target =
            OctoFirstSegmentBeyond(entry, inv_u, entry_abs, hit_inert_lo, hit_inert_hi,
                                   band_start, band_end, inv_dt, band_n);
        if (target > j) {
          if (fresh) OctoMarkSlotCounted(slot_used, shared_hit.slot, frame, counters);
          skipped += (target - j) * (uint)OCTO_ACTIVE_N;
          i = band_base + target;
          continue;
        }
      }
      /* Brick-local marching: once a ray is in a brick resident at its level, the samples up to
       * the brick's exit (found once; the band's shortened last segment excluded) run in one
       * tight loop: no box test, no node logic, the position straight from the sample index
       * (as below, so the same sample gives the same value whichever loop takes it). A fast hit's
       * first sample too; a fallback hit's first one takes the general path below, which
       * requests. A full frame's
       * fallback marches the same way through the ancestor's brick up to the wanted box's exit:
       * positions scaled `shift` levels up and clamped there as OctoResolveSource does (powers
       * of two: exact).
       * With skipping, the run walks the brick's cells along the ray (3-D DDA: per axis the arc
       * of the next cell face), testing each cell once: an inert cell's midpoints are jumped
       * over up to its exit less a rounding margin, a live cell's are sampled up to its exit plus
       * the margin, so a skipped midpoint lies in an inert cell (a cell's range covers positions
       * up to half a voxel outside it; the rounding is far below). Skips stop at the run's end:
       * an ancestor's cell may reach into a neighbour resident at the finer level. */
      if (OCTO_ALL_IDENTITY && (fast || (fallback && !fresh))) {
        const float hit_scale = ldexp(1.0f, level + shift); /* Hit level to level 0. */
        const float down = ldexp(1.0f, -shift);             /* Level to hit level. */
        const float scale = ldexp(1.0f, level);
        const uint run_end =
            min(OctoFirstSegmentBeyond(entry, inv_u, entry_abs, cache_lo * scale, cache_hi * scale,
                                       band_start, band_end, inv_dt, band_n),
                band_n - 1u);
        if (run_end > j) {
          /* A fast hit's first sample needs nothing of the general path but the slot's stamp
           * (its wanted node is resident: nothing to request). */
          if (fresh) OctoMarkSlotCounted(slot_used, shared_hit.slot, frame, counters);
          uint jj = j;
          /* The cell DDA: current cell (hit-level brick-local), the arc of its next face per
           * axis (infinite along an axis the ray does not move on). */
          bool dda = f.skip_empty;
          const int3 cells = OctoCellsPerAxis(g);
          __global const uint* slot_cells =
              cell_ranges + (ulong)shared_hit.slot * OctoCellWords(g) + OctoCellOffset(g);
          const int3 cell_step = convert_int3(sign(u));
          const float3 face_side = select((float3)(0.0f), (float3)(1.0f), isgreater(u, 0.0f));
          int3 cell = (int3)(0);
          float3 next_face = (float3)(INFINITY);
          if (dda) {
            float3 lp = clamp(entry_l + u_l * ((band_start + (float)jj * dt) + 0.5f * dt),
                              0.5f, valid_hi);
            if (shift > 0) lp = clamp(lp * down, 0.5f, hit_valid_hi);
            cell = clamp(convert_int3(lp - brick_origin) / OCTO_CELL_SIZE, 0, cells - 1);
            const float3 face = (brick_origin + (convert_float3(cell) + face_side) *
                                                    (float)OCTO_CELL_SIZE) * hit_scale;
            next_face = select((float3)(INFINITY), (face - entry) * inv_u, isfinite(inv_u));
          }
          while (jj < run_end) {
            /* The stretch to sample, [jj, stop), then the inert cell's midpoints [.., skip_to)
             * jumped over: consecutive live cells are gathered into one stretch, so its samples run
             * eight or four at a time across cell faces. DVR's inert test does not depend on the
             * ray. MIP's (MinIP's) does, and the gathered cells are not sampled yet: a cell ahead
             * is tested against `ahead`, the extremum as it will be at least (at most) once they
             * are — each live cell that gets a sample raises it to at least its range's minimum
             * (lowers it to at most its maximum: every sample attributed to a cell lies in its
             * range). Inert for `ahead` is inert for the true extremum then; a cell that only the
             * true one makes inert is sampled, which cannot change the ray. */
            uint stop = run_end;
            uint skip_to = 0u;
            if (dda) {
              stop = jj;
              bool inert = false;
#if OCTO_MODE == OCTO_MODE_DVR
              const float* ahead = extreme;
#else
              float ahead[OCTO_STATE_CHANNELS];
              for (int k = 0; k < OCTO_ACTIVE_N; ++k) ahead[k] = extreme[k];
#endif
              do {
                const float cell_exit = fmin(next_face.x, fmin(next_face.y, next_face.z));
                const float margin = 1e-3f + 1e-5f * (cell_exit + entry_abs);
                const int cell_id = (cell.z * cells.y + cell.y) * cells.x + cell.x;
                __global const uint* words =
                    slot_cells + (ulong)cell_id * (ulong)OctoStoredChannels(g);
                inert = OctoCellInert(words, f, channels, ahead);
                /* The first segment whose midpoint is at or beyond the face (less or plus the
                 * margin), within the run. */
                const float edge = (cell_exit + (inert ? -margin : margin) - band_start) * inv_dt;
                const float first_beyond = ceil(edge - 0.5f);
                const uint bound = !(first_beyond > 0.0f)           ? 0u
                                   : first_beyond >= (float)run_end ? run_end
                                                                    : (uint)first_beyond;
                if (inert) {
                  skip_to = bound;
                } else {
#if OCTO_MODE != OCTO_MODE_DVR
                  if (bound > stop) {
                    for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
                      const uint range = words[OCTO_CHANNEL_OF(k)];
#if OCTO_MODE == OCTO_MODE_MIP
                      ahead[k] = fmax(ahead[k], (float)(range & 0xffffu));
#else
                      ahead[k] = fmin(ahead[k], (float)(range >> 16));
#endif
                    }
                  }
#endif
                  stop = max(stop, bound);
                }
                /* Into the next cell: across the nearest face. */
                if (next_face.x <= next_face.y && next_face.x <= next_face.z) {
                  cell.x += cell_step.x;
                  next_face.x = ((brick_origin.x + ((float)cell.x + face_side.x) * OCTO_CELL_SIZE) *
                                     hit_scale - entry.x) * inv_u.x;
                } else if (next_face.y <= next_face.z) {
                  cell.y += cell_step.y;
                  next_face.y = ((brick_origin.y + ((float)cell.y + face_side.y) * OCTO_CELL_SIZE) *
                                     hit_scale - entry.y) * inv_u.y;
                } else {
                  cell.z += cell_step.z;
                  next_face.z = ((brick_origin.z + ((float)cell.z + face_side.z) * OCTO_CELL_SIZE) *
                                     hit_scale - entry.z) * inv_u.z;
                }
                /* Out of the brick before the run's end (rounding at its faces): the rest of the
                 * run is sampled. */
                if (any(cell < 0) || any(cell >= cells)) {
                  dda = false;
                  if (!inert) stop = run_end;
                }
              } while (!inert && dda && stop < run_end);
            }
            /* Eight samples at a time (where OCTO_RUN_LANES is 8), then four (OctoRunStep8, 4),
             * the rest one by one. The lane indices jj + l are exact in float (sample indices
             * stay far below 2^24). */
            uint taken = 0u;
#if OCTO_RUN_LANES >= 8
            for (; jj + 8u <= stop && !terminated; jj += taken) {
              const float8 lanes = (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
              const float8 arc8 = (band_start + ((float)jj + lanes) * dt) + 0.5f * dt;
              terminated = OctoRunStep8(f, g, channels, lut, shared_brick, arc8, entry_l, u_l,
                                        valid_hi, shift, down, hit_valid_hi, brick_origin,
                                        band_ratio, &acc, extreme, &samples, &taken);
            }
#endif
            for (; jj + 4u <= stop && !terminated; jj += taken) {
              const float4 arc4 =
                  (band_start + ((float)jj + (float4)(0.0f, 1.0f, 2.0f, 3.0f)) * dt) + 0.5f * dt;
              terminated = OctoRunStep4(f, g, channels, lut, shared_brick, arc4, entry_l, u_l,
                                        valid_hi, shift, down, hit_valid_hi, brick_origin,
                                        band_ratio, &acc, extreme, &samples, &taken);
            }
            if (terminated) break;
            for (; jj < stop; ++jj) {
              const float run_arc = (band_start + (float)jj * dt) + 0.5f * dt;
              float3 lp = clamp(entry_l + u_l * run_arc, 0.5f, valid_hi);
              if (shift > 0) lp = clamp(lp * down, 0.5f, hit_valid_hi);
              const OctoTrilinear tri = OctoTrilinearLocal(g, lp + 0.5f - brick_origin);
#if OCTO_MODE == OCTO_MODE_DVR
              float3 run_rgb = (float3)(0.0f);
              float run_transmit = 1.0f;
#endif
              for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
                const float v = OctoTrilinearRead(shared_brick, tri, OCTO_CHANNEL_OF(k));
#if OCTO_MODE == OCTO_MODE_DVR
                OctoMixChannel(&channels[k], lut, v, band_ratio, &run_rgb, &run_transmit);
#elif OCTO_MODE == OCTO_MODE_MIP
                extreme[k] = fmax(extreme[k], v);
#else
                extreme[k] = fmin(extreme[k], v);
#endif
              }
              samples += (uint)OCTO_ACTIVE_N;
#if OCTO_MODE == OCTO_MODE_DVR
              acc = OctoCompositeUnder(acc, run_rgb, run_transmit);
              if (acc.w >= 0.999f) {
                terminated = true;
                ++jj;
                break;
              }
#endif
            }
            if (terminated) break;
            if (skip_to > jj) {
              skipped += (skip_to - jj) * (uint)OCTO_ACTIVE_N;
              jj = skip_to;
            }
          }
          i = band_base + jj;
          last_cell = -1;
          if (terminated) break;
          continue;
        }
      }
      /* Cell ranges: in a brick resident at the sample's level, jump over the cell around the
       * sample when it cannot change the ray (tested once per cell the ray enters). Every skipped
       * midpoint lies between p and the cell's exit, so its clamped level position lies in the
       * cell too and reads only the voxels the cell's range covers. */
      if (OCTO_ALL_IDENTITY && fast && f.skip_empty) {
        const int3 cells = OctoCellsPerAxis(g);
        const int3 cell = min(convert_int3(level_pos - brick_origin) / OCTO_CELL_SIZE, cells - 1);
        const int cell_id = (cell.z * cells.y + cell.y) * cells.x + cell.x;
        if (cell_id != last_cell) {
          last_cell = cell_id;
          /* The brick counts as used even when its first cell is skipped (eviction order). */
          if (fresh) OctoMarkSlotCounted(slot_used, shared_hit.slot, frame, counters);
          __global const uint* words = cell_ranges + (ulong)shared_hit.slot * OctoCellWords(g) +
                                       OctoCellOffset(g) +
                                       (ulong)cell_id * (ulong)OctoStoredChannels(g);
          if (OctoCellInert(words, f, channels, extreme)) {
            const float scale = ldexp(1.0f, level);
            const float3 cell_lo = brick_origin + convert_float3(cell * OCTO_CELL_SIZE);
            const float3 cell_hi = fmin(cell_lo + (float)OCTO_CELL_SIZE,
                                        brick_origin + convert_float3(OctoBrickSize(g)));
            const uint target =
                OctoFirstSegmentBeyond(entry, inv_u, entry_abs, cell_lo * scale, cell_hi * scale,
                                       band_start, band_end, inv_dt, band_n);
            if (target > j) {
              skipped += (target - j) * (uint)OCTO_ACTIVE_N;
              i = band_base + target;
              continue;
            }
          }
        }
      }

      /* With transforms: each channel's position (outside the box: no sample), clamped to the
       * level, and its node hit (traversed only when it left the channel's cached box). */
      bool ch_in[OCTO_STATE_CHANNELS];
      bool ch_fresh[OCTO_STATE_CHANNELS];
      float3 ch_q[OCTO_STATE_CHANNELS];
      float3 ch_p[OCTO_STATE_CHANNELS]; /* The transformed position before the clamp. */
      if (!OCTO_ALL_IDENTITY) {
        bool any_fresh = false;
        for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
          ch_in[k] = OctoChannelPosition(&channels[k], p, f, &ch_q[k]);
          if (!ch_in[k]) continue;
          ch_p[k] = ch_q[k];
          const float3 ql = clamp(ch_q[k] * ldexp(1.0f, -level), 0.5f, valid_hi);
          ch_q[k] = ql * ldexp(1.0f, level); /* OctoClampToLevel, exactly. */
          ch_fresh[k] = !(ch_level[k] == level && all(ql >= ch_lo[k]) && all(ql < ch_hi[k]));
          if (ch_fresh[k]) {
            const OctoNodeHit hit = OctoFindNode(nodes, g, ch_q[k], level);
            const float3 size =
                convert_float3(OctoBrickSize(g)) * ldexp(1.0f, hit.wanted_level - level);
            ch_hit[k] = hit;
            ch_brick[k] = OctoHitBrick(OCTO_BRICK_BUFFER_ARGS, g, hit);
            ch_lo[k] = convert_float3(OctoNodeIndex(ch_q[k], hit.wanted_level, g).xyz) * size;
            ch_hi[k] = ch_lo[k] + size;
            ch_origin[k] = convert_float3(hit.index.xyz * OctoBrickSize(g));
            ch_level[k] = level;
            any_fresh = true;
          }
        }
        /* Empty space, each channel in its own space (when a channel enters a node): where
         * every enabled channel's position lies in an inert node of its own (OctoInertBox for
         * that channel alone), the ray jumps to the first midpoint beyond the nearest of their
         * exits, each taken along the channel's transformed ray (an affine map of a ray is a
         * ray). A channel outside the volume, or in an inert node's shell (tested again at the
         * next sample), stops the jump. */
        if (f.skip_empty && any_fresh) {
          uint target = band_n;
          for (int k = 0; k < OCTO_ACTIVE_N && target > j; ++k) {
            float3 inert_lo;
            float3 inert_hi;
            bool in_shell = false;
            if (!ch_in[k] || !OctoInertBox(nodes, g, ch_p[k], level, f, channels, extreme, k,
                                           k + 1, &inert_lo, &inert_hi, &in_shell)) {
              if (in_shell) ch_level[k] = -1;
              target = 0u;
              break;
            }
            float3 e = entry;
            float3 w = u;
            if (!channels[k].identity) {
              e = OctoTransformPoint(channels[k].transform, entry);
              w = OctoTransformDirection(channels[k].transform, u);
            }
            const float3 inv_w = 1.0f / w;
            const float e_abs = fmax(fabs(e.x), fmax(fabs(e.y), fabs(e.z)));
            target = min(target, OctoFirstSegmentBeyond(e, inv_w, e_abs, inert_lo, inert_hi,
                                                        band_start, band_end, inv_dt, band_n));
            /* Nor beyond where the channel leaves the volume: every skipped channel sample is
             * one that would have been taken (no "outside: no sample" among them). */
            if (!channels[k].identity) {
              const float3 box = (float3)(f.volume[0], f.volume[1], f.volume[2]);
              target = min(target, OctoFirstSegmentBeyond(e, inv_w, e_abs, (float3)(0.0f), box,
                                                          band_start, band_end, inv_dt, band_n));
            }
          }
          if (target > j) {
            /* Skipped resident bricks still count as used (eviction order). */
            for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
              if (ch_fresh[k] && OctoNodeInBuffer(ch_hit[k].word0)) {
                OctoMarkSlotCounted(slot_used, ch_hit[k].slot, frame, counters);
              }
            }
            skipped += (target - j) * (uint)OCTO_ACTIVE_N;
            i = band_base + target;
            continue;
          }
        }
        /* Transformed runs: while every channel's hit is its wanted node, resident at the
         * sample's level, full segments go eight or four at a time (OctoTransformStepN, which
         * tests each lane as this path does), up to where the first channel's transformed line
         * leaves its box (an estimate: the steps' tests decide) or the band's last segment. */
        bool run = true;
        uint run_end = band_n - 1u;
        const float scale = ldexp(1.0f, level);
        for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
          run = ch_in[k];
          if (!run) break;
          const OctoNodeHit hit = ch_hit[k];
          run = OctoNodeInBuffer(hit.word0) && hit.node == hit.wanted && hit.level == level;
          if (!run) break;
          float3 e = entry;
          float3 w = u;
          if (!channels[k].identity) {
            e = OctoTransformPoint(channels[k].transform, entry);
            w = OctoTransformDirection(channels[k].transform, u);
          }
          run_end = min(run_end, OctoFirstSegmentBeyond(
                                     e, 1.0f / w, fmax(fabs(e.x), fmax(fabs(e.y), fabs(e.z))),
                                     ch_lo[k] * scale, ch_hi[k] * scale, band_start, band_end,
                                     inv_dt, band_n));
        }
        if (run && run_end >= j + 4u) {
          /* The first use of a fast hit needs nothing of OctoResolveSource but the stamp. */
          __global const uint* ch_cells[OCTO_STATE_CHANNELS];
          for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
            if (ch_fresh[k]) OctoMarkSlotCounted(slot_used, ch_hit[k].slot, frame, counters);
            ch_cells[k] =
                cell_ranges + (ulong)ch_hit[k].slot * OctoCellWords(g) + OctoCellOffset(g);
          }
          const float level_down = ldexp(1.0f, -level);
          uint jj = j;
          uint taken = 1u;
          bool ended = false;
#if OCTO_RUN_LANES >= 8
          for (; jj + 8u <= run_end && taken > 0u && !ended; jj += taken) {
            const float8 lanes = (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
            const float8 arc8 = (band_start + ((float)jj + lanes) * dt) + 0.5f * dt;
            ended = OctoTransformStep8(f, g, channels, lut, ch_brick, ch_cells, arc8, entry, u,
                                       level_down, valid_hi, ch_lo, ch_hi, ch_origin, band_ratio,
                                       &acc, extreme, &samples, &skipped, &taken);
          }
          taken = 1u;
#endif
          for (; jj + 4u <= run_end && taken > 0u && !ended; jj += taken) {
            const float4 arc4 =
                (band_start + ((float)jj + (float4)(0.0f, 1.0f, 2.0f, 3.0f)) * dt) + 0.5f * dt;
            ended = OctoTransformStep4(f, g, channels, lut, ch_brick, ch_cells, arc4, entry, u,
                                       level_down, valid_hi, ch_lo, ch_hi, ch_origin, band_ratio,
                                       &acc, extreme, &samples, &skipped, &taken);
          }
          if (ended) break;
          if (jj > j) {
            i = band_base + jj;
            continue;
          }
        }
      }

#if OCTO_REFINE
      /* Refinement samples only the wanted level: a missing brick pauses the ray here. */
      bool missing = false;
      for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
        OctoNodeHit hit;
        if (OCTO_ALL_IDENTITY) {
          if (k > 0) break;
          hit = shared_hit;
        } else {
          if (!ch_in[k]) continue;
          hit = ch_hit[k];
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
      const OctoRatio ratio = OctoOpacityRatio(seg / vpu * f.inv_reference);
#endif
      /* All channels at one position read one source: resolve it once. */
      OctoSource shared_src;
      if (OCTO_ALL_IDENTITY) {
        if (!fresh && fast) {
          /* Brick-local marching: the same brick, addressed from the level position. */
          shared_src.brick = shared_brick;
          shared_src.from_brick = true;
          shared_src.average_node = shared_hit.node;
          shared_src.tri = OctoTrilinearLocal(g, level_pos + 0.5f - brick_origin);
        } else {
          shared_src = OctoResolveSource(shared_brick, g, shared_hit, shared_q, level, fresh,
                                         request_flags, request_list, request_capacity,
                                         slot_used, frame, counters);
        }
      }
      for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
        OctoSource src;
        if (OCTO_ALL_IDENTITY) {
          src = shared_src;
        } else {
          if (!ch_in[k]) continue;
          src = OctoResolveSource(ch_brick[k], g, ch_hit[k], ch_q[k], level, ch_fresh[k],
                                  request_flags, request_list, request_capacity, slot_used, frame,
                                  counters);
        }
        const float v = OctoSourceRead(nodes, g, src, OCTO_CHANNEL_OF(k));
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
      if (skippable && f.skip_empty && OCTO_ALL_IDENTITY && !OctoNodeHasBrick(shared_hit.word0) &&
          OctoNodeChildGroup(shared_hit.word0) == 0u && shared_hit.node == shared_hit.wanted) {
        const float3 size = convert_float3(OctoBrickSize(g)) * ldexp(1.0f, shared_hit.level);
        const float3 lo = convert_float3(shared_hit.index.xyz) * size;
        const uint target = OctoFirstSegmentBeyond(entry, inv_u, entry_abs, lo, lo + size,
                                                   band_start, band_end, inv_dt, band_n);
        if (target > next) {
          skipped += (target - next) * (uint)OCTO_ACTIVE_N;
          next = target;
        }
      }
      i = band_base + next;
    }
  }
  OctoAddSamples(counters, samples);
  OctoAddCount64(counters, OCTO_COUNTER_SKIPPED_LO, skipped);
#if OCTO_REFINE
  if (paused) {
    /* The tile goes on the next sweep's list once per pass (the first ray of the pass to pause
     * adds it; stamps are octree frames, new every pass). The host appends a sweep's slices one
     * after another (the counter starts where the last slice ended) and re-runs a slice from
     * the same counter, so each tile is listed once. */
    if (atomic_xchg(&tile_stamp[tile], frame) != frame) {
      tiles_out[atomic_inc(&counters[OCTO_COUNTER_NEXT_TILES])] = tile;
    }
    ray_next[pixel] = i;
#if OCTO_MODE == OCTO_MODE_DVR
    ray_acc[pixel] = acc;
#else
    for (int k = 0; k < OCTO_ACTIVE_N; ++k) {
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
