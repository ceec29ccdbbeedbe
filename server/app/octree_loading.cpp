#include "app/octree_loading.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <optional>
#include <system_error>

#include "app/commands.h"
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

// The files of a cache directory (octree/octree_cache.h).
constexpr const char* kManifestFile = "MANIFEST";
constexpr const char* kBuildingFile = "BUILDING";
constexpr const char* kLockFile = "LOCK";
constexpr uint64_t kMaxManifestBytes = uint64_t{1} << 20;

void ApplySpacingOverrides(const io::OpenOptions& open, volume::VolumeInfo& info) {
  for (int a = 0; a < 3; ++a) {
    if (open.spacing_um[a]) info.spacing_um[a] = open.spacing_um[a];
  }
}

}  // namespace

octree::Vec3 BrickSizeFor(const volume::VolumeInfo& info, const octree::Vec3& requested) {
  if (requested != octree::Vec3{0, 0, 0}) return requested;
  return octree::AutoBrickSize(octree::Vec3{info.size[0], info.size[1], info.size[2]});
}

octree::BuildBudget BuildBudgetFor(const volume::VolumeInfo& info, const octree::Vec3& brick_size,
                                   uint64_t ram_bytes) {
  const volume::DataType stored = volume::StoredTypeFor(info.dtype);
  return octree::SplitBuildBudget(info, brick_size,
                                  static_cast<int>(volume::BytesPerSample(stored)), ram_bytes);
}

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
  octree::ValueMapping mapping;
  const bool narrow = volume::BytesPerSample(info.dtype) <= 2;
  std::optional<io::VolumeStats> stats;
  if (!narrow || threshold > 0) {
    ProgressBar bar(stderr, "planes (value range)",
                    static_cast<uint64_t>(info.size[2]) * info.channel_count(),
                    static_cast<double>(source.SlabBytes(1)));
    io::StatsOptions options;
    options.progress = [&bar](uint64_t done, uint64_t) { bar.Update(done); };
    auto computed = io::ComputeVolumeStats(source, options);
    bar.Finish();
    if (!computed.ok()) return computed.status();
    stats = std::move(*computed);
  }
  for (int c = 0; c < info.channel_count(); ++c) {
    volume::ValueMap map = volume::FixedValueMap(
        info.dtype == volume::DataType::kUint8 || info.dtype == volume::DataType::kInt8 || narrow
            ? info.dtype
            : volume::DataType::kUint16);
    if (!narrow) {
      const io::ChannelStats& s = stats->channels[c];
      const double lo = s.count ? s.min : 0, hi = s.count ? s.max : 0;
      OCTO_ASSIGN_OR_RETURN(map, volume::ValueMapForRange(info.dtype, lo, hi));
    }
    uint32_t range = static_cast<uint32_t>(volume::TypeMax(map.stored_type));
    if (stats && stats->channels[c].count > 0) {
      // The channel's data range in stored units: what "5 % of the range" means.
      range = static_cast<uint32_t>(map.ToStored(stats->channels[c].max) -
                                    map.ToStored(stats->channels[c].min));
    }
    mapping.value_maps.push_back(map);
    mapping.value_range.push_back(range);
  }
  return mapping;
}

bool IsCacheDirectory(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_directory(path, ec)) return false;
  // A cache being built (or whose build was killed) has no MANIFEST yet, but its markers.
  for (const char* name : {kManifestFile, kBuildingFile, kLockFile}) {
    if (fs::is_regular_file(path / name, ec)) return true;
  }
  return false;
}

Result<std::unique_ptr<LoadedOctree>> OpenCacheDirectory(const fs::path& dir, uint64_t ram_bytes) {
  // While another process builds into the directory its MANIFEST is missing: say that, not "no
  // MANIFEST". (OctreeCache::Open below takes its own lock; this one is only the first look.)
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<octree::CacheLock> first_look,
                        octree::CacheLock::Acquire(dir, octree::CacheLock::Mode::kShared));
  std::error_code ec;
  if (!fs::exists(dir / kManifestFile, ec)) {
    return CorruptError(dir.string() +
                        ": the cache is incomplete (its build was interrupted); rebuild it from "
                        "the scan (octoscope build SCAN --cache DIR)");
  }
  OCTO_ASSIGN_OR_RETURN(std::string text, ReadSmallFile(dir / kManifestFile, kMaxManifestBytes));
  auto manifest = octree::CacheManifest::Parse(text);
  if (!manifest.ok()) {
    return CorruptError((dir / kManifestFile).string() + ": " + manifest.status().message());
  }
  // Opening with the manifest's own source and parameters reuses the cache; should it still be
  // unusable (damaged files), `derive` refuses before anything is cleared.
  auto cache = octree::OctreeCache::Open(
      dir, manifest->source, manifest->params, ram_bytes, [&dir]() -> Result<octree::ValueMapping> {
        return CorruptError(dir.string() +
                            ": the cache is incomplete or damaged; rebuild it from the scan "
                            "(octoscope build SCAN --cache DIR)");
      });
  if (!cache.ok()) return cache.status();
  auto loaded = std::make_unique<LoadedOctree>();
  loaded->info = manifest->params.info;
  loaded->value_maps = (*cache)->mapping().value_maps;
  loaded->source = "cache";
  loaded->cache_dir = dir;
  loaded->reused = true;
  loaded->cache = std::move(*cache);
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
  if (IsCacheDirectory(input)) {
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
    params.brick_size = BrickSizeFor(info, options.brick_size);
    params.threshold = options.threshold;
    const octree::BuildBudget budget = BuildBudgetFor(info, params.brick_size, options.ram_bytes);
    OCTO_ASSIGN_OR_RETURN(
        loaded->cache,
        octree::OctreeCache::Open(options.cache_dir, identity, params, budget.page_bytes,
                                  [&] { return DeriveMapping(*source, options.threshold); }));
    loaded->value_maps = loaded->cache->mapping().value_maps;
    loaded->cache_dir = options.cache_dir;
    loaded->reused = loaded->cache->reused();
    loaded->source = loaded->reused ? "cache" : "built-cache";
    if (!loaded->reused) {
      BuildRun run;
      run.budget = budget;
      run.scratch_dir = options.cache_dir;
      run.threads = options.threads;
      run.progress_bar = options.progress;
      OCTO_RETURN_IF_ERROR(
          BuildWithProgress(*source, loaded->value_maps, loaded->cache->octree(), run));
      OCTO_RETURN_IF_ERROR(loaded->cache->Commit());
    }
    return loaded;
  }

  // Route 3: in RAM, when the bricks fit the page budget.
  const octree::Vec3 brick_size = BrickSizeFor(info, options.brick_size);
  OCTO_ASSIGN_OR_RETURN(uint64_t pool_bytes, MaxPoolBytes(info, brick_size));
  const octree::BuildBudget budget = BuildBudgetFor(info, brick_size, options.ram_bytes);
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
  OCTO_RETURN_IF_ERROR(BuildWithProgress(*source, loaded->value_maps, *loaded->memory_tree, run));
  return loaded;
}

}  // namespace octoscope::app
