/* Octree traversal and brick sampling on the device: the building blocks of the ray caster.
 * Library code (no kernels); programs #include it (ProgramCache resolves includes from the
 * embedded kernels/ files).
 *
 * Coordinates: positions are continuous LEVEL-0 voxel coordinates; voxel v covers [v, v + 1) and
 * its sample sits at its centre v + 0.5. A level-L voxel j covers level-0 [j * 2^L, (j + 1) * 2^L),
 * so a position p has level-L coordinate q = p / 2^L and lies in level-L voxel floor(q); the node
 * of level L containing it has index floor(q) / bs (brick_geometry.h).
 *
 * Traversal (OctoFindNode): from the root, descend towards the node of the requested level that
 * contains p, following child groups, and stop early where a node has no children (pruned or not
 * yet built: its data represent the whole region). The result is the DEEPEST node of that path
 * that can be rendered — its brick is resident (in_buffer), or it has no brick (homogeneous or
 * virtual: its averages are its data). A node whose brick exists but is not resident is skipped
 * (an ancestor's data are used; its children may still be resident and are used when deeper).
 * When nothing on the path is renderable, the root's averages are used. `wanted` is the deepest
 * node of the path whatever its residency: the node a caller would like to have resident.
 *
 * Sampling (OctoSample): trilinear interpolation between the 8 level-L voxel centres around p,
 * read from the node's stored brick; p inside the node's interior always keeps the 2x2x2
 * footprint inside the stored box thanks to the one-voxel apron (no neighbour brick is read).
 * A node without a resident brick gives its channel average.
 */
#ifndef OCTOSCOPE_KERNELS_OCTREE_SAMPLING_CL_
#define OCTOSCOPE_KERNELS_OCTREE_SAMPLING_CL_

#include "node_format.h"

typedef struct OctoNodeHit {
  ulong node;       /* The node whose data represent p (see the file comment). */
  ulong wanted;     /* The deepest node of the path, resident or not. */
  int4 index;       /* `node`'s index in bricks per axis at its level (w unused). */
  int level;        /* `node`'s level. */
  int wanted_level; /* `wanted`'s level. */
  uint word0;       /* `node`'s word 0. */
  uint slot;        /* `node`'s brick slot; 0 unless in_buffer. */
} OctoNodeHit;

/* The index (in bricks) of the level-`level` node containing p; p is clamped into the node grid
 * [0, bs * 2^(R - level)) of level-`level` voxels, so any position gives a valid node. */
int4 OctoNodeIndex(float3 p, int level, OctoTreeGeometry g) {
  const int3 bs = OctoBrickSize(g);
  const int3 last = bs * (1 << (g.root_level - level)) - 1;
  /* Scaling by a power of two is exact in floating point. */
  const int3 voxel = clamp(convert_int3_sat_rtn(p * ldexp(1.0f, -level)), (int3)(0), last);
  const int3 index = voxel / bs;
  return (int4)(index, 0);
}

OctoNodeHit OctoFindNode(__global const uint* nodes, OctoTreeGeometry g, float3 p, int level) {
  const int target = clamp(level, 0, g.root_level);
  ulong node = 0;
  int l = g.root_level;
  uint word0 = OctoNodeWord(nodes, 0, g, 0);
  OctoNodeHit hit;
  hit.node = 0;
  hit.index = (int4)(0);
  hit.level = l;
  hit.word0 = word0;
  /* The path's node indices are the target level's shifted right: floor(floor(v / bs) / 2^k) =
   * floor(v / (bs 2^k)), clamping included, so one integer division per axis serves every
   * level. */
  const int4 target_index = OctoNodeIndex(p, target, g);
  while (l > target) {
    const uint group = OctoNodeChildGroup(word0);
    if (group == 0u) break; /* A leaf of the current tree: its data cover the whole region. */
    const int4 child = (int4)(OctoShiftRight3(target_index.xyz, l - 1 - target), 0);
    const uint octant = (uint)((child.x & 1) * OCTO_OCTANT_X + (child.y & 1) * OCTO_OCTANT_Y +
                               (child.z & 1) * OCTO_OCTANT_Z);
    node = OctoChildNode(group, octant);
    --l;
    word0 = OctoNodeWord(nodes, node, g, 0);
    if (OctoNodeInBuffer(word0) || !OctoNodeHasBrick(word0)) {
      hit.node = node;
      hit.index = child;
      hit.level = l;
      hit.word0 = word0;
    }
  }
  hit.wanted = node;
  hit.wanted_level = l;
  hit.slot = OctoNodeInBuffer(hit.word0) ? OctoNodeWord(nodes, hit.node, g, OCTO_NODE_SLOT_WORD) : 0u;
  return hit;
}

/* The channel-independent part of a trilinear brick read: the offset of the lower corner voxel
 * (channel 0) in the stored brick, the strides and the weights. */
typedef struct OctoTrilinear {
  uint o;
  uint dx;
  uint dy;
  uint dz;
  float3 f;
} OctoTrilinear;

/* The trilinear footprint of p in the stored brick of the level-`level` node `index`. 32-bit
 * offsets inside the brick: a stored brick holds at most 258^3 * 64 < 2^32 samples.
 * REQUIRES: p inside that node's interior (then the footprint lies in the stored box). */
OctoTrilinear OctoTrilinearLocal(OctoTreeGeometry g, float3 brick_pos);
OctoTrilinear OctoTrilinearAt(OctoTreeGeometry g, int4 index, int level, float3 p) {
  const int3 bs = OctoBrickSize(g);
  /* Brick-local coordinates of p in units of level voxels, relative to the stored box's corner
   * (interior origin - 1) and shifted by half a voxel, so the voxel centres are integers. */
  return OctoTrilinearLocal(g, p * ldexp(1.0f, -level) + 0.5f - convert_float3(index.xyz * bs));
}

/* The offsets between neighbouring stored voxels of a brick along x, y, z (channels interleaved,
 * x fastest: (bs + 2) stored voxels per axis). */
uint3 OctoBrickStrides(OctoTreeGeometry g) {
  const int3 bs = OctoBrickSize(g);
  const uint channels = (uint)OctoStoredChannels(g);
  const uint sx = (uint)(bs.x + 2);
  const uint sy = (uint)(bs.y + 2);
  return (uint3)(channels, sx * channels, sx * sy * channels);
}

/* The same from brick-local coordinates (as OctoTrilinearAt computes them). */
OctoTrilinear OctoTrilinearLocal(OctoTreeGeometry g, float3 brick_pos) {
  const int3 bs = OctoBrickSize(g);
  const float3 floor_local = floor(brick_pos);
  const int3 i0 = clamp(convert_int3(floor_local), (int3)(0), bs);
  OctoTrilinear t;
  t.f = clamp(brick_pos - floor_local, 0.0f, 1.0f);
  const uint3 d = OctoBrickStrides(g);
  t.dx = d.x;
  t.dy = d.y;
  t.dz = d.z;
  t.o = (uint)i0.x * d.x + (uint)i0.y * d.y + (uint)i0.z * d.z;
  return t;
}

/* N trilinear footprints at once (lane by lane OctoTrilinearLocal's) and channel c of their
 * reads (lane by lane OctoTrilinearRead's), for the runs' N-sample steps (N = 4, 8: a step of 8
 * fills AVX's 256-bit registers, one of 4 takes a stretch's remainder). OpenCL C has no
 * templates: OCTO_DEFINE_TRILINEAR_N writes the family once per width. Forced inline: PoCL
 * otherwise kept them as calls with the footprint passed through the stack (12 % of a DVR frame;
 * inlined, steady frames 7-9 % faster). */
#define OCTO_GATHER_4(brick, o, d)                                                                 \
  (float4)((float)(brick)[(o).s0 + (d)], (float)(brick)[(o).s1 + (d)],                             \
           (float)(brick)[(o).s2 + (d)], (float)(brick)[(o).s3 + (d)])
#define OCTO_GATHER_8(brick, o, d)                                                                 \
  (float8)(OCTO_GATHER_4(brick, (o).lo, d), OCTO_GATHER_4(brick, (o).hi, d))
#define OCTO_DEFINE_TRILINEAR_N(N)                                                                 \
  typedef struct OctoTrilinear##N {                                                                \
    uint##N o;                                                                                     \
    uint dx;                                                                                       \
    uint dy;                                                                                       \
    uint dz;                                                                                       \
    float##N fx;                                                                                   \
    float##N fy;                                                                                   \
    float##N fz;                                                                                   \
  } OctoTrilinear##N;                                                                              \
  __attribute__((always_inline)) OctoTrilinear##N OctoTrilinearLocal##N(                           \
      OctoTreeGeometry g, float##N bx, float##N by, float##N bz) {                                 \
    const int3 bs = OctoBrickSize(g);                                                              \
    const float##N lx = floor(bx);                                                                 \
    const float##N ly = floor(by);                                                                 \
    const float##N lz = floor(bz);                                                                 \
    const int##N ix = clamp(convert_int##N(lx), 0, bs.x);                                          \
    const int##N iy = clamp(convert_int##N(ly), 0, bs.y);                                          \
    const int##N iz = clamp(convert_int##N(lz), 0, bs.z);                                          \
    OctoTrilinear##N t;                                                                            \
    t.fx = clamp(bx - lx, 0.0f, 1.0f);                                                             \
    t.fy = clamp(by - ly, 0.0f, 1.0f);                                                             \
    t.fz = clamp(bz - lz, 0.0f, 1.0f);                                                             \
    const uint3 d = OctoBrickStrides(g);                                                           \
    t.dx = d.x;                                                                                    \
    t.dy = d.y;                                                                                    \
    t.dz = d.z;                                                                                    \
    t.o = convert_uint##N(ix) * d.x + convert_uint##N(iy) * d.y + convert_uint##N(iz) * d.z;       \
    return t;                                                                                      \
  }                                                                                                \
  __attribute__((always_inline)) float##N OctoTrilinearRead##N(__global const ushort* brick,       \
                                                               OctoTrilinear##N t, int c) {        \
    const uint##N o = t.o + (uint)c;                                                               \
    const float##N v000 = OCTO_GATHER_##N(brick, o, 0u);                                           \
    const float##N v100 = OCTO_GATHER_##N(brick, o, t.dx);                                         \
    const float##N v010 = OCTO_GATHER_##N(brick, o, t.dy);                                         \
    const float##N v110 = OCTO_GATHER_##N(brick, o, t.dy + t.dx);                                  \
    const float##N v001 = OCTO_GATHER_##N(brick, o, t.dz);                                         \
    const float##N v101 = OCTO_GATHER_##N(brick, o, t.dz + t.dx);                                  \
    const float##N v011 = OCTO_GATHER_##N(brick, o, t.dz + t.dy);                                  \
    const float##N v111 = OCTO_GATHER_##N(brick, o, t.dz + t.dy + t.dx);                           \
    const float##N v00 = mix(v000, v100, t.fx);                                                    \
    const float##N v10 = mix(v010, v110, t.fx);                                                    \
    const float##N v01 = mix(v001, v101, t.fx);                                                    \
    const float##N v11 = mix(v011, v111, t.fx);                                                    \
    return mix(mix(v00, v10, t.fy), mix(v01, v11, t.fy), t.fz);                                    \
  }
OCTO_DEFINE_TRILINEAR_N(4)
OCTO_DEFINE_TRILINEAR_N(8)

/* Channel c of the trilinear read `t` from the stored brick starting at `brick`. */
float OctoTrilinearRead(__global const ushort* brick, OctoTrilinear t, int c) {
  const uint o = t.o + (uint)c;
  const float v000 = (float)brick[o];
  const float v100 = (float)brick[o + t.dx];
  const float v010 = (float)brick[o + t.dy];
  const float v110 = (float)brick[o + t.dy + t.dx];
  const float v001 = (float)brick[o + t.dz];
  const float v101 = (float)brick[o + t.dz + t.dx];
  const float v011 = (float)brick[o + t.dz + t.dy];
  const float v111 = (float)brick[o + t.dz + t.dy + t.dx];
  const float v00 = mix(v000, v100, t.f.x);
  const float v10 = mix(v010, v110, t.f.x);
  const float v01 = mix(v001, v101, t.f.x);
  const float v11 = mix(v011, v111, t.f.x);
  return mix(mix(v00, v10, t.f.y), mix(v01, v11, t.f.y), t.f.z);
}

/* Trilinear sample of channel c at p from the stored brick starting at `brick` (its first sample)
 * of the level-`level` node `index`. REQUIRES: as OctoTrilinearAt. */
float OctoSampleBrickAt(__global const ushort* brick, OctoTreeGeometry g, int4 index, int level,
                        float3 p, int c) {
  return OctoTrilinearRead(brick, OctoTrilinearAt(g, index, level, p), c);
}

/* Trilinear sample of channel c at p from the stored brick in `slot` of the level-`level` node
 * `index` (64-bit slot offset: a buffer may hold more than 2^32 samples). REQUIRES: as
 * OctoSampleBrickAt. */
float OctoSampleBrick(__global const ushort* bricks, OctoTreeGeometry g, uint slot, int4 index,
                      int level, float3 p, int c) {
  return OctoSampleBrickAt(bricks + (ulong)slot * OctoBrickSamples(g), g, index, level, p, c);
}

/* Channel c at p as represented by `hit` (from OctoFindNode for the same p). */
float OctoSample(__global const uint* nodes, __global const ushort* bricks, OctoTreeGeometry g,
                 OctoNodeHit hit, float3 p, int c) {
  if (OctoNodeInBuffer(hit.word0)) {
    return OctoSampleBrick(bricks, g, hit.slot, hit.index, hit.level, p, c);
  }
  return OctoNodeAverage(nodes, hit.node, g, c);
}

#endif /* OCTOSCOPE_KERNELS_OCTREE_SAMPLING_CL_ */
