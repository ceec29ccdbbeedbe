// OctreeBuilder: streams a VolumeSource into an Octree, slab by slab — the incremental
// construction of the paper driven by a file (the same Octree::Insert a live acquisition calls).
//
// Pipeline: `threads` reader threads take (z-slab, channel) work items in z-major order, read the
// slab from the source (decoding, the usual bottleneck, runs in parallel — at least one thread per
// channel as in the paper) and convert it to the stored type with the channel's ValueMap; the
// calling thread inserts finished slabs into the octree. Octree::Insert serialises inserts, and
// the final structure does not depend on insertion order, so slabs are inserted as they arrive.
// At most `2 * threads` slabs exist at once: memory is bounded by the slab size, never the file.
// Slab buffers are recycled (a fresh buffer costs a page fault per 4 KiB), and when the value
// map is the identity the slab as read is inserted without a converted copy.
//
// Thread safety: Build() is called from one thread; it starts and always joins its readers.
#ifndef OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_
#define OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "io/volume_source.h"
#include "octree/octree.h"
#include "util/status.h"
#include "volume/value_map.h"

namespace octoscope::octree {

struct BuildProgress {
  uint64_t planes_done = 0;  // (z plane, channel) pairs inserted.
  uint64_t planes_total = 0;
  uint64_t source_bytes_done = 0;  // Bytes of the source's own type inserted.
};

struct BuildOptions {
  int threads = 0;  // Reader threads; 0 = one per channel, at least 2.
  // Bytes of source slabs (file type) in flight at most, over all threads; slabs are as many
  // whole planes as fit (at least one), preferably a divisor of the brick depth.
  uint64_t slab_budget_bytes = uint64_t{256} << 20;
  std::function<void(const BuildProgress&)> progress;  // Called on the calling thread.
};

// Planes per slab for `options`: the largest divisor of the brick depth (so slabs stay aligned
// to bricks) whose slabs fit 2 * threads times into the budget; at least 1.
int64_t SlabPlanes(const volume::VolumeInfo& info, int64_t brick_depth, int threads,
                   uint64_t slab_budget_bytes);

// Inserts every voxel of `source` into `octree`. `maps` holds one ValueMap per channel (file
// type -> stored type). REQUIRES: octree's volume size and channel count match the source;
// maps.size() == channels. The first error (source read, insert) stops the build and is returned.
Status BuildOctree(io::VolumeSource& source, const std::vector<volume::ValueMap>& maps,
                   Octree& octree, const BuildOptions& options);

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_
