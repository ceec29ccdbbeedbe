// Octree loading for the subcommands that need a built octree (`build`, `render`): the value
// mapping a build derives from the data, the default RAM budget, and the three ways to get an
// octree for an INPUT:
//  1. INPUT is a cache directory (it holds a MANIFEST, or the marks of a build: see
//     dataset::IsCacheDirectory): it is opened as it is, with the scan and parameters its manifest
//     records (the scan itself is not needed); one another process is building is refused
//     (kUnavailable);
//  2. INPUT is a scan and a cache directory is given: OctreeCache reuses a complete matching
//     cache there or builds into it (durable, reused by the next run);
//  3. INPUT is a scan and no cache directory: the octree is built in RAM
//     (paging::MemoryPageStore) when its bricks fit the RAM budget, else an error asks for a
//     cache directory.
// A build's RAM budget splits as octree::SplitBuildBudget says (docs/cli.md); opening a complete
// cache gives all of it to brick pages.
//
// Thread safety: not thread-safe; used by one command thread. A LoadedOctree owns everything
// behind its octree (destroy it after every user of the octree).
#ifndef OCTOSCOPE_APP_OCTREE_LOADING_H_
#define OCTOSCOPE_APP_OCTREE_LOADING_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "dataset/histogram.h"
#include "io/open_options.h"
#include "io/volume_source.h"
#include "octree/octree.h"
#include "octree/octree_builder.h"
#include "octree/octree_cache.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "util/result.h"
#include "util/status.h"
#include "volume/value_map.h"
#include "volume/volume_info.h"

namespace octoscope::app {

// A quarter of the machine's memory, within [256, 4096] MiB: a sensible budget on a shared lab
// machine.
int64_t DefaultRamMb();

// Prints "<command>: <file>: <problem>" as one line on stderr (docs/cli.md) and returns
// kExitBadInput. The input path is added when the message does not name the file already.
int ReportBadInput(const char* command, const std::string& input, const Status& status);

// dataset::DeriveMapping with a progress bar on stderr while the statistics pass runs.
Result<octree::ValueMapping> DeriveMapping(io::VolumeSource& source, double threshold);

// One build of a source into an octree, as the commands run it.
struct BuildRun {
  octree::BuildBudget budget;
  std::filesystem::path scratch_dir;  // For layers that do not fit the staging budget.
  int threads = 0;                    // Reader threads; 0 = one per channel, at least 2.
  int64_t slab_planes = 0;            // Planes per read; 0 = from the budget.
  bool progress_bar = true;           // A progress bar on stderr.
  std::function<void(const octree::BuildProgress&)> on_progress;  // Also called, if set.
  // Counts every voxel inserted (reset to the maps first), if set: the display defaults'
  // auto-contrast, kept in the cache as histogram.bin.
  dataset::HistogramAccumulator* histogram = nullptr;
};

// Streams the whole source into `tree` (octree::BuildOctree).
Status BuildWithProgress(io::VolumeSource& source, const std::vector<volume::ValueMap>& maps,
                         octree::Octree& tree, const BuildRun& run);

struct OctreeLoadOptions {
  io::OpenOptions open;             // For a scan INPUT.
  std::filesystem::path cache_dir;  // Empty: build in RAM.
  uint64_t ram_bytes = uint64_t{1} << 30;
  octree::Vec3 brick_size{0, 0, 0};  // {0, 0, 0}: octree::AutoBrickSize of the volume.
  double threshold = 0.0;  // Homogeneity threshold (fraction of the value range); 0 = lossless.
  int threads = 0;         // Reader threads; 0 = one per channel, at least 2.
  bool progress = true;    // Progress bars on stderr while building.
};

// An octree ready for use, with what backs it.
struct LoadedOctree {
  volume::VolumeInfo info;  // The scan's (for a cache directory: as its manifest records it).
  std::vector<volume::ValueMap> value_maps;
  std::string source;  // "cache" (an existing complete cache), "built-cache", "memory".
  std::filesystem::path cache_dir;  // Empty for "memory".
  bool reused = false;              // No voxel was read: a complete cache served the request.
  // Every voxel's value counted (by this build, or histogram.bin of the cache); nullopt when a
  // reused cache holds none (built by an older version).
  std::optional<dataset::Histogram> histogram;

  octree::Octree& octree() { return cache ? cache->octree() : *memory_tree; }

  // Owners. Destruction order matters: the octree uses the page cache, which uses the store.
  std::unique_ptr<octree::OctreeCache> cache;
  std::unique_ptr<paging::MemoryPageStore> memory_store;
  std::unique_ptr<paging::PageCache> memory_pages;
  std::unique_ptr<octree::Octree> memory_tree;
};

// Opens the complete cache in `dir` (route 1). kCorrupt when it is incomplete or damaged (it is
// never rebuilt or cleared here: the scan it came from is not known to be available).
Result<std::unique_ptr<LoadedOctree>> OpenCacheDirectory(const std::filesystem::path& dir,
                                                         uint64_t ram_bytes);

// Routes 1 to 3 above for `input`. Spacing overrides in options.open apply to every route.
Result<std::unique_ptr<LoadedOctree>> LoadOctree(const std::filesystem::path& input,
                                                 const OctreeLoadOptions& options);

// Bricks of the complete tree over `info` (every non-virtual node of every level) times the
// brick size: an upper bound of the pool an in-memory build may need.
Result<uint64_t> MaxPoolBytes(const volume::VolumeInfo& info, const octree::Vec3& brick_size);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_OCTREE_LOADING_H_
