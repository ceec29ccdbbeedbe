#include "dataset/dataset.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <random>
#include <system_error>

#include "dataset/cache_setup.h"
#include "io/open_volume.h"
#include "io/tiff_planes.h"
#include "octree/octree_builder.h"
#include "octree/voxel_reader.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/durable_file.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;

}  // namespace

std::string_view StateName(DatasetState state) {
  switch (state) {
    case DatasetState::kPending:
      return "pending";
    case DatasetState::kBuilding:
      return "building";
    case DatasetState::kStreaming:
      return "streaming";
    case DatasetState::kReady:
      return "ready";
    case DatasetState::kError:
      return "error";
  }
  return "error";
}

bool IsValidDatasetId(std::string_view id) {
  return id.size() == 12 && std::all_of(id.begin(), id.end(), [](char c) {
           return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
         });
}

Dataset::Dataset(Kind kind, Identity identity, volume::VolumeInfo info)
    : kind_(kind),
      id_(std::move(identity.id)),
      name_(std::move(identity.name)),
      cache_dir_(std::move(identity.cache_dir)),
      info_(std::move(info)),
      notifier_(std::make_shared<ChangeNotifier>()) {}

Dataset::~Dataset() {
  try {
    Close();
  } catch (...) {
    // Destructors never throw; Close reports its failures in the status.
  }
}

std::shared_ptr<Dataset> Dataset::ForSource(const SourceSpec& spec) {
  volume::VolumeInfo info;
  std::string header_error;
  // The dataset reads nothing outside its own folder, which every folder grant admitting it
  // contains (docs/server.md, "Users and access").
  io::OpenOptions open = spec.open;
  Result<io::FileGate> gate = io::FileGate::ForDataset(spec.path);
  if (gate.ok()) open.file_gate = *gate;
  auto source = gate.ok() ? io::OpenVolume(spec.path, open)
                          : Result<std::unique_ptr<io::VolumeSource>>(gate.status());
  if (source.ok()) {
    info = (*source)->info();
  } else {
    header_error = source.status().ToString();
    info.format = "unknown";
    info.channels.resize(1);
  }
  if (header_error.empty() && !IsValidDatasetId(spec.id)) {
    header_error = "invalid dataset id \"" + spec.id + "\"";
  }
  if (header_error.empty() && spec.cache_root.empty()) header_error = "no cache directory";
  Identity identity;
  identity.id = spec.id;
  identity.name = spec.name.empty() ? spec.path.filename().string() : spec.name;
  identity.cache_dir = spec.cache_root / spec.id;
  std::shared_ptr<Dataset> d(new Dataset(Kind::kFile, std::move(identity), std::move(info)));
  d->source_path_ = spec.path;
  d->open_options_ = std::move(open);
  d->open_options_.on_warning = nullptr;  // Warnings are in info().
  d->threshold_ = spec.threshold;
  d->brick_request_ = spec.brick_size;
  d->threads_ = spec.threads;
  d->ram_bytes_ = spec.ram_bytes;
  d->header_error_ = header_error;
  d->refers_outside_ = !source.ok() && io::IsOutsideFolderError(source.status());
  if (!header_error.empty()) {
    d->state_ = DatasetState::kError;
    d->error_ = header_error;
  }
  return d;
}

std::array<double, 3> Dataset::spacing_um() const {
  std::array<double, 3> s{1, 1, 1};
  for (int a = 0; a < 3; ++a) {
    if (info_.spacing_um[a]) s[a] = *info_.spacing_um[a];
  }
  return s;
}

DatasetStatus Dataset::status() const {
  DatasetStatus s;
  std::lock_guard lock(mu_);
  s.state = state_;
  s.open = tree_.load() != nullptr;
  s.planes_total = static_cast<uint64_t>(info_.size[2]) * info_.channel_count();
  s.planes_inserted = planes_inserted_;
  s.planes_received = kind_ == Kind::kStream ? planes_received_ : planes_inserted_;
  s.missing_planes = missing_planes_;
  s.histogram_complete = histogram_complete_;
  s.error = error_;
  s.warnings = warnings_;
  s.cache_dir = cache_dir_;
  return s;
}

std::vector<volume::ValueMap> Dataset::value_maps() const {
  std::lock_guard lock(mu_);
  return maps_;
}

Histogram Dataset::histogram() const { return histogram_.Snapshot(); }

uint64_t Dataset::ram_budget() const {
  std::lock_guard lock(mu_);
  return ram_bytes_;
}

void Dataset::SetRamBudget(uint64_t bytes) {
  {
    std::lock_guard lock(mu_);
    ram_bytes_ = bytes;
  }
  ApplyBudget();
}

void Dataset::ApplyBudget() {
  std::lock_guard budget(budget_mu_);
  paging::PageCache* pages = nullptr;
  uint64_t bytes = 0;
  {
    std::lock_guard lock(mu_);
    if (!cache_) return;
    pages = &cache_->page_cache();
    const uint64_t page = pages->page_bytes();
    const uint64_t floor = octree::OctreeCache::kMinPages * page;
    bytes = std::max(ram_bytes_ > reserved_bytes_ ? ram_bytes_ - reserved_bytes_ : 0, floor);
  }
  // Write-back errors of evicted dirty pages stay with the pages (they are retried and reported
  // by the next flush); the budget holds regardless.
  (void)pages->SetBudget(bytes);
}

void Dataset::Publish(std::unique_ptr<octree::OctreeCache> cache, uint64_t reserved) {
  {
    std::lock_guard lock(mu_);
    cache_ = std::move(cache);
    reserved_bytes_ = reserved;
    tree_.store(&cache_->octree(), std::memory_order_release);
  }
  ApplyBudget();
  cv_.notify_all();
  Notify();
}

void Dataset::SetError(const Status& status) {
  {
    std::lock_guard lock(mu_);
    state_ = DatasetState::kError;
    error_ = status.ToString();
    for (char& c : error_) {
      if (c == '\n' || c == '\r') c = ' ';  // One line.
    }
  }
  cv_.notify_all();
  Notify();
}

void Dataset::Notify() { notifier_->Notify(); }

Subscription Dataset::OnChange(std::function<void()> callback) {
  return notifier_->Subscribe(std::move(callback));
}

bool Dataset::WaitFor(const std::function<bool(const DatasetStatus&)>& done,
                      std::chrono::milliseconds timeout) const {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::unique_lock lock(mu_);
  while (true) {
    lock.unlock();
    const bool held = done(status());
    lock.lock();
    if (held) return true;
    if (cv_.wait_until(lock, deadline) == std::cv_status::timeout) {
      lock.unlock();
      return done(status());
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Opening and building.

Status Dataset::Open() {
  std::lock_guard life(lifecycle_mu_);
  {
    std::lock_guard lock(mu_);
    if (!header_error_.empty()) {
      return FailedPreconditionError(name_ + ": cannot be opened: " + header_error_);
    }
    if (!restore_error_.empty()) return FailedPreconditionError(name_ + ": " + restore_error_);
    if (worker_active_ || tree_.load() != nullptr) return Status::Ok();
    if (kind_ == Kind::kFile) {
      state_ = DatasetState::kBuilding;
    } else if (finished_) {
      state_ = DatasetState::kReady;
    }  // A suspended stream stays kStreaming while it resumes.
    error_.clear();
    worker_active_ = true;
  }
  if (worker_.joinable()) worker_.join();  // A previous run that has ended.
  try {
    worker_ = std::jthread([this](std::stop_token stop) { RunOpen(stop); });
  } catch (const std::system_error& e) {
    {
      std::lock_guard lock(mu_);
      worker_active_ = false;
    }
    const Status s = ResourceExhaustedError(name_ + ": cannot start a worker thread: " + e.what());
    SetError(s);
    return s;
  }
  cv_.notify_all();
  Notify();
  return Status::Ok();
}

void Dataset::RunOpen(std::stop_token stop) {
  Status s;
  try {
    bool finished = false;
    {
      std::lock_guard lock(mu_);
      finished = finished_;
    }
    if (kind_ == Kind::kFile) {
      s = OpenOrBuild(stop);
    } else if (finished) {
      s = ReopenStream(stop);
    } else {
      s = stop.stop_requested() ? CancelledError(name_ + ": not resumed") : ResumeStream();
    }
  } catch (const std::exception& e) {
    s = ResourceExhaustedError(name_ + ": " + e.what());
  } catch (...) {
    s = InternalError(name_ + ": an unknown exception");
  }
  if (!s.ok() && !(s.code() == StatusCode::kCancelled && stop.stop_requested())) SetError(s);
  {
    std::lock_guard lock(mu_);
    worker_active_ = false;
  }
  cv_.notify_all();
  Notify();
}

Status Dataset::OpenOrBuild(std::stop_token stop) {
  Result<octree::SourceIdentity> computed =
      octree::ComputeSourceIdentity(source_path_, open_options_.file_gate);
  if (!computed.ok()) return io::OutsideFolderErrorOf(computed.status(), source_path_);
  const octree::SourceIdentity identity = *computed;
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<io::VolumeSource> source,
                        io::OpenVolume(source_path_, open_options_));
  const volume::VolumeInfo& info = source->info();
  if (info.size != info_.size || info.channel_count() != info_.channel_count() ||
      info.dtype != info_.dtype) {
    return FailedPreconditionError(source_path_.string() + ": changed since it was listed (now " +
                                   info.ToString() + "); rescan the data folders");
  }
  octree::CacheParams params;
  params.info = info;
  params.brick_size = BrickSizeFor(info, brick_request_);
  params.threshold = threshold_;
  uint64_t ram = 0;
  {
    std::lock_guard lock(mu_);
    ram = ram_bytes_;
  }
  const octree::BuildBudget budget = BuildBudgetFor(info, params.brick_size, ram);
  OCTO_ASSIGN_OR_RETURN(
      std::unique_ptr<octree::OctreeCache> cache,
      octree::OctreeCache::Open(cache_dir_, identity, params, budget.page_bytes,
                                [&] { return DeriveMapping(*source, threshold_); }));
  const std::vector<volume::ValueMap> maps = cache->mapping().value_maps;
  const uint64_t total = static_cast<uint64_t>(info.size[2]) * info.channel_count();
  {
    std::lock_guard lock(mu_);
    maps_ = maps;
  }

  if (cache->reused()) {
    {
      std::lock_guard lock(mu_);
      state_ = DatasetState::kReady;
      planes_inserted_ = total;
    }
    Publish(std::move(cache), 0);
    LoadOrCountHistogram(identity, stop);
    return Status::Ok();
  }

  // Build: the octree is viewable from now on and grows as layers are inserted.
  std::error_code ec;
  fs::remove(cache_dir_ / kHistogramFile, ec);  // Describes an earlier build; ours is counted.
  histogram_.Reset(maps);
  {
    std::lock_guard lock(mu_);
    state_ = DatasetState::kBuilding;
    planes_inserted_ = 0;
    histogram_complete_ = false;
  }
  octree::OctreeCache* building = cache.get();
  Publish(std::move(cache), budget.slab_bytes + budget.staging_bytes);

  octree::BuildOptions options;
  options.threads = threads_;
  options.slab_budget_bytes = budget.slab_bytes;
  options.staging_bytes = budget.staging_bytes;
  options.scratch_dir = cache_dir_;
  options.stop = stop;
  options.progress = [this](const octree::BuildProgress& p) {
    bool changed = false;
    {
      std::lock_guard lock(mu_);
      changed = planes_inserted_ != p.planes_done;
      planes_inserted_ = p.planes_done;
    }
    if (changed) {
      cv_.notify_all();
      Notify();
    }
  };
  options.on_slab = [this](int channel, int64_t, int64_t, std::span<const std::byte> stored) {
    histogram_.Add(channel, stored);
  };
  OCTO_RETURN_IF_ERROR(octree::BuildOctree(*source, maps, building->octree(), options));
  source.reset();
  OCTO_RETURN_IF_ERROR(WriteHistogramFile(cache_dir_, histogram_.Snapshot(), identity));
  OCTO_RETURN_IF_ERROR(building->Commit());
  MarkReady([&] { planes_inserted_ = total; });
  return Status::Ok();
}

Status Dataset::ReopenStream(std::stop_token stop) {
  uint64_t ram = 0;
  {
    std::lock_guard lock(mu_);
    ram = ram_bytes_;
  }
  OCTO_ASSIGN_OR_RETURN(OpenedCache opened, OpenCompleteCache(cache_dir_, ram));
  const octree::SourceIdentity identity = opened.manifest.source;
  Publish(std::move(opened.cache), 0);
  LoadOrCountHistogram(identity, stop);
  return Status::Ok();
}

void Dataset::LoadOrCountHistogram(const octree::SourceIdentity& identity, std::stop_token stop) {
  const std::vector<volume::ValueMap> maps = value_maps();
  auto loaded = ReadHistogramFile(cache_dir_, identity, maps);
  if (!loaded.ok()) {
    // A cache without a (valid) histogram: count its level-0 voxels now, then keep the result.
    const octree::Octree* tree = octree();
    if (tree == nullptr) return;
    loaded = HistogramFromOctree(*tree, maps, stop);
    if (!loaded.ok()) return;  // The histogram stays incomplete; the dataset is fine.
    (void)WriteHistogramFile(cache_dir_, *loaded, identity);  // Best effort (read-only media).
  }
  histogram_.Assign(std::move(*loaded));
  {
    std::lock_guard lock(mu_);
    histogram_complete_ = true;
  }
  cv_.notify_all();
  Notify();
}

void Dataset::MarkReady(const std::function<void()>& under_lock) {
  {
    std::lock_guard lock(mu_);
    under_lock();
    state_ = DatasetState::kReady;
    histogram_complete_ = true;
    reserved_bytes_ = 0;  // Construction is over: the page cache gets the whole budget.
  }
  ApplyBudget();
  cv_.notify_all();
  Notify();
}

void Dataset::Close() {
  std::lock_guard life(lifecycle_mu_);
  CloseLocked();
}

void Dataset::CloseLocked() {
  // The worker (a build, a cache load, a resume) stops first: it may wait for add_mu_.
  if (worker_.joinable()) {
    worker_.request_stop();
    cv_.notify_all();
    worker_.join();
  }
  std::unique_ptr<octree::OctreeCache> cache;
  {
    std::unique_lock add(add_mu_);
    if (kind_ == Kind::kStream) {
      // An unfinished stream is suspended, never finished: checkpointed, then closed. Should the
      // checkpoint fail, it resumes from its previous one (and says what was lost).
      if (Status s = CheckpointLocked(); !s.ok()) {
        std::lock_guard lock(mu_);
        error_ = name_ + ": closed without its last checkpoint: " + s.message();
      }
    }
    ingest_.reset();
    insert_pool_.reset();
    std::lock_guard lock(mu_);
    if (!cache_ && state_ != DatasetState::kBuilding) return;  // Nothing open.
    tree_.store(nullptr, std::memory_order_release);
    cache = std::move(cache_);
    flush_due_.reset();
    // A stream's next checkpoint is its resume's business (a failed one above left the cache at
    // the previous checkpoint, which the resume reports).
    changed_since_checkpoint_ = false;
    if (kind_ == Kind::kFile && state_ == DatasetState::kBuilding) state_ = DatasetState::kPending;
    // A ready file whose histogram was still being counted: the next Open counts again.
  }
  {
    std::lock_guard budget(budget_mu_);
    cache.reset();  // Octree, page cache (flushes what is dirty), store, lock.
  }
  cv_.notify_all();
  Notify();
}

}  // namespace octoscope::dataset
