/* Slice views: one axis-aligned plane of the octree rendered with the channels' transfer
 * functions at one level of detail (server/render/slice_renderer.h is the host side and states
 * the definitions; this file only implements them).
 *
 * Per pixel (one work item): its centre p = origin + (px + 0.5) du + (py + 0.5) dv (physical µm).
 * Outside the volume box the pixel is the background. Inside, every ENABLED channel c reads the
 * volume at transform_c * p (skipped when that lands outside the box), trilinearly at `level`,
 * the position clamped to the level's valid voxel centres [0.5, LevelSize - 0.5] (level
 * coordinates), i.e. clamp-to-edge like ReferenceVolume::Sample. rgb = sum of the channels'
 * TransferFunction(WindowedValue(v)).rgb, clamped to 1; alpha 1.
 * Missing bricks (the full-frame rule of the 3-D renderer): the deepest resident node of the path
 * within two levels of the wanted one, else the wanted node's average; the wanted node is
 * requested (OctoRequestNode) and every sampled slot marked (OctoMarkSlotUsed).
 */
#include "feedback.h"
#include "octree_sampling.cl"

/* Floats per channel in the channel parameter buffer (mirrored by slice_renderer.cpp). */
#define OCTO_SLICE_CHANNEL_FLOATS 24
#define OCTO_SLICE_ENABLED 0    /* 1 = sample this channel. */
#define OCTO_SLICE_LO 1         /* level - window / 2. */
#define OCTO_SLICE_WINDOW 2     /* window (> 0). */
#define OCTO_SLICE_GAMMA 3      /* gamma (> 0). */
#define OCTO_SLICE_HAS_LUT 4    /* 1 = read the LUT instead of colour * t. */
#define OCTO_SLICE_IDENTITY 5   /* 1 = transform is the identity. */
#define OCTO_SLICE_COLOR 6      /* r, g, b. */
#define OCTO_SLICE_TRANSFORM 9  /* The top 3 rows of the affine 4x4, row-major (12 floats). */
#define OCTO_SLICE_LUT_ENTRIES 256

/* The plane and the volume box as a kernel argument: 4-byte members only, so the layout is the
 * same in C++ (slice_renderer.cpp static_asserts its size). */
typedef struct OctoSliceSetup {
  float origin[3];      /* Physical position of image-plane point (0, 0). */
  float du[3];          /* Physical step of one pixel to the right. */
  float dv[3];          /* Physical step of one pixel down (next row). */
  float box_hi[3];      /* The volume box is [0, box_hi] (faces inclusive). */
  float inv_spacing[3]; /* Level-0 voxels per µm per axis. */
  float background[4];  /* Straight RGBA of pixels outside the box. */
  int width;
  int height;
  int level; /* The level of detail sampled. */
} OctoSliceSetup;

bool OctoSliceInside(float3 p, float3 hi) {
  return all(p >= (float3)(0.0f)) && all(p <= hi);
}

/* Valid voxels per axis at `level`: ceil(size / 2^level). */
float3 OctoLevelSize(OctoTreeGeometry g, int level) {
  const int3 size = (int3)(g.volume_size[0], g.volume_size[1], g.volume_size[2]);
  return convert_float3(OctoShiftRight3(size + (1 << level) - 1, level));
}

/* p (level-0 voxel coordinates) clamped to the voxel centres of `level`, in level-0 units. */
float3 OctoClampToLevel(OctoTreeGeometry g, float3 p, int level) {
  const float scale = ldexp(1.0f, level);
  const float3 q = clamp(p / scale, 0.5f, OctoLevelSize(g, level) - 0.5f);
  return q * scale;
}

/* The channel value at level-0 position p as the slice rule defines it (see the file comment).
 * `hit` must come from OctoFindNode at p (clamped to `level`) and `level`. */
float OctoSliceSample(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS, OctoTreeGeometry g,
                      OctoNodeHit hit, float3 p, int c, __global uint* slot_used, uint frame) {
  /* Too coarse a substitute: the wanted node's own average is the better approximation. */
  if (hit.level > hit.wanted_level + 2) return OctoNodeAverage(nodes, hit.wanted, g, c);
  if (!OctoNodeInBuffer(hit.word0)) return OctoNodeAverage(nodes, hit.node, g, c);
  uint local_slot = 0;
  __global const ushort* bricks = OctoBrickAllocation(OCTO_BRICK_BUFFER_ARGS, hit.slot,
                                                      &local_slot);
  OctoMarkSlotUsed(slot_used, hit.slot, frame);
  /* Re-clamp at the level actually read, so a coarser substitute never reads virtual voxels. */
  const float3 q = OctoClampToLevel(g, p, hit.level);
  return OctoSampleBrick(bricks, g, local_slot, hit.index, hit.level, q, c);
}

__kernel void RenderSlice(__global const uint* nodes, OCTO_BRICK_BUFFER_PARAMS,
                          OctoTreeGeometry g, volatile __global uint* request_flags,
                          volatile __global uint* request_list, uint request_capacity,
                          __global uint* slot_used, uint frame, OctoSliceSetup s,
                          __global const float* channel_params, __global const float4* luts,
                          __global float4* out, volatile __global uint* sample_count) {
  const int i = (int)get_global_id(0);
  if (i >= s.width * s.height) return;
  const int px = i % s.width;
  const int py = i / s.width;
  const float3 origin = (float3)(s.origin[0], s.origin[1], s.origin[2]);
  const float3 du = (float3)(s.du[0], s.du[1], s.du[2]);
  const float3 dv = (float3)(s.dv[0], s.dv[1], s.dv[2]);
  const float3 hi = (float3)(s.box_hi[0], s.box_hi[1], s.box_hi[2]);
  const float3 inv_spacing = (float3)(s.inv_spacing[0], s.inv_spacing[1], s.inv_spacing[2]);
  const float3 p = origin + ((float)px + 0.5f) * du + ((float)py + 0.5f) * dv;
  if (!OctoSliceInside(p, hi)) {
    out[i] = (float4)(s.background[0], s.background[1], s.background[2], s.background[3]);
    return;
  }

  float3 rgb = (float3)(0.0f);
  uint samples = 0;
  /* Channels without a transform share one traversal; remember the last one. */
  bool have_hit = false;
  float3 hit_pos = (float3)(0.0f);
  OctoNodeHit hit;
  for (int c = 0; c < g.channels; ++c) {
    __global const float* cp = channel_params + c * OCTO_SLICE_CHANNEL_FLOATS;
    if (cp[OCTO_SLICE_ENABLED] == 0.0f) continue;
    float3 q = p;
    if (cp[OCTO_SLICE_IDENTITY] == 0.0f) {
      __global const float* m = cp + OCTO_SLICE_TRANSFORM;
      q = (float3)(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
                   m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                   m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]);
      /* A sample moved out of the volume contributes nothing. */
      if (!OctoSliceInside(q, hi)) continue;
    }
    /* Level-0 voxel coordinates, clamped to the wanted level's voxel centres. */
    const float3 v = OctoClampToLevel(g, q * inv_spacing, s.level);
    if (!have_hit || any(v != hit_pos)) {
      hit = OctoFindNode(nodes, g, v, s.level);
      hit_pos = v;
      have_hit = true;
      if (hit.node != hit.wanted || (OctoNodeHasBrick(hit.word0) && !OctoNodeInBuffer(hit.word0))) {
        OctoRequestNode(request_flags, request_list, request_capacity, hit.wanted, frame);
      }
    }
    const float value =
        OctoSliceSample(nodes, OCTO_BRICK_BUFFER_ARGS, g, hit, v, c, slot_used, frame);
    ++samples;

    /* WindowedValue and TransferFunction of render_params.h. */
    float t = clamp((value - cp[OCTO_SLICE_LO]) / cp[OCTO_SLICE_WINDOW], 0.0f, 1.0f);
    if (cp[OCTO_SLICE_GAMMA] != 1.0f) t = pow(t, cp[OCTO_SLICE_GAMMA]);
    if (cp[OCTO_SLICE_HAS_LUT] != 0.0f) {
      const float x = t * (float)(OCTO_SLICE_LUT_ENTRIES - 1);
      const int i0 = min((int)x, OCTO_SLICE_LUT_ENTRIES - 1);
      const int i1 = min(i0 + 1, OCTO_SLICE_LUT_ENTRIES - 1);
      __global const float4* lut = luts + c * OCTO_SLICE_LUT_ENTRIES;
      rgb += mix(lut[i0], lut[i1], x - (float)i0).xyz;
    } else {
      rgb += (float3)(cp[OCTO_SLICE_COLOR], cp[OCTO_SLICE_COLOR + 1], cp[OCTO_SLICE_COLOR + 2]) *
             t;
    }
  }
  if (samples > 0u) atomic_add(sample_count, samples);
  out[i] = (float4)(min(rgb, 1.0f), 1.0f);
}
