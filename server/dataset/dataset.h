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
//           `octoscope render CACHE`). Only Finish finishes a stream: its owner's call.
//   Close releases the octree and page cache (a build is cancelled); the state then says what
//   the cache on disk holds (kReady for a complete cache, kPending otherwise) and a later Open
//   reopens it. An unfinished stream is SUSPENDED instead: checkpointed durably
//   (octree::OctreeCache::Checkpoint: its octree, received planes and histogram) and closed; it
//   stays kStreaming, and the next AddSlab, Open or Finish resumes it transparently (Open on the
//   worker, the others at once) with planes_received, missing planes, histogram and plane
//   replacement exactly as before. Release (the DatasetHub's idle release) is Close, except that
//   it leaves a stream that received a slab recently open.
//
// Checkpoints: an open unfinished stream is also checkpointed by its timer thread once it has
// been quiet (no slab) for StreamSpec::checkpoint_quiet after a change, and at least every
// checkpoint_interval while slabs keep arriving. A crash loses at most what arrived since the
// last checkpoint; the stream then resumes from that checkpoint and its warnings say which planes
// must be sent (again) — see docs/server.md, "Streams live until their owner finishes them".
//
// Persistence: a stream with a record folder (StreamSpec::record_dir) keeps its record there
// (stream_record.h): written at creation, at Finish and when a warning is added. RestoreStream
// brings it back after a restart, suspended, from its record and its cache (the last checkpoint,
// or the complete cache of a finished stream).
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
// or timer threads (never under the dataset's mutex mu_) and must be cheap.
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
#include "octree/octree_builder.h"
#include "octree/octree_cache.h"
#include "octree/slab_ingest.h"
#include "protocol/dataset_json.h"
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
  // An open stream is checkpointed once no slab came for checkpoint_quiet after a change, and at
  // least every checkpoint_interval while slabs keep coming.
  std::chrono::milliseconds checkpoint_quiet{2000};
  std::chrono::milliseconds checkpoint_interval{60000};
  std::string creator;                 // Opaque (who created it); "" for the server's own.
  std::filesystem::path watch_folder;  // The --watch folder feeding it; empty for none.
  std::filesystem::path record_dir;    // Its record goes there (ID.json); empty = none.
  // Runs after a suspended stream was resumed, on the resuming thread, without the dataset's
  // locks (the registry re-divides the RAM budget). May be empty.
  std::function<void()> on_resume;
};

// Copies a stream request's shape (name, size, channels, dtype, spacing, channel names) into
// `spec`.
void SetStreamShape(const protocol::StreamRequest& shape, StreamSpec& spec);

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
  std::vector<std::string> warnings;       // Streams: e.g. planes lost in an unclean stop.
  std::filesystem::path cache_dir;
};

class Dataset {
 public:
  // A dataset for `spec.path`; reads the header now (cheap: no voxel data), so info() works
  // before Open. A file no reader accepts gives a dataset in kError (Open then fails).
  static std::shared_ptr<Dataset> ForSource(const SourceSpec& spec);
  // A streaming dataset in kStreaming with an empty octree in a fresh cache directory
  // cache_root / id. kInvalidArgument for a bad spec (sizes, channels, type, spacing, names,
  // planes over kMaxStreamPlaneBytes); cache errors as OctreeCache::CreateResumable. The stream
  // is checkpointed at once (an empty checkpoint) and its record written.
  static Result<std::shared_ptr<Dataset>> CreateStream(const StreamSpec& spec);
  // A stream created before (its record), as its cache left it: suspended, listed with its
  // received planes, histogram and state (kStreaming from a checkpoint, kReady from a complete
  // cache); the next AddSlab, Open or Finish resumes it. `defaults` gives what the record does
  // not hold (cache_root, RAM, latencies, record_dir, on_resume). A stream whose cache is missing
  // or damaged is kError saying so (its slabs and Finish are refused); an unclean stop (see
  // "Checkpoints") adds a warning naming the planes to send again. kInvalidArgument for a record
  // that breaks CreateStream's rules.
  static Result<std::shared_ptr<Dataset>> RestoreStream(const protocol::StreamRecord& record,
                                                        const StreamSpec& defaults);
  ~Dataset();
  Dataset(const Dataset&) = delete;
  Dataset& operator=(const Dataset&) = delete;

  const std::string& id() const { return id_; }
  const std::string& name() const { return name_; }
  bool is_stream() const { return kind_ == Kind::kStream; }
  // Streams: who created it (opaque; "" for the server's own streams and for files).
  const std::string& creator() const { return creator_; }
  // Streams fed by a watched folder: the folder; else empty.
  const std::filesystem::path& watch_folder() const { return watch_folder_; }
  // Streams: per (channel, z), channel-major, whether the plane was received.
  std::vector<bool> received_planes() const;
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
  // cache, else builds one; a suspended stream is resumed. Errors only for a dataset that cannot
  // be opened at all (its file was unreadable when listed, a stream's cache is lost).
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
  // Resumes a suspended stream first.
  Status Finish();

  // The dataset's RAM budget (see the header comment); takes effect at once.
  void SetRamBudget(uint64_t bytes);
  uint64_t ram_budget() const;

  // Releases the octree and page cache (see the header comment; an unfinished stream is
  // suspended). Idempotent.
  void Close();
  // Close for an idle release, except for an unfinished stream that received a slab less than
  // `quiet` ago (kFailedPrecondition: it stays open) or whose checkpoint fails (that error; it
  // stays open). OK when the dataset is closed now.
  Status Release(std::chrono::milliseconds quiet);

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

  // Worker of Open: reuse or build (file), reopen a finished stream's cache, or resume a
  // suspended stream.
  void RunOpen(std::stop_token stop);
  Status OpenOrBuild(std::stop_token stop);
  Status ReopenStream(std::stop_token stop);
  // Close's work. REQUIRES: lifecycle_mu_ held.
  void CloseLocked();
  // Resumes a suspended stream (no-op when open or finished), then notifies and runs on_resume.
  Status ResumeStream();
  // Resume's work: reopens the checkpoint, its received planes and histogram, the ingest and
  // the timer. Sets *resumed when it did. REQUIRES: add_mu_ held exclusively.
  Status ResumeLocked(bool* resumed);
  // Checkpoints an open unfinished stream that changed since its last checkpoint (else OK).
  // REQUIRES: add_mu_ held exclusively.
  Status CheckpointLocked();
  // Starts the stream's timer thread unless it runs. REQUIRES: add_mu_ held exclusively (or no
  // other thread knows the dataset yet).
  Status EnsureStreamTimer();
  // A stream's shell (no cache yet) for CreateStream and RestoreStream.
  static Result<std::shared_ptr<Dataset>> NewStream(const StreamSpec& spec);
  // The cache parameters and RAM split of the stream (its budget now).
  octree::CacheParams StreamParams() const;
  octree::BuildBudget StreamBudget() const;
  // The checkpoint attachments of the received planes and histogram now.
  octree::CheckpointAttachments CheckpointAttachmentsNow();
  // Makes `cache` the open stream's: ingest (the received planes count as inserted), worker
  // pool, publication, timer. REQUIRES: add_mu_ held exclusively (or a stream being created).
  Status StartIngest(std::unique_ptr<octree::OctreeCache> cache, const octree::BuildBudget& budget);
  // Writes the stream's record (no-op without a record folder).
  Status WriteRecord();
  // Adds `warning` to the stream's warnings (and its record).
  void AddWarning(const std::string& warning);
  // The warning of an unclean stop for the received planes `received`.
  std::string UncleanStopWarning(const std::vector<uint8_t>& received) const;
  // Loads histogram.bin, or counts the octree's voxels and writes it.
  void LoadOrCountHistogram(const octree::SourceIdentity& identity, std::stop_token stop);
  // Timer of a stream: inserts staged planes when their latency is up, checkpoints when due.
  void RunStreamTimer(std::stop_token stop);
  // Makes `cache` the dataset's (octree() returns its tree) with `reserved` bytes of the budget
  // kept for construction, and applies the budget.
  void Publish(std::unique_ptr<octree::OctreeCache> cache, uint64_t reserved);
  // Applies the current budget to the page cache.
  void ApplyBudget();
  // AddSlab after conversion to the file type in native byte order (resumes a suspended stream).
  Status AddNative(int channel, int64_t z0, int64_t nz, std::span<const std::byte> native,
                   bool wait_visible);
  // AddNative on the open stream; sets *suspended (and changes nothing) when it found the stream
  // suspended (or suspended and resumed while it waited): resume and call again.
  Status AddToOpenStream(int channel, int64_t z0, int64_t nz, std::span<const std::byte> stored,
                         bool wait_visible, bool* suspended);
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
  std::chrono::milliseconds checkpoint_quiet_{2000};
  std::chrono::milliseconds checkpoint_interval_{60000};
  std::string creator_;
  std::filesystem::path watch_folder_;
  std::filesystem::path record_dir_;
  int64_t created_unix_ms_ = 0;
  std::function<void()> on_resume_;
  std::string restore_error_;  // Set when a restored stream's cache is unusable: it stays kError.

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
  std::vector<std::string> warnings_;
  // Open streams: the last slab, whether anything changed since the last checkpoint, when that
  // was, and when a failed checkpoint may be retried.
  std::chrono::steady_clock::time_point last_slab_{};
  bool changed_since_checkpoint_ = false;
  std::chrono::steady_clock::time_point last_checkpoint_{};
  std::chrono::steady_clock::time_point checkpoint_retry_{};
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
  mutable std::mutex claim_mu_;
  std::vector<uint8_t> received_;  // Guarded by claim_mu_: per (channel, z), 1 = received.
  octree::SourceIdentity identity_;

  HistogramAccumulator histogram_;
  std::shared_ptr<ChangeNotifier> notifier_;
  // Streams: flushes and checkpoints (RunStreamTimer); started on creation or the first resume,
  // stopped by the destructor. Last: stopped before anything it uses is destroyed.
  std::jthread stream_timer_;
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DATASET_H_
