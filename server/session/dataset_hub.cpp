#include "session/dataset_hub.h"

#include <utility>
#include <vector>

namespace octoscope::session {

std::optional<render::DatasetKey> DatasetUse::render_key() const { return hub_->KeyFor(*dataset_); }

DatasetHub::DatasetHub(render::RenderService* renderer, Finder finder)
    : renderer_(renderer), finder_(std::move(finder)) {}

DatasetHub::~DatasetHub() {
  std::map<std::string, Entry> entries;
  {
    std::lock_guard<std::mutex> lock(mu_);
    entries.swap(entries_);
  }
  for (auto& [id, entry] : entries) {
    if (entry.key != 0) renderer_->RemoveDataset(entry.key);
  }
}

Result<std::shared_ptr<DatasetUse>> DatasetHub::Use(std::string_view id) {
  std::shared_ptr<dataset::Dataset> found;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(std::string(id));
    if (it != entries_.end()) found = it->second.dataset;
  }
  if (found == nullptr) {
    found = finder_(id);
    if (found == nullptr) return NotFoundError("no dataset '" + std::string(id) + "'");
    std::lock_guard<std::mutex> lock(mu_);
    auto [it, inserted] = entries_.try_emplace(std::string(id), Entry{found, 0});
    found = it->second.dataset;
  }
  // Non-blocking: a build or cache load runs on the dataset's worker.
  if (Status status = found->Open(); !status.ok()) return status;
  return std::shared_ptr<DatasetUse>(new DatasetUse(this, std::move(found)));
}

size_t DatasetHub::renderable() const {
  std::lock_guard<std::mutex> lock(mu_);
  size_t n = 0;
  for (const auto& [id, entry] : entries_) n += entry.key != 0;
  return n;
}

std::optional<render::DatasetKey> DatasetHub::KeyFor(dataset::Dataset& dataset) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = entries_.find(dataset.id());
  if (it == entries_.end()) return std::nullopt;
  if (it->second.key != 0) return it->second.key;
  octree::Octree* tree = dataset.octree();
  if (tree == nullptr) return std::nullopt;
  const auto spacing = dataset.spacing_um();
  it->second.key = renderer_->AddDataset(tree, render::Vec3{spacing[0], spacing[1], spacing[2]});
  return it->second.key;
}

}  // namespace octoscope::session
