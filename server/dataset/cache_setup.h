// CacheSetup: what opening, reusing and building an octree cache directory needs beyond
// octree::OctreeCache — the value mapping a build derives from the data, the brick size and RAM
// split a build uses, and opening a complete cache directory as it stands (with the scan and
// parameters its MANIFEST records, without the scan). Shared by the server's datasets and the
// CLI's build/render commands.
//
// Thread safety: pure functions of their arguments (and the file system).
#ifndef OCTOSCOPE_DATASET_CACHE_SETUP_H_
#define OCTOSCOPE_DATASET_CACHE_SETUP_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>

#include "io/volume_source.h"
#include "octree/octree_builder.h"
#include "octree/octree_cache.h"
#include "util/result.h"
#include "volume/volume_info.h"

namespace octoscope::dataset {

// The value mapping a build needs: for 8/16-bit data the fixed maps, plus (when the threshold is
// a fraction of the data's range, or the type is wider) one statistics pass over the data, which
// reports (planes done, planes total) through `progress` when set.
Result<octree::ValueMapping> DeriveMapping(
    io::VolumeSource& source, double threshold,
    const std::function<void(uint64_t done, uint64_t total)>& progress = {});

// The fixed mapping of a volume of an 8/16-bit type (what a stream stores): its own maps, the
// stored type's full range. REQUIRES: BytesPerSample(info.dtype) <= 2.
octree::ValueMapping FixedMapping(const volume::VolumeInfo& info);

// `requested`, or the volume's automatic brick size (octree::AutoBrickSize) when it is {0,0,0}.
octree::Vec3 BrickSizeFor(const volume::VolumeInfo& info, const octree::Vec3& requested);

// The build budget split (octree::SplitBuildBudget) for `info` in bricks of `brick_size`.
octree::BuildBudget BuildBudgetFor(const volume::VolumeInfo& info, const octree::Vec3& brick_size,
                                   uint64_t ram_bytes);

// True when `path` is a directory holding a cache MANIFEST, or the BUILDING or LOCK file of a
// cache being built (or whose build was interrupted).
bool IsCacheDirectory(const std::filesystem::path& path);

// A complete cache opened as it stands.
struct OpenedCache {
  std::unique_ptr<octree::OctreeCache> cache;
  octree::CacheManifest manifest;
};

// Opens the complete cache in `dir` with a page cache of `ram_bytes`, sharing the directory's
// lock. kCorrupt when it is incomplete or damaged (it is never rebuilt or cleared here: the scan
// it came from is not known to be available); kFailedPrecondition when it holds the checkpoint of
// a stream that has not finished; kUnavailable while another process builds in it.
Result<OpenedCache> OpenCompleteCache(const std::filesystem::path& dir, uint64_t ram_bytes);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_CACHE_SETUP_H_
