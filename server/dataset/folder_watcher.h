// FolderWatcher: `octoscope serve --watch DIR` — follows a folder into which an acquisition writes
// one TIFF file per plane (per channel) and streams each plane into a streaming dataset once the
// file is complete, so that viewers see the scan while it is being acquired (docs/server.md,
// "Watched folders").
//
// The folder holds `octoscope.json`, the acquisition's description (protocol::ParseStreamRequest
// kSidecar: size, channels, dtype, spacing, names, index_base), and plane files named by
// io/slice_names.h — "z0012.tif" (one channel), "img_c1_z0012.tif", or channel sub-folders
// "ch1/0012.tif"; numbers count from index_base.
// A file is read only once it is COMPLETE: its size and modification time unchanged for
// settle_time, and then it must decode as exactly one plane of the described size and type
// (a truncated TIFF does not). A file that stays unreadable is reported once and skipped until it
// changes; a file that is rewritten replaces its plane. When every plane of every channel has
// arrived the dataset is finished (its cache then opens with `octoscope render`).
//
// Restarts: the folder's stream is recorded with the folder (DatasetRegistry::
// CreateWatchedStream). A watcher started on a folder whose stream is listed already (restored
// after a restart) goes on with it when the sidecar describes the same volume (size, channels,
// type): files of planes it received before are not read again (until they change), the others
// are streamed in, and the acquisition is finished when it is complete (a stream whose cache was
// lost, or of another shape, is replaced by a new one fed from the folder's files). An idle
// release of the stream never stops the watcher: the next plane resumes the stream.
//
// Thread safety: Start and the destructor from one thread; the watcher polls on its own thread.
#ifndef OCTOSCOPE_DATASET_FOLDER_WATCHER_H_
#define OCTOSCOPE_DATASET_FOLDER_WATCHER_H_

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "dataset/dataset_registry.h"
#include "util/logger.h"
#include "util/result.h"

namespace octoscope::dataset {

inline constexpr char kWatchSidecarName[] = "octoscope.json";

struct WatchOptions {
  std::chrono::milliseconds poll_interval{200};
  std::chrono::milliseconds settle_time{500};
  // A complete-looking file that still does not decode after this long is reported as bad.
  std::chrono::milliseconds give_up_after{10'000};
};

struct WatchStats {
  uint64_t planes_ingested = 0;
  uint64_t bad_files = 0;  // Reported and skipped (until they change).
  std::string dataset_id;  // "" until the sidecar was read.
  std::string last_error;
};

class FolderWatcher {
 public:
  // REQUIRES: registry and logger outlive the watcher. kNotFound when `dir` is not a folder.
  static Result<std::unique_ptr<FolderWatcher>> Start(DatasetRegistry* registry,
                                                      const std::filesystem::path& dir,
                                                      Logger* logger,
                                                      const WatchOptions& options = {});
  ~FolderWatcher();
  FolderWatcher(const FolderWatcher&) = delete;
  FolderWatcher& operator=(const FolderWatcher&) = delete;

  WatchStats stats() const;

 private:
  struct FileState {
    uint64_t size = 0;
    std::filesystem::file_time_type mtime{};
    std::chrono::steady_clock::time_point stable_since{};
    bool done = false;      // Ingested at this size and mtime.
    bool reported = false;  // Reported as bad at this size and mtime.
  };

  FolderWatcher() = default;
  void Run(std::stop_token stop);
  // One pass over the folder.
  void Poll();
  void ReadSidecar();
  // Goes on with the folder's stream from before a restart.
  void Resume(std::shared_ptr<Dataset> dataset);
  // The (channel, z) of a plane file, or nullopt (logged once) when the name says none.
  std::optional<std::pair<int, int64_t>> PlaneOf(const std::filesystem::path& path,
                                                 std::optional<uint64_t> folder_channel);
  void Consider(const std::filesystem::path& path, int channel, int64_t z);
  void Report(const std::string& message);

  DatasetRegistry* registry_ = nullptr;
  Logger* logger_ = nullptr;
  std::filesystem::path dir_;
  WatchOptions options_;
  std::shared_ptr<Dataset> dataset_;
  int index_base_ = 0;
  std::map<std::filesystem::path, FileState> files_;
  std::vector<bool> received_;  // Per channel * z.
  // A resumed stream: the planes it had received before (their files are not read again).
  std::vector<bool> already_received_;
  bool finished_ = false;
  mutable std::mutex mu_;  // Guards stats_.
  WatchStats stats_;
  std::jthread thread_;  // Last.
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_FOLDER_WATCHER_H_
