// Dataset: one dataset of `octoscope serve` — a scan file or folder whose octree is reused from
// its cache or built into it, or a stream an acquisition sends plane by plane — with its octree,
// page cache, construction and histogram, shared (std::shared_ptr) by every session viewing it.
//
// Life cycle (DatasetState):
//   file:   kPending --Open--> kBuilding (a worker builds; the octree is viewable at once and
//           grows) --> kReady; or a complete matching cache is reused: kBuilding --> kReady
//           within the time of loading its node table. Any failure (unreadable file, cache
//           locked by another process, disk full) is kError with one line in `error`; Open
//           again retries.
//   stream: CreateStream --> kStreaming (AddSlab inserts planes; a latency timer makes staged
//           planes visible) --Finish--> kReady (the cache is committed and opens with
//           `octoscope render CACHE`).
//   Close releases the octree and page cache (a build is cancelled; an unfinished stream is
//   committed first, as Finish does); the state then says what the cache on disk holds
//   (kReady for a complete cache, kPending otherwise) and a later Open reopens it.
//
// Explicit lifetime: everything the dataset owns (worker thread, cache lock, page cache, octree,
// ingest) is private; Close and the destructor stop and join the worker, wait for slab calls in
// flight, flush, and release in that order. octree() is valid from a successful Open until Close
// (callers keep the dataset open through a DatasetLease; see dataset_registry.h).
//
// RAM: SetRamBudget gives the dataset a byte budget: a build or stream reserves its reader slabs
// and layer staging (octree::SplitBuildBudget, fixed when the build or stream starts) and the page
// cache gets the rest (at least 8 pages); a ready dataset's page cache gets all of it.
//
// Histograms (histogram()): every voxel inserted is counted — by the build's reader threads
// (octree::BuildOptions::on_slab), by AddSlab for streams (a replaced plane's old voxels are read
// back from the tree and subtracted) — and persisted as histogram.bin in the cache directory
// before it is committed. A reused cache loads it; a cache without one (built by an older
// version) gets it counted from its level-0 bricks on the worker after the dataset is ready
// (DatasetStatus::histogram_complete says when).
//
// Thread safety: every member function is thread-safe. OnChange callbacks run on worker, upload
// or timer threads (never under the dataset's locks) and must be cheap.
#ifndef OCTOSCOPE_DATASET_DATASET_H_
#define OCTOSCOPE_DATASET_DATASET_H_

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "dataset/change_notifier.h"
#include "dataset/histogram.h"
#include "io/open_options.h"
#include "octree/octree.h"
#include "octree/octree_cache.h"
#include "octree/slab_ingest.h"
#include "util/result.h"
#include "util/status.h"
#include "util/worker_pool.h"
#include "volume/data_type.h"
#include "volume/value_map.h"
#include "volume/volume_info.h"

namespace octoscope::dataset {

enum class DatasetState { kPending, kBuilding, kStreaming, kReady, kError };
// "pending", "building", "streaming", "ready", "error" (docs/api.md).
std::string_view StateName(DatasetState state);

// True for ids of the form [a-z0-9]{12}.
bool IsValidDatasetId(std::string_view id);

inline constexpr uint64_t kDefaultDatasetRamBytes = uint64_t{1} << 30;

// A file or folder any reader accepts.
struct SourceSpec {
  std::string id;                    // [a-z0-9]{12}.
  std::string name;                  // Shown to users; "" = the file or folder name.
  std::filesystem::path path;        // The scan.
  io::OpenOptions open;              // Series, time, spacing overrides, sidecar loader, limits.
  std::filesystem::path cache_root;  // The cache lives in cache_root / id.
  double threshold = 0.0;            // Homogeneity threshold; 0 = lossless.
  octree::Vec3 brick_size{0, 0, 0};  // {0, 0, 0} = octree::AutoBrickSize.
  uint64_t ram_bytes = kDefaultDatasetRamBytes;  // Until SetRamBudget says otherwise.
  int threads = 0;                               // Build reader threads; 0 = the builder's default.
};

// An acquisition that sends its planes (POST /api/datasets, a watched folder, the demo).
struct StreamSpec {
  std::string id;                                      // [a-z0-9]{12}.
  std::string name;                                    // "" = "stream <id>".
  std::array<int64_t, 3> size{1, 1, 1};                // Each 1..65536.
  int channels = 1;                                    // 1..64.
  volume::DataType dtype = volume::DataType::kUint16;  // uint8, uint16, int8 or int16.
  std::array<double, 3> spacing_um{1, 1, 1};           // Each finite, in (0, 1e6].
  std::vector<std::string> channel_names;              // Empty or one per channel.
  std::filesystem::path cache_root;                    // The cache lives in cache_root / id.
  uint64_t ram_bytes = kDefaultDatasetRamBytes;
  // Staged planes (of brick layers not complete yet) are inserted at most this long after they
  // arrived (plus the insert's own time), so viewers see them within 250 ms.
  std::chrono::milliseconds flush_latency{100};
};

// The largest plane (x * y * bytes per sample) a stream accepts.
inline constexpr uint64_t kMaxStreamPlaneBytes = uint64_t{1} << 30;
// The most bytes the planes of one TIFF slab may decode to.
inline constexpr uint64_t kMaxTiffSlabBytes = uint64_t{1} << 30;

struct DatasetStatus {
  DatasetState state = DatasetState::kPending;
  bool open = false;             // The octree is loaded (octree() is not null).
  uint64_t planes_total = 0;     // z planes x channels.
  uint64_t planes_received = 0;  // Streams: distinct planes received; files: = planes_inserted.
  uint64_t planes_inserted = 0;  // Visible in the octree.
  std::optional<uint64_t> missing_planes;  // Finished streams: planes that never arrived.
  bool histogram_complete = false;         // histogram() counts every inserted voxel.
  std::string error;                       // One line; "" unless something failed.
  std::filesystem::path cache_dir;
};

class Dataset {
 public:
  // A dataset for `spec.path`; reads the header now (cheap: no voxel data), so info() works
  // before Open. A file no reader accepts gives a dataset in kError (Open then fails).
  static std::shared_ptr<Dataset> ForSource(const SourceSpec& spec);
  // A streaming dataset in kStreaming with an empty octree in a fresh cache directory
  // cache_root / id. kInvalidArgument for a bad spec (sizes, channels, type, spacing, names,
  // planes over kMaxStreamPlaneBytes); cache errors as OctreeCache::Open.
  static Result<std::shared_ptr<Dataset>> CreateStream(const StreamSpec& spec);
  ~Dataset();
  Dataset(const Dataset&) = delete;
  Dataset& operator=(const Dataset&) = delete;

  const std::string& id() const { return id_; }
  const std::string& name() const { return name_; }
  bool is_stream() const { return kind_ == Kind::kStream; }
  // The scan's metadata (a stream's from its spec), fixed at creation.
  const volume::VolumeInfo& info() const { return info_; }
  // Voxel spacing in µm, 1 where the scan does not say.
  std::array<double, 3> spacing_um() const;
  const std::filesystem::path& cache_dir() const { return cache_dir_; }
  const std::filesystem::path& source_path() const { return source_path_; }
  // The scan was refused at creation for referring to a file outside its own folder (io::FileGate;
  // the error says only that).
  bool refers_outside() const { return refers_outside_; }
  DatasetStatus status() const;

  // Makes the octree available: idempotent and non-blocking (the work runs on the dataset's
  // worker thread; OnChange / WaitFor tell when octree() is there). Reuses a complete matching
  // cache, else builds one. Errors only for a dataset that cannot be opened at all (its file
  // was unreadable when listed).
  Status Open();
  // The octree, or null until Open succeeded (or after Close). Valid until Close.
  octree::Octree* octree() const { return tree_.load(std::memory_order_acquire); }
  // File value = offset + scale * stored value, per channel; empty until known (after Open).
  std::vector<volume::ValueMap> value_maps() const;
  Histogram histogram() const;

  // Streams only. Inserts planes [z0, z0 + nz) of `channel`: `samples` holds them as
  // little-endian samples of the stream's dtype, x fastest (exactly x*y*nz samples). With
  // `wait_visible` it returns once they are inserted (visible to every viewer); else once they
  // are staged, and the latency timer inserts them within flush_latency. A plane sent again
  // replaces the earlier one. Errors: kFailedPrecondition after Finish/Close (or for a file
  // dataset), kOutOfRange for the channel or planes, kInvalidArgument for the size; insert and
  // disk errors as the octree reports them.
  Status AddSlab(int channel, int64_t z0, int64_t nz, std::span<const std::byte> samples,
                 bool wait_visible);
  // The same with the planes given as a TIFF file in memory (io::DecodeTiffPlanes: its pages
  // must be x*y of the stream's dtype, one sample per pixel); `nz` = the page count it must
  // hold, 0 = any (up to the volume's end).
  Status AddTiffSlab(int channel, int64_t z0, int64_t nz, std::span<const std::byte> tiff,
                     bool wait_visible);
  // Streams only: inserts everything staged, writes histogram.bin and commits the cache (it then
  // opens with `octoscope render CACHE`); state kReady with missing_planes. Idempotent.
  Status Finish();

  // The dataset's RAM budget (see the header comment); takes effect at once.
  void SetRamBudget(uint64_t bytes);
  uint64_t ram_budget() const;

  // Releases the octree and page cache (see the header comment). Idempotent.
  void Close();

  // `callback` is called whenever status or progress changes or new data became visible.
  Subscription OnChange(std::function<void()> callback);
  // Waits until `done(status())` holds or `timeout` passes; returns whether it held.
  bool WaitFor(const std::function<bool(const DatasetStatus&)>& done,
               std::chrono::milliseconds timeout) const;

 private:
  enum class Kind { kFile, kStream };
  struct Identity {
    std::string id;
    std::string name;
    std::filesystem::path cache_dir;
  };

  Dataset(Kind kind, Identity identity, volume::VolumeInfo info);

  // Worker of a file dataset: reuse or build (file), or reopen a finished stream's cache.
  void RunOpen(std::stop_token stop);
  Status OpenOrBuild(std::stop_token stop);
  Status ReopenStream(std::stop_token stop);
  // Loads histogram.bin, or counts the octree's voxels and writes it.
  void LoadOrCountHistogram(const octree::SourceIdentity& identity, std::stop_token stop);
  // Worker of a stream: inserts staged planes when their latency is up.
  void RunFlushTimer(std::stop_token stop);
  // Makes `cache` the dataset's (octree() returns its tree) with `reserved` bytes of the budget
  // kept for construction, and applies the budget.
  void Publish(std::unique_ptr<octree::OctreeCache> cache, uint64_t reserved);
  // Applies the current budget to the page cache.
  void ApplyBudget();
  // AddSlab after conversion to the file type in native byte order.
  Status AddNative(int channel, int64_t z0, int64_t nz, std::span<const std::byte> native,
                   bool wait_visible);
  Status CheckSlab(int channel, int64_t z0, int64_t nz) const;
  // Finish's work. REQUIRES: lifecycle_mu_ held, add_mu_ held exclusively.
  Status FinishLocked();
  // Flushes the ingest and refreshes the counters. REQUIRES: add_mu_ held (shared suffices).
  Status FlushIngest();
  void RefreshCounters();
  // State kReady with the histogram complete and no construction reserve; `under_lock` sets
  // more fields under mu_ first. Then applies the budget and notifies.
  void MarkReady(const std::function<void()>& under_lock);
  void SetError(const Status& status);
  void Notify();

  const Kind kind_;
  const std::string id_;
  const std::string name_;
  const std::filesystem::path cache_dir_;
  const volume::VolumeInfo info_;

  // File datasets.
  std::filesystem::path source_path_;
  io::OpenOptions open_options_;
  double threshold_ = 0.0;
  octree::Vec3 brick_request_{0, 0, 0};
  int threads_ = 0;
  std::string header_error_;     // Set when the file was unreadable at creation.
  bool refers_outside_ = false;  // header_error_ is the gate's refusal.
  // Streams.
  std::chrono::milliseconds flush_latency_{100};

  std::mutex lifecycle_mu_;  // Serialises Open, Finish and Close.
  mutable std::mutex mu_;    // Guards the fields below; never held across I/O or callbacks.
  mutable std::condition_variable_any cv_;  // Any change of them.
  DatasetState state_ = DatasetState::kPending;
  std::string error_;
  uint64_t planes_received_ = 0;
  uint64_t planes_inserted_ = 0;
  std::optional<uint64_t> missing_planes_;
  bool histogram_complete_ = false;
  bool worker_active_ = false;
  bool finished_ = false;  // A stream after Finish.
  uint64_t ram_bytes_ = kDefaultDatasetRamBytes;
  uint64_t reserved_bytes_ = 0;  // Of ram_bytes_, kept for construction (slabs, staging).
  std::vector<volume::ValueMap> maps_;
  std::optional<std::chrono::steady_clock::time_point> flush_due_;
  std::unique_ptr<octree::OctreeCache> cache_;

  std::atomic<octree::Octree*> tree_{nullptr};
  std::mutex budget_mu_;  // Serialises ApplyBudget with itself and with releasing the cache.
  std::jthread worker_;   // Owned by lifecycle_mu_ holders.

  // Stream ingest: AddSlab holds add_mu_ shared, Finish / Close / replacing a plane exclusive.
  std::shared_mutex add_mu_;
  std::unique_ptr<WorkerPool> insert_pool_;
  std::unique_ptr<octree::SlabIngest> ingest_;
  std::mutex claim_mu_;
  std::vector<uint8_t> received_;  // Guarded by claim_mu_: per (channel, z), 1 = received.
  octree::SourceIdentity identity_;

  HistogramAccumulator histogram_;
  std::shared_ptr<ChangeNotifier> notifier_;
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DATASET_H_
