#include "dataset/histogram.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "octree/voxel_reader.h"
#include "util/durable_file.h"
#include "util/file_reading.h"

namespace octoscope::dataset {
namespace {

constexpr char kMagic[8] = {'O', 'C', 'T', 'O', 'H', 'I', 'S', 'T'};
constexpr uint32_t kVersion = 1;
constexpr size_t kViewBins = 256;

size_t BinsFor(const volume::ValueMap& map) {
  return map.stored_type == volume::DataType::kUint8 ? 256 : 65536;
}

// Counts the samples of `stored` into `counts` with `sign` (+1 or -1, saturating).
void Count(std::vector<uint64_t>& counts, uint64_t& total, std::span<const std::byte> stored,
           bool one_byte, bool add) {
  const size_t n = one_byte ? stored.size() : stored.size() / 2;
  for (size_t i = 0; i < n; ++i) {
    uint16_t v;
    if (one_byte) {
      v = std::to_integer<uint8_t>(stored[i]);
    } else {
      std::memcpy(&v, stored.data() + 2 * i, 2);
    }
    if (add) {
      ++counts[v];
      ++total;
    } else if (counts[v] > 0) {
      --counts[v];
      --total;
    }
  }
}

void PutU32(std::string& out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
void PutU64(std::string& out, uint64_t v) {
  for (int i = 0; i < 8; ++i) out.push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}

// A bounds-checked little-endian reader of histogram.bin.
class Reader {
 public:
  explicit Reader(std::string_view bytes) : bytes_(bytes) {}
  bool U32(uint32_t& v) { return Get(4, v); }
  bool U64(uint64_t& v) { return Get(8, v); }
  size_t offset() const { return at_; }
  size_t left() const { return bytes_.size() - at_; }

 private:
  template <typename T>
  bool Get(size_t n, T& v) {
    if (left() < n) return false;
    v = 0;
    for (size_t i = 0; i < n; ++i) {
      v |= static_cast<T>(static_cast<uint8_t>(bytes_[at_ + i])) << (8 * i);
    }
    at_ += n;
    return true;
  }
  std::string_view bytes_;
  size_t at_ = 0;
};

}  // namespace

Histogram::Histogram(std::vector<volume::ValueMap> maps) : maps_(std::move(maps)) {
  for (const volume::ValueMap& m : maps_) counts_.emplace_back(BinsFor(m), 0);
  totals_.assign(maps_.size(), 0);
}

void Histogram::Add(int c, std::span<const std::byte> stored) {
  Count(counts_[c], totals_[c], stored, counts_[c].size() == 256, true);
}

void Histogram::Subtract(int c, std::span<const std::byte> stored) {
  Count(counts_[c], totals_[c], stored, counts_[c].size() == 256, false);
}

void Histogram::Add(int c, std::span<const uint16_t> values) {
  for (uint16_t v : values) ++counts_[c][v];
  totals_[c] += values.size();
}

void Histogram::Subtract(int c, std::span<const uint16_t> values) {
  for (uint16_t v : values) {
    if (counts_[c][v] == 0) continue;
    --counts_[c][v];
    --totals_[c];
  }
}

void Histogram::AddCount(int c, uint32_t value, uint64_t count) {
  counts_[c][value] += count;
  totals_[c] += count;
}

void Histogram::Merge(const Histogram& other) {
  for (size_t c = 0; c < counts_.size(); ++c) {
    for (size_t v = 0; v < counts_[c].size(); ++v) counts_[c][v] += other.counts_[c][v];
    totals_[c] += other.totals_[c];
  }
}

std::optional<uint32_t> Histogram::MinStored(int c) const {
  const auto& h = counts_[c];
  for (size_t v = 0; v < h.size(); ++v) {
    if (h[v] != 0) return static_cast<uint32_t>(v);
  }
  return std::nullopt;
}

std::optional<uint32_t> Histogram::MaxStored(int c) const {
  const auto& h = counts_[c];
  for (size_t v = h.size(); v-- > 0;) {
    if (h[v] != 0) return static_cast<uint32_t>(v);
  }
  return std::nullopt;
}

std::optional<double> Histogram::Percentile(int c, double fraction) const {
  if (totals_[c] == 0) return std::nullopt;
  const double wanted = std::ceil(std::clamp(fraction, 0.0, 1.0) * static_cast<double>(totals_[c]));
  const uint64_t rank = std::max<uint64_t>(1, static_cast<uint64_t>(wanted));
  uint64_t seen = 0;
  const auto& h = counts_[c];
  for (size_t v = 0; v < h.size(); ++v) {
    seen += h[v];
    if (seen >= rank) return maps_[c].ToFile(static_cast<double>(v));
  }
  return maps_[c].ToFile(static_cast<double>(h.size() - 1));
}

protocol::HistogramChannelDescription Histogram::Describe(int c) const {
  protocol::HistogramChannelDescription d;
  d.bins.assign(kViewBins, 0);
  d.count = totals_[c];
  const std::optional<uint32_t> lo = MinStored(c), hi = MaxStored(c);
  if (!lo) return d;
  // Bins of a whole number of stored values each, from the smallest value present.
  const uint64_t width = std::max<uint64_t>(1, (*hi - *lo + kViewBins) / kViewBins);
  const auto& h = counts_[c];
  for (uint32_t v = *lo; v <= *hi; ++v) d.bins[(v - *lo) / width] += h[v];
  const volume::ValueMap& map = maps_[c];
  d.min = map.ToFile(*lo);
  d.max = map.ToFile(*hi);
  d.lo = map.ToFile(*lo);
  d.hi = map.ToFile(static_cast<double>(*lo) + static_cast<double>(width * kViewBins));
  d.p001 = *Percentile(c, 0.001);
  d.p999 = *Percentile(c, 0.999);
  return d;
}

std::string SerializeHistogram(const Histogram& histogram, const octree::SourceIdentity& source) {
  std::string out(kMagic, sizeof kMagic);
  PutU32(out, kVersion);
  PutU64(out, source.hash);
  PutU64(out, source.file_bytes);
  PutU32(out, static_cast<uint32_t>(histogram.channels()));
  for (int c = 0; c < histogram.channels(); ++c) {
    const std::span<const uint64_t> h = histogram.counts(c);
    PutU32(out, static_cast<uint32_t>(h.size()));
    const uint32_t nonzero =
        static_cast<uint32_t>(std::count_if(h.begin(), h.end(), [](uint64_t n) { return n; }));
    PutU32(out, nonzero);
    for (size_t v = 0; v < h.size(); ++v) {
      if (h[v] == 0) continue;
      PutU32(out, static_cast<uint32_t>(v));
      PutU64(out, h[v]);
    }
  }
  PutU64(out, Fnv1a64(out));
  return out;
}

Result<Histogram> ParseHistogram(std::string_view bytes, const octree::SourceIdentity& source,
                                 const std::vector<volume::ValueMap>& maps) {
  auto corrupt = [](const std::string& what) { return CorruptError("histogram.bin: " + what); };
  if (bytes.size() < sizeof kMagic + 8 ||
      bytes.substr(0, sizeof kMagic) != std::string_view(kMagic, sizeof kMagic)) {
    return corrupt("not a histogram file");
  }
  Reader tail(bytes.substr(bytes.size() - 8));
  uint64_t checksum = 0;
  tail.U64(checksum);
  if (Fnv1a64(bytes.substr(0, bytes.size() - 8)) != checksum) return corrupt("checksum mismatch");
  Reader in(bytes.substr(sizeof kMagic, bytes.size() - sizeof kMagic - 8));
  uint32_t version = 0, channels = 0;
  uint64_t hash = 0, file_bytes = 0;
  if (!in.U32(version) || !in.U64(hash) || !in.U64(file_bytes) || !in.U32(channels)) {
    return corrupt("truncated header");
  }
  if (version != kVersion) return corrupt("unsupported version " + std::to_string(version));
  if (hash != source.hash || file_bytes != source.file_bytes) {
    return corrupt("written for another scan");
  }
  if (channels != maps.size()) return corrupt("written for another channel count");
  Histogram histogram(maps);
  for (uint32_t c = 0; c < channels; ++c) {
    uint32_t bins = 0, nonzero = 0;
    if (!in.U32(bins) || !in.U32(nonzero)) return corrupt("truncated");
    if (bins != histogram.counts(static_cast<int>(c)).size()) {
      return corrupt("channel " + std::to_string(c) + " has another stored type");
    }
    // Entries are appended as read: a lying count cannot allocate more than the file holds.
    if (nonzero > bins || static_cast<uint64_t>(nonzero) * 12 > in.left()) {
      return corrupt("channel " + std::to_string(c) + " declares too many values");
    }
    int64_t previous = -1;
    for (uint32_t i = 0; i < nonzero; ++i) {
      uint32_t value = 0;
      uint64_t count = 0;
      if (!in.U32(value) || !in.U64(count)) return corrupt("truncated");
      if (static_cast<int64_t>(value) <= previous || value >= bins || count == 0) {
        return corrupt("channel " + std::to_string(c) + " has an invalid entry");
      }
      previous = value;
      histogram.AddCount(static_cast<int>(c), value, count);
    }
  }
  if (in.left() != 0) return corrupt("trailing bytes");
  return histogram;
}

Status WriteHistogramFile(const std::filesystem::path& dir, const Histogram& histogram,
                          const octree::SourceIdentity& source) {
  // Several processes may serve one cache and write this file at once: each through its own
  // temporary file (the contents are equal; the last rename wins).
  return WriteFileDurably(dir / kHistogramFile, SerializeHistogram(histogram, source),
                          ".tmp." + std::to_string(::getpid()));
}

Result<Histogram> ReadHistogramFile(const std::filesystem::path& dir,
                                    const octree::SourceIdentity& source,
                                    const std::vector<volume::ValueMap>& maps) {
  // The largest valid file: 64 channels of 65536 entries of 12 bytes, plus headers.
  constexpr uint64_t kMaxBytes = uint64_t{64} * (65536 * 12 + 8) + 64;
  std::error_code ec;
  if (!std::filesystem::exists(dir / kHistogramFile, ec)) {
    return NotFoundError((dir / kHistogramFile).string() + ": no histogram");
  }
  OCTO_ASSIGN_OR_RETURN(std::string bytes, ReadSmallFile(dir / kHistogramFile, kMaxBytes));
  auto parsed = ParseHistogram(bytes, source, maps);
  if (!parsed.ok()) return parsed.status().WithContext(dir.string());
  return parsed;
}

Result<Histogram> HistogramFromOctree(const octree::Octree& tree,
                                      const std::vector<volume::ValueMap>& maps,
                                      std::stop_token stop) {
  Histogram histogram(maps);
  std::vector<std::vector<uint64_t>> counts;
  for (int c = 0; c < histogram.channels(); ++c) counts.emplace_back(histogram.counts(c).size(), 0);
  OCTO_RETURN_IF_ERROR(octree::CountVoxels(tree, counts, stop));
  for (int c = 0; c < histogram.channels(); ++c) {
    for (size_t v = 0; v < counts[c].size(); ++v) {
      if (counts[c][v] != 0) histogram.AddCount(c, static_cast<uint32_t>(v), counts[c][v]);
    }
  }
  return histogram;
}

void HistogramAccumulator::Reset(std::vector<volume::ValueMap> maps) {
  Histogram fresh(std::move(maps));
  std::lock_guard lock(mu_);
  histogram_ = std::move(fresh);
}

void HistogramAccumulator::Assign(Histogram histogram) {
  std::lock_guard lock(mu_);
  histogram_ = std::move(histogram);
}

void HistogramAccumulator::Add(int c, std::span<const std::byte> stored) {
  std::unique_lock lock(mu_);
  const size_t bins = histogram_.counts(c).size();
  const size_t samples = bins == 256 ? stored.size() : stored.size() / 2;
  if (samples < bins) {
    histogram_.Add(c, stored);  // Small: counting costs less than a private table.
    return;
  }
  // Large: count into a private table without the lock, then merge (bins additions).
  const std::vector<volume::ValueMap> maps{histogram_.value_maps()[c]};
  lock.unlock();
  Histogram part(maps);
  part.Add(0, stored);
  lock.lock();
  const std::span<const uint64_t> counts = part.counts(0);
  // A Reset meanwhile (a new build) made these counts stale.
  if (c >= histogram_.channels() || histogram_.counts(c).size() != counts.size()) return;
  for (size_t v = 0; v < counts.size(); ++v) {
    if (counts[v] != 0) histogram_.AddCount(c, static_cast<uint32_t>(v), counts[v]);
  }
}

void HistogramAccumulator::Subtract(int c, std::span<const std::byte> stored) {
  std::lock_guard lock(mu_);
  histogram_.Subtract(c, stored);
}

void HistogramAccumulator::Subtract(int c, std::span<const uint16_t> values) {
  std::lock_guard lock(mu_);
  histogram_.Subtract(c, values);
}

Histogram HistogramAccumulator::Snapshot() const {
  std::lock_guard lock(mu_);
  return histogram_;
}

}  // namespace octoscope::dataset
