/* Test kernel: samples the octree at a list of positions (tests/render/octree_sampling_test.cpp
 * compares the results with a CPU computation from the octree's bricks and the source voxels).
 *
 * For position i (level-0 voxel coordinates in positions[i].xyz):
 *   out[i * C + c] = channel c sampled at the requested level (OctoFindNode + OctoSample);
 *   info[i] = (node used (low 32 bits), its level, wanted node (low 32 bits), its level).
 */
#include "octree_sampling.cl"

__kernel void SamplePoints(__global const uint* nodes, __global const ushort* bricks,
                           OctoTreeGeometry geometry, __global const float4* positions,
                           uint count, int level, __global float* out, __global uint4* info) {
  const size_t i = get_global_id(0);
  if (i >= count) return;
  const float3 p = positions[i].xyz;
  const OctoNodeHit hit = OctoFindNode(nodes, geometry, p, level);
  for (int c = 0; c < geometry.channels; ++c) {
    out[i * (size_t)geometry.channels + (size_t)c] = OctoSample(nodes, bricks, geometry, hit, p, c);
  }
  info[i] = (uint4)((uint)hit.node, (uint)hit.level, (uint)hit.wanted, (uint)hit.wanted_level);
}

/* Test kernel: decodes node entries 0..count-1 with node_format.h's accessors, for comparison
 * with the host decoder (octree::DecodeNode). Per node, 4 + C words of `out`:
 *   in_buffer, has_brick, child_group, slot (0 unless in_buffer), then the C averages. */
__kernel void DecodeNodes(__global const uint* nodes, OctoTreeGeometry geometry, uint count,
                          __global uint* out) {
  const size_t n = get_global_id(0);
  if (n >= count) return;
  const uint word0 = OctoNodeWord(nodes, n, geometry, 0);
  __global uint* o = out + n * (size_t)(4 + geometry.channels);
  o[0] = OctoNodeInBuffer(word0) ? 1u : 0u;
  o[1] = OctoNodeHasBrick(word0) ? 1u : 0u;
  o[2] = OctoNodeChildGroup(word0);
  o[3] = OctoNodeInBuffer(word0) ? OctoNodeWord(nodes, n, geometry, OCTO_NODE_SLOT_WORD) : 0u;
  for (int c = 0; c < geometry.channels; ++c) {
    o[4 + c] = (uint)OctoNodeAverage(nodes, n, geometry, c);
  }
}
