#include "app/octree_loading.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <optional>
#include <system_error>

#include "app/commands.h"
#include "dataset/cache_setup.h"
#include "io/open_volume.h"
#include "io/volume_stats.h"
#include "octree/brick_geometry.h"
#include "octree/octree_builder.h"
#include "util/checked_math.h"
#include "util/file_reading.h"
#include "util/progress.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

void ApplySpacingOverrides(const io::OpenOptions& open, volume::VolumeInfo& info) {
  for (int a = 0; a < 3; ++a) {
    if (open.spacing_um[a]) info.spacing_um[a] = open.spacing_um[a];
  }
}

}  // namespace

Status BuildWithProgress(io::VolumeSource& source, const std::vector<volume::ValueMap>& maps,
                         octree::Octree& tree, const BuildRun& run) {
  const volume::VolumeInfo& info = source.info();
  std::optional<ProgressBar> bar;
  if (run.progress_bar) {
    bar.emplace(stderr, "planes", static_cast<uint64_t>(info.size[2]) * info.channel_count(),
                static_cast<double>(source.SlabBytes(1)));
  }
  octree::BuildOptions build;
  build.threads = run.threads;
  build.slab_budget_bytes = run.budget.slab_bytes;
  build.staging_bytes = run.budget.staging_bytes;
  build.scratch_dir = run.scratch_dir;
  build.slab_planes = run.slab_planes;
  if (run.histogram != nullptr) {
    run.histogram->Reset(maps);
    build.on_slab = [histogram = run.histogram](int channel, int64_t, int64_t,
                                                std::span<const std::byte> stored) {
      histogram->Add(channel, stored);
    };
  }
  build.progress = [&](const octree::BuildProgress& p) {
    if (bar) bar->Update(p.planes_done);
    if (run.on_progress) run.on_progress(p);
  };
  Status built = octree::BuildOctree(source, maps, tree, build);
  if (bar) bar->Finish();
  return built;
}

int64_t DefaultRamMb() {
  const int64_t pages = sysconf(_SC_PHYS_PAGES), page_size = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page_size <= 0) return 1024;
  return std::clamp<int64_t>(pages * page_size / 4 / (1 << 20), 256, 4096);
}

int ReportBadInput(const char* command, const std::string& input, const Status& status) {
  const bool names_file =
      !input.empty() &&
      status.message().find(fs::path(input).filename().string()) != std::string::npos;
  std::string line =
      names_file || input.empty() ? status.ToString() : status.WithContext(input).ToString();
  // A message must stay one line even when a file name or library text holds a newline.
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  std::fprintf(stderr, "%s: %s\n", command, line.c_str());
  return kExitBadInput;
}

Result<octree::ValueMapping> DeriveMapping(io::VolumeSource& source, double threshold) {
  const volume::VolumeInfo& info = source.info();
  std::optional<ProgressBar> bar;
  auto progress = [&](uint64_t done, uint64_t) {
    if (!bar) {
      bar.emplace(stderr, "planes (value range)",
                  static_cast<uint64_t>(info.size[2]) * info.channel_count(),
                  static_cast<double>(source.SlabBytes(1)));
    }
    bar->Update(done);
  };
  auto mapping = dataset::DeriveMapping(source, threshold, progress);
  if (bar) bar->Finish();
  return mapping;
}

Result<std::unique_ptr<LoadedOctree>> OpenCacheDirectory(const fs::path& dir, uint64_t ram_bytes) {
  OCTO_ASSIGN_OR_RETURN(dataset::OpenedCache opened, dataset::OpenCompleteCache(dir, ram_bytes));
  auto loaded = std::make_unique<LoadedOctree>();
  loaded->info = opened.manifest.params.info;
  loaded->value_maps = opened.cache->mapping().value_maps;
  loaded->source = "cache";
  loaded->cache_dir = dir;
  loaded->reused = true;
  loaded->cache = std::move(opened.cache);
  auto histogram = dataset::ReadHistogramFile(dir, loaded->cache->source(), loaded->value_maps);
  if (histogram.ok()) loaded->histogram = std::move(*histogram);
  return loaded;
}

Result<uint64_t> MaxPoolBytes(const volume::VolumeInfo& info, const octree::Vec3& brick_size) {
  const volume::DataType stored = volume::StoredTypeFor(info.dtype);
  OCTO_ASSIGN_OR_RETURN(
      octree::BrickGeometry geometry,
      octree::BrickGeometry::Create({octree::Vec3{info.size[0], info.size[1], info.size[2]},
                                     brick_size, info.channel_count(),
                                     static_cast<int>(volume::BytesPerSample(stored))}));
  uint64_t bricks = 0;
  for (int level = 0; level <= geometry.root_level(); ++level) {
    const octree::Box nodes = geometry.NonVirtualNodes(level);
    bricks += static_cast<uint64_t>(nodes.Extent(0)) * nodes.Extent(1) * nodes.Extent(2);
  }
  auto bytes = CheckedMul(bricks, geometry.brick_bytes());
  if (!bytes) return ResourceExhaustedError("the octree's size overflows");
  return *bytes;
}

Result<std::unique_ptr<LoadedOctree>> LoadOctree(const fs::path& input,
                                                 const OctreeLoadOptions& options) {
  // Route 1: a cache directory.
  if (dataset::IsCacheDirectory(input)) {
    OCTO_ASSIGN_OR_RETURN(auto loaded, OpenCacheDirectory(input, options.ram_bytes));
    ApplySpacingOverrides(options.open, loaded->info);
    return loaded;
  }
  OCTO_ASSIGN_OR_RETURN(auto source, io::OpenVolume(input, options.open));
  const volume::VolumeInfo& info = source->info();
  auto loaded = std::make_unique<LoadedOctree>();
  loaded->info = info;

  // Route 2: build into (or reuse) a cache directory.
  if (!options.cache_dir.empty()) {
    OCTO_ASSIGN_OR_RETURN(octree::SourceIdentity identity, octree::ComputeSourceIdentity(input));
    octree::CacheParams params;
    params.info = info;
    params.brick_size = dataset::BrickSizeFor(info, options.brick_size);
    params.threshold = options.threshold;
    const octree::BuildBudget budget =
        dataset::BuildBudgetFor(info, params.brick_size, options.ram_bytes);
    OCTO_ASSIGN_OR_RETURN(
        loaded->cache,
        octree::OctreeCache::Open(options.cache_dir, identity, params, budget.page_bytes,
                                  [&] { return DeriveMapping(*source, options.threshold); }));
    loaded->value_maps = loaded->cache->mapping().value_maps;
    loaded->cache_dir = options.cache_dir;
    loaded->reused = loaded->cache->reused();
    loaded->source = loaded->reused ? "cache" : "built-cache";
    if (!loaded->reused) {
      dataset::HistogramAccumulator histogram;
      BuildRun run;
      run.budget = budget;
      run.scratch_dir = options.cache_dir;
      run.threads = options.threads;
      run.progress_bar = options.progress;
      run.histogram = &histogram;
      OCTO_RETURN_IF_ERROR(
          BuildWithProgress(*source, loaded->value_maps, loaded->cache->octree(), run));
      loaded->histogram = histogram.Snapshot();
      // Written before the commit: a committed cache always has its histogram.
      OCTO_RETURN_IF_ERROR(
          dataset::WriteHistogramFile(options.cache_dir, *loaded->histogram, identity));
      OCTO_RETURN_IF_ERROR(loaded->cache->Commit());
    } else {
      auto histogram = dataset::ReadHistogramFile(options.cache_dir, identity, loaded->value_maps);
      if (histogram.ok()) loaded->histogram = std::move(*histogram);
    }
    return loaded;
  }

  // Route 3: in RAM, when the bricks fit the page budget.
  const octree::Vec3 brick_size = dataset::BrickSizeFor(info, options.brick_size);
  OCTO_ASSIGN_OR_RETURN(uint64_t pool_bytes, MaxPoolBytes(info, brick_size));
  const octree::BuildBudget budget = dataset::BuildBudgetFor(info, brick_size, options.ram_bytes);
  const uint64_t page_budget = budget.page_bytes;
  if (pool_bytes > page_budget) {
    return ResourceExhaustedError(
        "the octree needs up to " + std::to_string(pool_bytes >> 20) +
        " MiB of bricks, more than the RAM budget's " + std::to_string(page_budget >> 20) +
        " MiB for pages; build it into a cache directory with --cache DIR (or raise --ram-mb)");
  }
  OCTO_ASSIGN_OR_RETURN(octree::ValueMapping mapping, DeriveMapping(*source, options.threshold));
  octree::OctreeOptions tree_options;
  tree_options.brick_size = brick_size;
  tree_options.homogeneity_threshold = options.threshold;
  tree_options.value_range = mapping.value_range;
  const volume::DataType stored = volume::StoredTypeFor(info.dtype);
  tree_options.bytes_per_sample = static_cast<int>(volume::BytesPerSample(stored));
  OCTO_ASSIGN_OR_RETURN(octree::BrickGeometry geometry,
                        octree::BrickGeometry::Create(
                            {octree::Vec3{info.size[0], info.size[1], info.size[2]}, brick_size,
                             info.channel_count(), tree_options.bytes_per_sample}));
  const uint64_t page_bytes = octree::OctreeCache::PageBytesFor(geometry.brick_bytes());
  loaded->memory_store = std::make_unique<paging::MemoryPageStore>(page_bytes);
  // The store holds every page in RAM already; the cache in front of it needs only a few.
  loaded->memory_pages = std::make_unique<paging::PageCache>(
      loaded->memory_store.get(), std::max(page_bytes * 2 * octree::OctreeCache::kMinPages,
                                           std::min<uint64_t>(page_budget / 4, pool_bytes)));
  OCTO_ASSIGN_OR_RETURN(loaded->memory_tree,
                        octree::Octree::Create(geometry, tree_options, loaded->memory_pages.get()));
  loaded->value_maps = mapping.value_maps;
  loaded->source = "memory";
  BuildRun run;
  run.budget = budget;
  run.threads = options.threads;
  run.progress_bar = options.progress;
  std::error_code ec;
  run.scratch_dir = fs::temp_directory_path(ec);
  dataset::HistogramAccumulator histogram;
  run.histogram = &histogram;
  OCTO_RETURN_IF_ERROR(BuildWithProgress(*source, loaded->value_maps, *loaded->memory_tree, run));
  loaded->histogram = histogram.Snapshot();
  return loaded;
}

}  // namespace octoscope::app
