// Histogram: per channel, how many voxels hold each STORED value — over ALL voxels inserted into
// a dataset (not a sample), accumulated while a file is built or a stream arrives and kept in
// the cache directory (histogram.bin, docs/octree_format.md "Cache directory"). 256 bins for a
// uint8 stored type, 65536 for uint16: exact for every type Octoscope stores. The channel's
// ValueMap turns stored values into the file's units for percentiles (auto-contrast) and the
// API's 256-bin view (docs/api.md).
//
// Thread safety: Histogram is a value type (not synchronised); HistogramAccumulator is
// thread-safe (one mutex; large slabs are counted outside it and merged).
#ifndef OCTOSCOPE_DATASET_HISTOGRAM_H_
#define OCTOSCOPE_DATASET_HISTOGRAM_H_

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <mutex>
#include <optional>
#include <span>
#include <stop_token>
#include <string>
#include <string_view>
#include <vector>

#include "octree/octree.h"
#include "octree/octree_cache.h"
#include "protocol/dataset_json.h"
#include "util/result.h"
#include "volume/value_map.h"

namespace octoscope::dataset {

class Histogram {
 public:
  Histogram() = default;
  // Zero counts, one channel per map; bins by the map's stored type (uint8: 256, else 65536).
  explicit Histogram(std::vector<volume::ValueMap> maps);

  int channels() const { return static_cast<int>(maps_.size()); }
  const std::vector<volume::ValueMap>& value_maps() const { return maps_; }
  // counts(c)[v]: voxels of channel c holding stored value v. REQUIRES: 0 <= c < channels().
  std::span<const uint64_t> counts(int c) const { return counts_[c]; }
  uint64_t total(int c) const { return totals_[c]; }

  // One count per sample of `stored` (the channel's stored type, native byte order); Subtract
  // removes them again (saturating at 0). REQUIRES: 0 <= c < channels(), a whole number of
  // samples.
  void Add(int c, std::span<const std::byte> stored);
  void Subtract(int c, std::span<const std::byte> stored);
  // The same for stored values given as uint16 (octree::ReadVoxels). REQUIRES: values < bins.
  void Add(int c, std::span<const uint16_t> values);
  void Subtract(int c, std::span<const uint16_t> values);
  // Adds `count` voxels of stored value `value`. REQUIRES: value < bins.
  void AddCount(int c, uint32_t value, uint64_t count);
  // Adds another histogram's counts. REQUIRES: same channels and bins.
  void Merge(const Histogram& other);

  // Smallest and largest stored value present; nullopt when the channel is empty.
  std::optional<uint32_t> MinStored(int c) const;
  std::optional<uint32_t> MaxStored(int c) const;
  // The fraction-quantile in file units: the smallest stored value v such that at least
  // ceil(fraction * total) (and at least one) counted voxels are <= v, mapped to the file's
  // units. nullopt when empty. REQUIRES: 0 <= fraction <= 1.
  std::optional<double> Percentile(int c, double fraction) const;
  // The API's view of channel c (docs/api.md): 256 equal bins of a whole number of stored values
  // each, from the smallest value present, covering the largest; min/max and the 0.1 % / 99.9 %
  // percentiles; all in file units.
  protocol::HistogramChannelDescription Describe(int c) const;

  bool operator==(const Histogram&) const = default;

 private:
  std::vector<volume::ValueMap> maps_;
  std::vector<std::vector<uint64_t>> counts_;
  std::vector<uint64_t> totals_;
};

// histogram.bin (docs/octree_format.md): the counts of the scan identified by `source`.
std::string SerializeHistogram(const Histogram& histogram, const octree::SourceIdentity& source);
// Parses histogram.bin written for `source` with channels stored as `maps` (kCorrupt for damage,
// another scan, other channels or types; every count is checked before use).
Result<Histogram> ParseHistogram(std::string_view bytes, const octree::SourceIdentity& source,
                                 const std::vector<volume::ValueMap>& maps);

inline constexpr char kHistogramFile[] = "histogram.bin";
// Writes `dir`/histogram.bin durably (temp file of this process, then rename).
Status WriteHistogramFile(const std::filesystem::path& dir, const Histogram& histogram,
                          const octree::SourceIdentity& source);
// Reads `dir`/histogram.bin: kNotFound when absent, kCorrupt when it does not describe `source`.
Result<Histogram> ReadHistogramFile(const std::filesystem::path& dir,
                                    const octree::SourceIdentity& source,
                                    const std::vector<volume::ValueMap>& maps);
// Counts every valid level-0 voxel of `tree` (octree::CountVoxels): exact for a complete
// lossless tree; with a lossy threshold, pruned bricks count as their averages. kCancelled when
// `stop` is requested meanwhile.
Result<Histogram> HistogramFromOctree(const octree::Octree& tree,
                                      const std::vector<volume::ValueMap>& maps,
                                      std::stop_token stop = {});

// A Histogram shared by threads: reader threads of a build, uploads of a stream.
class HistogramAccumulator {
 public:
  // Starts over with zero counts for `maps`.
  void Reset(std::vector<volume::ValueMap> maps);
  // Replaces the counts (a histogram loaded or computed elsewhere).
  void Assign(Histogram histogram);
  void Add(int c, std::span<const std::byte> stored);
  void Subtract(int c, std::span<const std::byte> stored);
  void Subtract(int c, std::span<const uint16_t> values);
  Histogram Snapshot() const;

 private:
  mutable std::mutex mu_;
  Histogram histogram_;  // Guarded by mu_.
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_HISTOGRAM_H_
