#include "session/dataset_hub.h"

#include <algorithm>
#include <utility>
#include <vector>

namespace octoscope::session {

using Clock = std::chrono::steady_clock;

DatasetUse::~DatasetUse() { hub_->Unuse(dataset_->id()); }

std::optional<render::DatasetKey> DatasetUse::render_key() const { return hub_->KeyFor(*dataset_); }

DatasetHub::DatasetHub(render::RenderService* renderer, Finder finder, HubOptions options)
    : renderer_(renderer), finder_(std::move(finder)), options_(std::move(options)) {
  if (options_.idle_timeout.count() > 0) {
    releaser_ = std::jthread([this](std::stop_token stop) { ReleaseLoop(stop); });
  }
}

DatasetHub::~DatasetHub() {
  if (releaser_.joinable()) {
    releaser_.request_stop();
    wake_.notify_all();
    releaser_.join();
  }
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
  bool releasing = false;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(std::string(id));
    if (it != entries_.end()) {
      found = it->second.dataset;
      releasing = it->second.releasing;
      ++it->second.uses;  // Held from here: the release thread leaves it alone.
    }
  }
  if (found == nullptr) {
    found = finder_(id);
    if (found == nullptr) return NotFoundError("no dataset '" + std::string(id) + "'");
    std::lock_guard<std::mutex> lock(mu_);
    Entry fresh;
    fresh.dataset = found;
    auto [it, inserted] = entries_.try_emplace(std::string(id), std::move(fresh));
    found = it->second.dataset;
    releasing = it->second.releasing;
    ++it->second.uses;
  }
  auto use = std::shared_ptr<DatasetUse>(new DatasetUse(this, found));
  // Non-blocking: a build or cache load runs on the dataset's worker. A dataset being released
  // is reopened by the release thread once its close finished.
  if (!releasing) {
    if (Status status = found->Open(); !status.ok()) return status;
  }
  return use;
}

void DatasetHub::Unuse(const std::string& id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = entries_.find(id);
  if (it == entries_.end()) return;
  if (--it->second.uses == 0) it->second.idle_since = Clock::now();
}

size_t DatasetHub::renderable() const {
  std::lock_guard<std::mutex> lock(mu_);
  size_t n = 0;
  for (const auto& [id, entry] : entries_) n += entry.key != 0;
  return n;
}

size_t DatasetHub::held() const {
  std::lock_guard<std::mutex> lock(mu_);
  return entries_.size();
}

uint64_t DatasetHub::releases() const {
  std::lock_guard<std::mutex> lock(mu_);
  return releases_;
}

std::optional<render::DatasetKey> DatasetHub::KeyFor(dataset::Dataset& dataset) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = entries_.find(dataset.id());
  if (it == entries_.end() || it->second.releasing) return std::nullopt;
  if (it->second.key != 0) return it->second.key;
  octree::Octree* tree = dataset.octree();
  if (tree == nullptr) return std::nullopt;
  const auto spacing = dataset.spacing_um();
  it->second.key = renderer_->AddDataset(tree, render::Vec3{spacing[0], spacing[1], spacing[2]});
  return it->second.key;
}

size_t DatasetHub::ReleaseIdle(Clock::time_point idle_since_before) {
  struct Victim {
    std::string id;
    std::shared_ptr<dataset::Dataset> dataset;
    render::DatasetKey key;
  };
  std::vector<Victim> victims;
  {
    std::lock_guard<std::mutex> lock(mu_);
    for (auto& [id, entry] : entries_) {
      if (entry.uses == 0 && !entry.releasing && entry.idle_since <= idle_since_before) {
        entry.releasing = true;
        victims.push_back({id, entry.dataset, entry.key});
      }
    }
  }
  if (victims.empty()) return 0;
  std::vector<std::shared_ptr<dataset::Dataset>> reopen;
  size_t released = 0;
  for (Victim& v : victims) {
    // No view of it exists (no use): the render service drops its bricks, then the pages go.
    if (v.key != 0) renderer_->RemoveDataset(v.key);
    // A stream still receiving slabs stays open (and is tried again after another timeout).
    const bool closed = v.dataset->Release(options_.idle_timeout).ok();
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(v.id);
    it->second.releasing = false;
    it->second.key = 0;
    if (closed) {
      ++releases_;
      ++released;
    }
    if (it->second.uses > 0) {
      reopen.push_back(v.dataset);  // A session came back meanwhile.
    } else if (closed) {
      entries_.erase(it);
    } else {
      it->second.idle_since = Clock::now();
    }
  }
  for (const auto& dataset : reopen) (void)dataset->Open();
  if (options_.on_release) options_.on_release();
  return released;
}

void DatasetHub::ReleaseLoop(std::stop_token stop) {
  // Checked a few times per timeout, at most every 5 s: a dataset is released between
  // idle_timeout and 1.25 idle_timeout after its last use.
  const auto period = std::clamp<std::chrono::milliseconds>(
      options_.idle_timeout / 4, std::chrono::milliseconds(10), std::chrono::milliseconds(5000));
  std::mutex wait_mu;
  std::unique_lock<std::mutex> lock(wait_mu);
  while (!stop.stop_requested()) {
    wake_.wait_for(lock, stop, period, [] { return false; });
    if (stop.stop_requested()) break;
    ReleaseIdle(Clock::now() - options_.idle_timeout);
  }
}

}  // namespace octoscope::session
