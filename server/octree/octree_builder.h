// OctreeBuilder: streams a VolumeSource into an Octree — the incremental construction of the paper
// driven by a file, through the same SlabIngest a live acquisition uses.
//
// Pipeline: `threads` reader threads take (z-slab, channel) work items in z-major order (files
// stored plane-interleaved are then read nearly sequentially), read the slab (decoding, often the
// bottleneck, runs in parallel), convert it to the stored type with the channel's ValueMap and
// hand it to a SlabIngest, which stages planes per brick layer and inserts each complete layer
// with all channels at once, the octree's brick writes spread over `insert_threads`. The reader
// that completes a layer inserts it, so readers never run far ahead of construction. Memory:
// reader buffers (2 slabs per thread) + the ingest's staging (RAM up to staging_bytes, then
// scratch files) + the octree's page cache; never the file.
//
// Cancellation and failures: the build stops at the first error (read, convert, insert, a
// progress callback that throws) or when `stop` is requested (kCancelled); every thread it
// started is joined before BuildOctree returns, and if no reader thread can be started the
// calling thread reads alone. A stopped build leaves the octree consistent but incomplete.
//
// Thread safety: BuildOctree is called from one thread; progress callbacks run on that thread.
#ifndef OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_
#define OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <span>
#include <stop_token>
#include <vector>

#include "io/volume_source.h"
#include "octree/octree.h"
#include "octree/slab_ingest.h"
#include "util/status.h"
#include "volume/value_map.h"

namespace octoscope::octree {

struct BuildProgress {
  uint64_t planes_done = 0;  // (z plane, channel) pairs inserted (visible in the octree).
  uint64_t planes_read = 0;  // (z plane, channel) pairs read from the source.
  uint64_t planes_total = 0;
  uint64_t source_bytes_done = 0;  // Bytes of the source's own type inserted.
};

struct BuildOptions {
  int threads = 0;  // Reader threads; 0 = one per channel, at least 2.
  // Threads writing bricks during inserts; 0 = the machine's hardware threads.
  int insert_threads = 0;
  // Bytes of source slabs (file type) in flight at most, over all reader threads.
  uint64_t slab_budget_bytes = uint64_t{64} << 20;
  // Planes per read; 0 = from the budget (SlabPlanes). 1 reproduces a live acquisition's
  // plane-by-plane delivery.
  int64_t slab_planes = 0;
  // Staging of brick layers (SlabIngest): RAM, then files in scratch_dir (empty = RAM only).
  uint64_t staging_bytes = uint64_t{512} << 20;
  std::filesystem::path scratch_dir;
  std::function<void(const BuildProgress&)> progress;  // Called on the calling thread.
  // Called on a READER thread (several at once) for every slab right after it was handed to the
  // ingest: `stored` holds planes [z0, z0 + nz) of `channel` in the stored type. Every plane of
  // every channel is passed exactly once per build (e.g. to accumulate histograms). An exception
  // it throws fails the build.
  std::function<void(int channel, int64_t z0, int64_t nz, std::span<const std::byte> stored)>
      on_slab;
  std::stop_token stop;  // Requests cancellation.
};

// How a build splits its RAM budget. Reader slabs get 1/16 (at most 64 MiB). Staging gets two
// brick layers (all channels, stored type) when they fit in half the budget, so readers fill
// the next layer while one is inserted; else one layer when it fits in a quarter; else none, and
// layers are staged in scratch files and inserted brick row by brick row (one row's buffers are
// reserved). Pages get the rest:
// the working set of construction is about one layer of leaf bricks plus a third of that for
// their parents.
struct BuildBudget {
  uint64_t slab_bytes = 0;
  uint64_t staging_bytes = 0;
  uint64_t page_bytes = 0;
  // Pages construction touches repeatedly: one layer of leaf bricks and a third of that for their
  // parents. With page_bytes below it, pages are written and read back (same tree, slower).
  uint64_t working_set_bytes = 0;
};
BuildBudget SplitBuildBudget(const volume::VolumeInfo& info, const Vec3& brick_size,
                             int bytes_per_stored_sample, uint64_t ram_bytes);

// Planes per read for `options`: the largest divisor of the brick depth whose slabs fit
// 2 * threads times into the budget; at least 1.
int64_t SlabPlanes(const volume::VolumeInfo& info, int64_t brick_depth, int threads,
                   uint64_t slab_budget_bytes);

// Inserts every voxel of `source` into `octree`. `maps` holds one ValueMap per channel (file
// type -> stored type). REQUIRES: octree's volume size and channel count match the source;
// maps.size() == channels. Returns the first error, kCancelled when stopped.
Status BuildOctree(io::VolumeSource& source, const std::vector<volume::ValueMap>& maps,
                   Octree& octree, const BuildOptions& options);

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_OCTREE_BUILDER_H_
