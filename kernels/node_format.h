/* The device layout of the octree, shared by every kernel and checked from C++: the node buffer
 * entry of docs/octree_format.md ("Device node buffer"), whose host encoder is
 * server/octree/node_encoding.h, and the tree geometry the kernels receive as an argument.
 * This is the ONE place the bit layout is written down for the device: the constants below are
 * static_assert'ed equal to node_encoding.h (server/render/node_format_check.cpp and the render
 * tests include this header from C++), the functions exist only in OpenCL C.
 *
 * Node buffer: uint32 words; node n occupies words [n * W, (n + 1) * W) with W = OCTO_NODE_WORDS(C):
 *   word 0: bit 31 in_buffer, bit 30 has_brick, bits 0..29 child group (0 = no children; the child
 *           in octant o = x | y << 1 | z << 2 is node 8 * group + o; the root is node 0);
 *   word 1: brick slot in the brick buffer (valid only with in_buffer);
 *   word 2 + k: uint16 averages of channels 2k (bits 0..15) and 2k + 1 (bits 16..31);
 *   word 2 + ceil(C / 2) + c: channel c's subtree value range, min bits 0..15, max bits 16..31.
 * Brick buffer: uint16 samples; the brick in slot s starts at sample s * OctoBrickSamples(g) and
 * holds the node's interior plus a one-voxel apron, (bs + 2) voxels per axis, channels
 * interleaved, x fastest: ((z * sy + y) * sx + x) * C + c (brick_geometry.h).
 * Cell ranges (server/render/cell_ranges.h): slot s's words start at s * OctoCellWords(g):
 * the fine cells (OCTO_FINE_CELL_SIZE^3 interior voxels), then the coarse ones
 * (OCTO_COARSE_CELL_SIZE^3); in each, cell (cx, cy, cz), x fastest, holds word (cell * C + c)
 * per channel: min bits 0..15, max bits 16..31 over the stored voxels its trilinear samples read.
 */
#ifndef OCTOSCOPE_KERNELS_NODE_FORMAT_H_
#define OCTOSCOPE_KERNELS_NODE_FORMAT_H_

#define OCTO_NODE_IN_BUFFER_BIT 0x80000000u
#define OCTO_NODE_HAS_BRICK_BIT 0x40000000u
#define OCTO_NODE_CHILD_GROUP_MASK 0x3fffffffu
#define OCTO_NODE_SLOT_WORD 1
#define OCTO_NODE_AVERAGE_WORD 2
/* Words per node for `channels` channels: 2 + ceil(channels / 2) + channels. */
#define OCTO_NODE_WORDS(channels) (2 + ((channels) + 1) / 2 + (channels))
/* The word of channel 0's value range inside an entry. */
#define OCTO_NODE_RANGE_WORD(channels) (2 + ((channels) + 1) / 2)
/* Octant bits of a child inside its parent (child index & 1 per axis). */
#define OCTO_OCTANT_X 1
#define OCTO_OCTANT_Y 2
#define OCTO_OCTANT_Z 4
#define OCTO_CHILDREN_PER_GROUP 8
/* Interior voxels per axis of the fine and the coarse cells of the cell ranges. */
#define OCTO_FINE_CELL_SIZE 8
#define OCTO_COARSE_CELL_SIZE 16
/* The cells a program walks: fine unless it defines OCTO_CELL_SIZE as OCTO_COARSE_CELL_SIZE
 * first (raycast.cl for DVR, whose inert test does not depend on the ray, so bigger cells skip
 * as much with fewer tests; MIP's and MinIP's follow the running extremum, which finer cells
 * track more closely). */
#ifndef OCTO_CELL_SIZE
#define OCTO_CELL_SIZE OCTO_FINE_CELL_SIZE
#endif
#if OCTO_CELL_SIZE != OCTO_FINE_CELL_SIZE && OCTO_CELL_SIZE != OCTO_COARSE_CELL_SIZE
#error "OCTO_CELL_SIZE must be OCTO_FINE_CELL_SIZE or OCTO_COARSE_CELL_SIZE: no other ranges exist"
#endif

/* The tree's geometry as a kernel argument (passed by value; only 32-bit ints, so the layout is
 * the same in C++ and OpenCL C: 32 bytes, no padding). Mirrors octree::BrickGeometry. */
typedef struct OctoTreeGeometry {
  int volume_size[3]; /* Level-0 voxels per axis. */
  int brick_size[3];  /* Brick interior per axis (even); stored bricks are brick_size + 2. */
  int root_level;     /* Levels 0..root_level; the root is node 0. */
  int channels;       /* C, 1..64. */
} OctoTreeGeometry;

#ifdef __OPENCL_VERSION__

/* The brick interior size and stored channel count. A program built for one tree may fix them
 * (-DOCTO_FIXED_BRICK=bx,by,bz -DOCTO_FIXED_CHANNELS=C, equal to the geometry argument): brick
 * strides and node indices then compile to constants and shifts. */
int3 OctoBrickSize(OctoTreeGeometry g) {
#ifdef OCTO_FIXED_BRICK
  (void)g;
  return (int3)(OCTO_FIXED_BRICK);
#else
  return (int3)(g.brick_size[0], g.brick_size[1], g.brick_size[2]);
#endif
}
int OctoStoredChannels(OctoTreeGeometry g) {
#ifdef OCTO_FIXED_CHANNELS
  (void)g;
  return OCTO_FIXED_CHANNELS;
#else
  return g.channels;
#endif
}

uint OctoNodeWords(OctoTreeGeometry g) { return (uint)OCTO_NODE_WORDS(OctoStoredChannels(g)); }

bool OctoNodeInBuffer(uint word0) { return (word0 & OCTO_NODE_IN_BUFFER_BIT) != 0u; }
bool OctoNodeHasBrick(uint word0) { return (word0 & OCTO_NODE_HAS_BRICK_BIT) != 0u; }
uint OctoNodeChildGroup(uint word0) { return word0 & OCTO_NODE_CHILD_GROUP_MASK; }

/* v >> s per component, as three scalar shifts. REQUIRES: 0 <= s < 32. Not `v >> s`: NVIDIA's
 * OpenCL compiler (driver 580, H200) miscompiled int vectors shifted by a varying scalar inside
 * the ray caster (every lane came out 0: each ray descended the octree into octant 0). */
int3 OctoShiftRight3(int3 v, int s) { return (int3)(v.x >> s, v.y >> s, v.z >> s); }

/* Word `word` of node `node`. 64-bit offsets: node ids reach 2^33 (30-bit groups times 8). */
uint OctoNodeWord(__global const uint* nodes, ulong node, OctoTreeGeometry g, int word) {
  return nodes[node * OctoNodeWords(g) + (ulong)word];
}

/* The child of a node with child group `group` in `octant`. */
ulong OctoChildNode(uint group, uint octant) {
  return (ulong)OCTO_CHILDREN_PER_GROUP * (ulong)group + (ulong)octant;
}

/* Channel c's average of a node (uint16, as float). */
float OctoNodeAverage(__global const uint* nodes, ulong node, OctoTreeGeometry g, int c) {
  const uint word = OctoNodeWord(nodes, node, g, OCTO_NODE_AVERAGE_WORD + c / 2);
  return (float)((word >> (16 * (c & 1))) & 0xffffu);
}

/* Channel c's subtree value range of a node: (min, max) in stored units. Every stored voxel of
 * the node and its descendants, hence every trilinear sample of their bricks that reads only
 * voxels inside the node's box, lies in it. */
uint2 OctoNodeRange(__global const uint* nodes, ulong node, OctoTreeGeometry g, int c) {
  const uint word = OctoNodeWord(nodes, node, g, OCTO_NODE_RANGE_WORD(OctoStoredChannels(g)) + c);
  return (uint2)(word & 0xffffu, word >> 16);
}

/* Samples of one stored brick: (bs + 2)^3 voxels times C channels. */
ulong OctoBrickSamples(OctoTreeGeometry g) {
  const int3 bs = OctoBrickSize(g);
  return (ulong)(bs.x + 2) * (ulong)(bs.y + 2) * (ulong)(bs.z + 2) * (ulong)OctoStoredChannels(g);
}

/* Cells of `size` per axis of a brick: ceil(bs / size). */
int3 OctoCellsPerAxisOf(OctoTreeGeometry g, int size) {
  return (OctoBrickSize(g) + size - 1) / size;
}

/* Cell range words of one slot at one cell size: cells times channels. */
ulong OctoCellWordsOf(OctoTreeGeometry g, int size) {
  const int3 n = OctoCellsPerAxisOf(g, size);
  return (ulong)n.x * (ulong)n.y * (ulong)n.z * (ulong)OctoStoredChannels(g);
}

/* The program's cells (OCTO_CELL_SIZE) per axis of a brick. */
int3 OctoCellsPerAxis(OctoTreeGeometry g) { return OctoCellsPerAxisOf(g, OCTO_CELL_SIZE); }

/* Cell range words of one slot (its stride): fine and coarse cells. */
ulong OctoCellWords(OctoTreeGeometry g) {
  return OctoCellWordsOf(g, OCTO_FINE_CELL_SIZE) + OctoCellWordsOf(g, OCTO_COARSE_CELL_SIZE);
}

/* Where the program's cells start within a slot's words. */
ulong OctoCellOffset(OctoTreeGeometry g) {
  return OCTO_CELL_SIZE == OCTO_FINE_CELL_SIZE ? 0 : OctoCellWordsOf(g, OCTO_FINE_CELL_SIZE);
}

#endif /* __OPENCL_VERSION__ */

#endif /* OCTOSCOPE_KERNELS_NODE_FORMAT_H_ */
