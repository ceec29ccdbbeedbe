// VoxelReader: reads the full-resolution (level-0) voxels back out of an octree, as it represents
// them now — a level-0 brick's interior where one exists; the value of the deepest existing
// node's brick (sampled at the voxel's position in its level) or its uniform value where the tree
// ends above level 0 (pruned homogeneous regions, and never-written regions, which show the
// background). For a lossless tree (tolerance 0) every written voxel reads back exactly. Used
// to subtract a replaced plane from a histogram, and to count the voxels of a cache built without
// a histogram.
//
// Walks from the root through GetNode / ReadBrick only (octree.h's reader contract). While other
// threads insert, a node seen as a parent may be pruned before its children are read: that is
// reported as kUnavailable ("changed while reading"), never as wrong voxels; callers that need a
// result keep inserts out meanwhile.
//
// Thread safety: the functions are thread-safe (the octree's readers are).
#ifndef OCTOSCOPE_OCTREE_VOXEL_READER_H_
#define OCTOSCOPE_OCTREE_VOXEL_READER_H_

#include <cstdint>
#include <span>
#include <stop_token>
#include <vector>

#include "octree/brick_geometry.h"
#include "octree/octree.h"
#include "util/status.h"

namespace octoscope::octree {

// Copies channel `channel` of the level-0 box `box` into `out` (x fastest, then y, then z).
// kInvalidArgument for a bad channel, a box outside the volume or empty, or
// out.size() != box.VoxelCount().
Status ReadVoxels(const Octree& tree, int channel, const Box& box, std::span<uint16_t> out);

// Adds, for every valid level-0 voxel of the volume and every channel c, one count to
// counts[c][value]. REQUIRES: counts has one vector per channel, each of 256 entries for a
// uint8 tree and 65536 for a uint16 tree (kInvalidArgument otherwise). kCancelled (counts
// partial) when `stop` is requested meanwhile.
Status CountVoxels(const Octree& tree, std::vector<std::vector<uint64_t>>& counts,
                   std::stop_token stop = {});

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_VOXEL_READER_H_
