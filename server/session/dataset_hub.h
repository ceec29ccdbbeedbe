// DatasetHub: the datasets that sessions view, made renderable. A session asks for a dataset by
// id (Use); the hub finds it (the app's finder: the registry), starts opening it (a build or a
// cache load runs on the dataset's worker) and, as soon as the dataset's octree exists, adds it
// to the render service once — every session viewing it then renders from the same octree,
// page cache and device mirror.
//
// Release: the hub counts the DatasetUses of each dataset. With HubOptions::idle_timeout set, a
// dataset no session has used for that long is released on the hub's own thread: removed from the
// render service (its device bricks go back to the others) and closed (Dataset::Release: pages
// flushed, page cache and octree freed; an unfinished stream is checkpointed and suspended —
// never finished — and resumes on its next slab), then HubOptions::on_release runs (the registry
// re-divides the RAM budget). A stream that received a slab within idle_timeout is left open (and
// tried again later). A later Use reopens a released dataset from its cache (no rebuild). A Use
// that arrives while the release runs gets its DatasetUse at once; the dataset is reopened as soon
// as the close finished (render_key is nullopt until then, as while a dataset loads).
//
// Thread safety: thread-safe. Use may be called from I/O threads: it never waits for disk.
#ifndef OCTOSCOPE_SESSION_DATASET_HUB_H_
#define OCTOSCOPE_SESSION_DATASET_HUB_H_

#include <chrono>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>

#include "dataset/dataset.h"
#include "render/render_service.h"
#include "util/result.h"

namespace octoscope::session {

class DatasetHub;

struct HubOptions {
  // A dataset unused this long is released; zero never releases.
  std::chrono::milliseconds idle_timeout{0};
  // Runs on the hub's thread after datasets were released or reopened (without the hub's lock).
  std::function<void()> on_release;
};

// One session's use of a dataset; the dataset is not released while a use exists.
class DatasetUse {
 public:
  ~DatasetUse();
  DatasetUse(const DatasetUse&) = delete;
  DatasetUse& operator=(const DatasetUse&) = delete;

  dataset::Dataset& dataset() const { return *dataset_; }
  const std::shared_ptr<dataset::Dataset>& shared() const { return dataset_; }
  // The dataset's key in the render service once its octree exists (added on first call after
  // that), else nullopt.
  std::optional<render::DatasetKey> render_key() const;

 private:
  friend class DatasetHub;
  DatasetUse(DatasetHub* hub, std::shared_ptr<dataset::Dataset> dataset)
      : hub_(hub), dataset_(std::move(dataset)) {}
  DatasetHub* hub_;
  std::shared_ptr<dataset::Dataset> dataset_;
};

class DatasetHub {
 public:
  // Finds a dataset by id (null: none). Called without the hub's lock held.
  using Finder = std::function<std::shared_ptr<dataset::Dataset>(std::string_view id)>;

  // REQUIRES: renderer outlives the hub; every DatasetUse is destroyed before the hub.
  DatasetHub(render::RenderService* renderer, Finder finder, HubOptions options = {});
  // Stops the release thread; removes the datasets from the render service (waits for its
  // current pass).
  ~DatasetHub();
  DatasetHub(const DatasetHub&) = delete;
  DatasetHub& operator=(const DatasetHub&) = delete;

  // kNotFound for an unknown id; the dataset's open error (kError state) otherwise.
  Result<std::shared_ptr<DatasetUse>> Use(std::string_view id);
  // Datasets added to the render service.
  size_t renderable() const;
  // Datasets the hub holds (used, or unused and not released yet).
  size_t held() const;
  // Datasets released so far (their closes finished).
  uint64_t releases() const;
  // Releases now the datasets unused since `idle_since_before` or earlier (the release thread
  // calls it with now - idle_timeout). Blocks while they are flushed. Returns how many were
  // closed (a stream still receiving slabs is not).
  size_t ReleaseIdle(std::chrono::steady_clock::time_point idle_since_before);

 private:
  friend class DatasetUse;
  std::optional<render::DatasetKey> KeyFor(dataset::Dataset& dataset);
  void Unuse(const std::string& id);
  void ReleaseLoop(std::stop_token stop);

  render::RenderService* renderer_;
  Finder finder_;
  const HubOptions options_;
  mutable std::mutex mu_;
  struct Entry {
    std::shared_ptr<dataset::Dataset> dataset;
    render::DatasetKey key = 0;
    int uses = 0;
    std::chrono::steady_clock::time_point idle_since;  // When uses last dropped to 0.
    bool releasing = false;                            // Being removed and closed.
  };
  std::map<std::string, Entry> entries_;  // By dataset id.
  uint64_t releases_ = 0;
  std::condition_variable_any wake_;
  std::jthread releaser_;  // Last: stopped first.
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_DATASET_HUB_H_
