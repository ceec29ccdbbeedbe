// DatasetRegistry: every dataset `octoscope serve` knows — the scans under the --data folders
// (every file or folder a reader accepts; headers only until a viewer opens one), streams created
// over the API or for watched folders, the demo — by stable id. It owns the global RAM budget and
// divides it among the datasets whose octrees are loaded, re-dividing as they open and close.
//
// Streams outlive the process: with a state folder (RegistryOptions::state_dir) every stream but
// the demo has a record in STATE_DIR/streams (dataset/stream_record.h), and Create lists every
// recorded stream of this cache root again, as its cache left it (Dataset::RestoreStream):
// unfinished ones suspended, finished ones ready. Records of other cache roots are left alone;
// records that do not read back are reported (restore_messages) and left in place.
//
// Ids: [a-z0-9]{12}. A scan's id is derived from its --data folder's position and its path
// relative to that folder (stable across restarts, so caches are reused); a stream's is random
// and kept by its record; the demo's is "demospecimen" (streamed afresh by every run).
//
// Thread safety: thread-safe. Create scans the folders (reads headers and stream records:
// start-up only); every other call is cheap and never touches the disk, except CreateStream
// (creates a cache folder and a record) and Close.
#ifndef OCTOSCOPE_DATASET_DATASET_REGISTRY_H_
#define OCTOSCOPE_DATASET_DATASET_REGISTRY_H_

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "dataset/dataset.h"
#include "io/open_options.h"
#include "protocol/dataset_json.h"
#include "util/result.h"

namespace octoscope::dataset {

struct RegistryOptions {
  std::vector<std::filesystem::path> data_dirs;
  std::filesystem::path cache_root;        // Created if missing.
  uint64_t ram_bytes = uint64_t{1} << 30;  // Divided among the open datasets.
  io::OpenOptions open;                    // How scans are read (parsers, overrides).
  int max_scan_depth = 3;                  // Folder levels searched below each --data folder.
  size_t max_datasets = 10000;             // Scanning stops there (a huge tree is a mistake).
  std::chrono::milliseconds stream_flush_latency{100};
  // Streams are checkpointed this long after their last slab, and at least this often while
  // slabs arrive (StreamSpec).
  std::chrono::milliseconds stream_checkpoint_quiet{2000};
  std::chrono::milliseconds stream_checkpoint_interval{60000};
  // Durable server state: stream records go to state_dir/streams. Empty = streams are not
  // recorded (they are gone after a restart; unit tests).
  std::filesystem::path state_dir;
};

class DatasetRegistry {
 public:
  // Scans the data folders. Errors: kNotFound for a data folder that does not exist, cache root
  // errors (it cannot be created).
  static Result<std::unique_ptr<DatasetRegistry>> Create(const RegistryOptions& options);
  // Close().
  ~DatasetRegistry();
  DatasetRegistry(const DatasetRegistry&) = delete;
  DatasetRegistry& operator=(const DatasetRegistry&) = delete;

  // Every dataset, scans in path order, then streams in creation order.
  std::vector<std::shared_ptr<Dataset>> List() const;
  std::shared_ptr<Dataset> Find(std::string_view id) const;
  // Find + Dataset::Open (non-blocking) + a new division of the RAM budget. Null when unknown.
  Result<std::shared_ptr<Dataset>> Open(std::string_view id);

  // A new streaming dataset (random id; its cache under the cache root, its record in the state
  // folder). `creator` is opaque (who may see it is the access layer's business).
  Result<std::shared_ptr<Dataset>> CreateStream(const protocol::StreamRequest& request,
                                                const std::string& creator);
  // The same with a given id (the demo: never recorded); an existing cache folder of that id is
  // replaced. kFailedPrecondition when a dataset of that id exists.
  Result<std::shared_ptr<Dataset>> CreateStreamWithId(const protocol::StreamRequest& request,
                                                      const std::string& id,
                                                      const std::string& creator);
  // A new stream fed by the watched folder `folder` (created by the server: no creator).
  Result<std::shared_ptr<Dataset>> CreateWatchedStream(const protocol::StreamRequest& request,
                                                       const std::filesystem::path& folder);
  // The newest stream fed by `folder` (compared after weakly_canonical), or null.
  std::shared_ptr<Dataset> FindWatchedStream(const std::filesystem::path& folder) const;
  // What Create found while restoring the streams (one line each: skipped records, streams whose
  // cache is lost), for the log.
  const std::vector<std::string>& restore_messages() const { return restore_messages_; }

  // Divides the RAM budget equally among the datasets in use: those whose octree is loaded, or
  // being built. Called by Open and CreateStream, when a suspended stream resumes, and by whoever
  // closes a dataset (the session layer's release).
  void Rebalance();
  // The budget being divided.
  uint64_t ram_bytes() const { return options_.ram_bytes; }
  const std::filesystem::path& cache_root() const { return options_.cache_root; }

  // Closes every dataset (builds cancelled, unfinished streams checkpointed — never finished —,
  // pages flushed). Idempotent.
  void Close();

 private:
  explicit DatasetRegistry(RegistryOptions options);
  // Lists the recorded streams of this cache root (Create).
  void RestoreStreams();
  Result<std::shared_ptr<Dataset>> AddStream(const protocol::StreamRequest& request,
                                             const std::string& id, const std::string& creator,
                                             const std::filesystem::path& watch_folder);
  // What every stream of this registry shares: cache root, RAM, latencies, record folder, the
  // resume hook.
  StreamSpec StreamDefaults() const;
  void Scan(const std::filesystem::path& root, size_t root_index);
  void ScanFolder(const std::filesystem::path& root, size_t root_index,
                  const std::filesystem::path& folder, int depth);
  // True when a reader accepted `path` (it is then listed). A folder refused for referring outside
  // itself is listed too, but is searched further (false).
  bool TryAdd(const std::filesystem::path& root, size_t root_index,
              const std::filesystem::path& path);

  const RegistryOptions options_;
  const std::filesystem::path record_dir_;  // Empty: streams are not recorded.
  // The registry as the streams' resume hook sees it: null once closed (a stream resumed later
  // must not reach a registry being destroyed).
  struct Hook {
    std::mutex mu;
    DatasetRegistry* registry = nullptr;
  };
  std::shared_ptr<Hook> hook_;
  std::vector<std::string> restore_messages_;  // Written by Create only.
  mutable std::mutex mu_;
  std::vector<std::shared_ptr<Dataset>> ordered_;
  std::map<std::string, std::shared_ptr<Dataset>, std::less<>> by_id_;
  bool closed_ = false;
};

// The demo's id.
std::string_view DemoDatasetId();

// The stable id of `relative_path` below the data folder number `root_index`.
std::string ScanDatasetId(size_t root_index, const std::filesystem::path& relative_path);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DATASET_REGISTRY_H_
