// DatasetRegistry: every dataset `octoscope serve` knows — the scans under the --data folders
// (every file or folder a reader accepts; headers only until a viewer opens one), streams created
// over the API, the demo — by stable id. It owns the global RAM budget and divides it among the
// datasets whose octrees are loaded, re-dividing as they open and close.
//
// Ids: [a-z0-9]{12}. A scan's id is derived from its --data folder's position and its path
// relative to that folder (stable across restarts, so caches are reused); a stream's is random;
// the demo's is "demospecimen".
//
// Thread safety: thread-safe. Create scans the folders (reads headers: start-up only); every
// other call is cheap and never touches the disk, except CreateStream (creates a cache folder)
// and Close.
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

  // A new streaming dataset (random id; its cache under the cache root).
  Result<std::shared_ptr<Dataset>> CreateStream(const protocol::StreamRequest& request);
  // The same with a given id (the demo); an existing cache folder of that id is replaced.
  Result<std::shared_ptr<Dataset>> CreateStreamWithId(const protocol::StreamRequest& request,
                                                      const std::string& id);

  // Divides the RAM budget equally among the datasets in use: those whose octree is loaded or
  // being loaded, built or streamed. Called by Open and CreateStream, and by whoever closes a
  // dataset (the session layer's release).
  void Rebalance();
  // The budget being divided.
  uint64_t ram_bytes() const { return options_.ram_bytes; }
  const std::filesystem::path& cache_root() const { return options_.cache_root; }

  // Closes every dataset (builds cancelled, streams committed, pages flushed). Idempotent.
  void Close();

 private:
  explicit DatasetRegistry(RegistryOptions options) : options_(std::move(options)) {}
  void Scan(const std::filesystem::path& root, size_t root_index);
  void ScanFolder(const std::filesystem::path& root, size_t root_index,
                  const std::filesystem::path& folder, int depth);
  // True when a reader accepted `path` (it is then listed). A folder refused for referring outside
  // itself is listed too, but is searched further (false).
  bool TryAdd(const std::filesystem::path& root, size_t root_index,
              const std::filesystem::path& path);

  const RegistryOptions options_;
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
