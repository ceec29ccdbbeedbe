// DatasetHub: the datasets that sessions view, made renderable. A session asks for a dataset by
// id (Use); the hub finds it (the app's finder: the registry), starts opening it (a build or a
// cache load runs on the dataset's worker) and, as soon as the dataset's octree exists, adds it
// to the render service once — every session viewing it then renders from the same octree,
// page cache and device mirror.
//
// Lifetime: a dataset added to the render service stays added (and open) until the hub is
// destroyed; the render service drops its device mirror while no view uses it. Releasing unused
// datasets is the registry's policy (it must not close a dataset the hub holds).
//
// Thread safety: thread-safe. Use may be called from I/O threads: it never waits for disk.
#ifndef OCTOSCOPE_SESSION_DATASET_HUB_H_
#define OCTOSCOPE_SESSION_DATASET_HUB_H_

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "dataset/dataset.h"
#include "render/render_service.h"
#include "util/result.h"

namespace octoscope::session {

class DatasetHub;

// One session's use of a dataset.
class DatasetUse {
 public:
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

  // REQUIRES: renderer outlives the hub.
  DatasetHub(render::RenderService* renderer, Finder finder);
  // Removes the datasets from the render service (waits for its current pass).
  ~DatasetHub();
  DatasetHub(const DatasetHub&) = delete;
  DatasetHub& operator=(const DatasetHub&) = delete;

  // kNotFound for an unknown id; the dataset's open error (kError state) otherwise.
  Result<std::shared_ptr<DatasetUse>> Use(std::string_view id);
  // Datasets added to the render service.
  size_t renderable() const;

 private:
  friend class DatasetUse;
  std::optional<render::DatasetKey> KeyFor(dataset::Dataset& dataset);

  render::RenderService* renderer_;
  Finder finder_;
  mutable std::mutex mu_;
  struct Entry {
    std::shared_ptr<dataset::Dataset> dataset;
    render::DatasetKey key = 0;
  };
  std::map<std::string, Entry> entries_;  // By dataset id.
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_DATASET_HUB_H_
