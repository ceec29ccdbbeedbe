#include "dataset/cache_setup.h"

#include <optional>
#include <system_error>

#include "io/volume_stats.h"
#include "util/file_reading.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;

// The files of a cache directory (octree/octree_cache.h).
constexpr const char* kManifestFile = "MANIFEST";
constexpr const char* kBuildingFile = "BUILDING";
constexpr const char* kLockFile = "LOCK";
constexpr uint64_t kMaxManifestBytes = uint64_t{1} << 20;

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

Result<octree::ValueMapping> DeriveMapping(
    io::VolumeSource& source, double threshold,
    const std::function<void(uint64_t done, uint64_t total)>& progress) {
  const volume::VolumeInfo& info = source.info();
  octree::ValueMapping mapping;
  const bool narrow = volume::BytesPerSample(info.dtype) <= 2;
  std::optional<io::VolumeStats> stats;
  if (!narrow || threshold > 0) {
    io::StatsOptions options;
    options.progress = progress;
    OCTO_ASSIGN_OR_RETURN(stats, io::ComputeVolumeStats(source, options));
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

octree::ValueMapping FixedMapping(const volume::VolumeInfo& info) {
  octree::ValueMapping mapping;
  const volume::ValueMap map = volume::FixedValueMap(info.dtype);
  for (int c = 0; c < info.channel_count(); ++c) {
    mapping.value_maps.push_back(map);
    mapping.value_range.push_back(static_cast<uint32_t>(volume::TypeMax(map.stored_type)));
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

Result<OpenedCache> OpenCompleteCache(const fs::path& dir, uint64_t ram_bytes) {
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
  OpenedCache opened;
  opened.cache = std::move(*cache);
  opened.manifest = std::move(*manifest);
  return opened;
}

}  // namespace octoscope::dataset
