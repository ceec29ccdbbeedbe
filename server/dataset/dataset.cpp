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

constexpr size_t kMaxNameBytes = 256;
constexpr int64_t kMaxAxis = 65536;
constexpr int kMaxChannels = 64;
constexpr double kMaxSpacingUm = 1e6;

// A stream's identity in its cache MANIFEST: no file backs it, so a nonce makes every stream's
// cache its own (a directory reused by a later stream of the same id is rebuilt, never served).
octree::SourceIdentity StreamIdentity(const std::string& id) {
  std::random_device random;
  const uint64_t nonce = (static_cast<uint64_t>(random()) << 32) ^ random();
  octree::SourceIdentity identity;
  identity.hash = Fnv1a64("octoscope-stream:" + id + ":" + std::to_string(nonce));
  identity.file_bytes = 0;
  return identity;
}

Status CheckStreamSpec(const StreamSpec& spec) {
  auto bad = [&](const std::string& what) {
    return InvalidArgumentError("stream " + spec.id + ": " + what);
  };
  if (!IsValidDatasetId(spec.id)) return InvalidArgumentError("stream id must be [a-z0-9]{12}");
  if (spec.name.size() > kMaxNameBytes) return bad("name longer than 256 bytes");
  for (int a = 0; a < 3; ++a) {
    if (spec.size[a] < 1 || spec.size[a] > kMaxAxis) {
      return bad("size[" + std::to_string(a) + "] is " + std::to_string(spec.size[a]) +
                 ", must be in 1..65536");
    }
    if (!std::isfinite(spec.spacing_um[a]) || !(spec.spacing_um[a] > 0) ||
        spec.spacing_um[a] > kMaxSpacingUm) {
      return bad("spacing[" + std::to_string(a) + "] must be in (0, 1e6] µm");
    }
  }
  if (spec.channels < 1 || spec.channels > kMaxChannels) {
    return bad(std::to_string(spec.channels) + " channels, must be 1..64");
  }
  if (volume::BytesPerSample(spec.dtype) > 2 || volume::IsFloat(spec.dtype)) {
    return bad("dtype " + std::string(volume::NumpyName(spec.dtype)) +
               ", must be uint8, uint16, int8 or int16");
  }
  if (!spec.channel_names.empty() &&
      spec.channel_names.size() != static_cast<size_t>(spec.channels)) {
    return bad(std::to_string(spec.channel_names.size()) + " channel names for " +
               std::to_string(spec.channels) + " channels");
  }
  for (const std::string& n : spec.channel_names) {
    if (n.size() > kMaxNameBytes) return bad("a channel name is longer than 256 bytes");
  }
  const uint64_t plane = static_cast<uint64_t>(spec.size[0]) * static_cast<uint64_t>(spec.size[1]) *
                         volume::BytesPerSample(spec.dtype);
  if (plane > kMaxStreamPlaneBytes) {
    return bad("a plane of " + std::to_string(plane >> 20) + " MiB is more than the " +
               std::to_string(kMaxStreamPlaneBytes >> 20) + " MiB a stream accepts");
  }
  if (spec.cache_root.empty()) return bad("no cache directory");
  if (spec.flush_latency.count() < 0) return bad("negative flush latency");
  return Status::Ok();
}

// Samples of `data` converted from the file type (native order) to the stored type; `scratch`
// holds them unless no conversion is needed.
std::span<const std::byte> ToStored(const volume::ValueMap& map, std::span<const std::byte> data,
                                    std::vector<std::byte>& scratch) {
  if (map.file_type == map.stored_type && map.offset == 0 && map.scale == 1) return data;
  const size_t samples = data.size() / volume::BytesPerSample(map.file_type);
  scratch.resize(samples * volume::BytesPerSample(map.stored_type));
  volume::ConvertToStored(map, data, scratch);
  return scratch;
}

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

Result<std::shared_ptr<Dataset>> Dataset::CreateStream(const StreamSpec& spec) {
  OCTO_RETURN_IF_ERROR(CheckStreamSpec(spec));
  volume::VolumeInfo info;
  info.format = "stream";
  info.size = spec.size;
  info.dtype = spec.dtype;
  for (int c = 0; c < spec.channels; ++c) {
    info.channels.push_back(
        {spec.channel_names.empty() ? std::string() : spec.channel_names[c], std::nullopt});
  }
  for (int a = 0; a < 3; ++a) info.spacing_um[a] = spec.spacing_um[a];
  OCTO_RETURN_IF_ERROR(info.Validate());

  Identity identity;
  identity.id = spec.id;
  identity.name = spec.name.empty() ? "stream " + spec.id : spec.name;
  identity.cache_dir = spec.cache_root / spec.id;
  std::shared_ptr<Dataset> d(new Dataset(Kind::kStream, std::move(identity), info));
  d->flush_latency_ = spec.flush_latency;
  d->ram_bytes_ = spec.ram_bytes;
  d->identity_ = StreamIdentity(spec.id);

  // A fresh cache (the nonce identity never matches what a directory holds), built into.
  octree::CacheParams params;
  params.info = info;
  params.brick_size = BrickSizeFor(info, {0, 0, 0});
  params.threshold = 0;
  const octree::BuildBudget budget = BuildBudgetFor(info, params.brick_size, spec.ram_bytes);
  const octree::ValueMapping mapping = FixedMapping(info);
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<octree::OctreeCache> cache,
                        octree::OctreeCache::Open(d->cache_dir_, d->identity_, params,
                                                  budget.page_bytes, [&] { return mapping; }));
  std::error_code ec;
  fs::remove(d->cache_dir_ / kHistogramFile, ec);
  const unsigned hardware = std::max(1u, std::thread::hardware_concurrency());
  d->insert_pool_ = std::make_unique<WorkerPool>(static_cast<int>(std::min(hardware, 4u)));
  octree::IngestOptions ingest;
  ingest.staging_bytes = budget.staging_bytes;
  ingest.scratch_dir = d->cache_dir_;
  ingest.workers = d->insert_pool_.get();
  OCTO_ASSIGN_OR_RETURN(d->ingest_, octree::SlabIngest::Create(&cache->octree(), ingest));
  d->received_.assign(static_cast<size_t>(info.size[2]) * info.channel_count(), 0);
  d->histogram_.Reset(mapping.value_maps);
  {
    std::lock_guard lock(d->mu_);
    d->maps_ = mapping.value_maps;
    d->state_ = DatasetState::kStreaming;
  }
  d->Publish(std::move(cache), budget.slab_bytes + budget.staging_bytes);
  try {
    d->worker_ = std::jthread([raw = d.get()](std::stop_token stop) { raw->RunFlushTimer(stop); });
  } catch (const std::system_error& e) {
    return ResourceExhaustedError("stream " + spec.id +
                                  ": cannot start its flush timer: " + e.what());
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
    if (worker_active_ || tree_.load() != nullptr) return Status::Ok();
    if (kind_ == Kind::kStream && !finished_) {
      return FailedPreconditionError(name_ + ": the stream was closed before it finished");
    }
    state_ = kind_ == Kind::kStream ? DatasetState::kReady : DatasetState::kBuilding;
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
    s = kind_ == Kind::kStream ? ReopenStream(stop) : OpenOrBuild(stop);
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

// ---------------------------------------------------------------------------------------------
// Streaming.

Status Dataset::CheckSlab(int channel, int64_t z0, int64_t nz) const {
  if (kind_ != Kind::kStream) {
    return FailedPreconditionError(name_ + ": not a streaming dataset; slabs cannot be added");
  }
  if (channel < 0 || channel >= info_.channel_count()) {
    return OutOfRangeError(name_ + ": channel " + std::to_string(channel) + " of " +
                           std::to_string(info_.channel_count()));
  }
  if (nz < 1 || z0 < 0 || z0 > info_.size[2] - nz) {
    return OutOfRangeError(name_ + ": planes [" + std::to_string(z0) + ", " + std::to_string(z0) +
                           "+" + std::to_string(nz) + ") outside [0, " +
                           std::to_string(info_.size[2]) + ")");
  }
  return Status::Ok();
}

Status Dataset::AddSlab(int channel, int64_t z0, int64_t nz, std::span<const std::byte> samples,
                        bool wait_visible) {
  OCTO_RETURN_IF_ERROR(CheckSlab(channel, z0, nz));
  const uint64_t sample_bytes = volume::BytesPerSample(info_.dtype);
  const std::optional<uint64_t> expected =
      CheckedProduct({info_.PlaneVoxels(), static_cast<uint64_t>(nz), sample_bytes});
  if (!expected || samples.size() != *expected) {
    return InvalidArgumentError(
        name_ + ": " + std::to_string(nz) + " planes of " + std::to_string(info_.size[0]) + "x" +
        std::to_string(info_.size[1]) + " " + std::string(volume::NumpyName(info_.dtype)) +
        " are " + (expected ? std::to_string(*expected) : std::string("too many")) +
        " bytes, got " + std::to_string(samples.size()));
  }
  if constexpr (std::endian::native == std::endian::little) {
    return AddNative(channel, z0, nz, samples, wait_visible);
  } else {
    std::vector<std::byte> native(samples.begin(), samples.end());
    SwapBytesInPlace(native, sample_bytes);
    return AddNative(channel, z0, nz, native, wait_visible);
  }
}

Status Dataset::AddTiffSlab(int channel, int64_t z0, int64_t nz, std::span<const std::byte> tiff,
                            bool wait_visible) {
  OCTO_RETURN_IF_ERROR(CheckSlab(channel, z0, std::max<int64_t>(nz, 1)));
  io::PlaneExpectation expect;
  expect.width = info_.size[0];
  expect.height = info_.size[1];
  expect.dtype = info_.dtype;
  expect.planes = nz;
  expect.max_planes = info_.size[2] - z0;
  expect.max_bytes = kMaxTiffSlabBytes;
  OCTO_ASSIGN_OR_RETURN(io::DecodedPlanes planes,
                        io::DecodeTiffPlanes(tiff, name_ + ": slab TIFF", expect));
  return AddNative(channel, z0, planes.count, planes.samples, wait_visible);
}

Status Dataset::AddNative(int channel, int64_t z0, int64_t nz, std::span<const std::byte> native,
                          bool wait_visible) {
  std::shared_lock add(add_mu_);
  volume::ValueMap map;
  {
    std::lock_guard lock(mu_);
    if (finished_) {
      return FailedPreconditionError(name_ + ": the acquisition was finished; no more slabs");
    }
    if (!ingest_) return FailedPreconditionError(name_ + ": the stream was closed");
    map = maps_[channel];
  }
  std::vector<std::byte> scratch;
  const std::span<const std::byte> stored = ToStored(map, native, scratch);
  const size_t first =
      static_cast<size_t>(channel) * static_cast<size_t>(info_.size[2]) + static_cast<size_t>(z0);
  const size_t count = static_cast<size_t>(nz);

  // 1. Claim the planes; a plane received before is a replacement.
  bool replacement = false;
  {
    std::lock_guard claim(claim_mu_);
    for (size_t i = first; i < first + count; ++i) replacement = replacement || received_[i];
    if (!replacement) std::fill_n(received_.begin() + first, count, 1);
  }
  Status status;
  std::unique_lock<std::shared_mutex> exclusive;
  if (!replacement) {
    status = ingest_->Add(channel, z0, nz, stored);
    if (status.ok()) {
      histogram_.Add(channel, stored);
    } else {
      std::lock_guard claim(claim_mu_);
      std::fill_n(received_.begin() + first, count, 0);  // Counted when sent again.
    }
  } else {
    // 2. Replacing planes: alone (no other slab in flight), insert what is staged so that the
    // old planes are in the tree, subtract them from the histogram, then add the new ones.
    add.unlock();
    exclusive = std::unique_lock(add_mu_);
    {
      std::lock_guard lock(mu_);
      if (finished_ || !ingest_) {
        return FailedPreconditionError(name_ + ": the acquisition was finished; no more slabs");
      }
    }
    std::vector<uint8_t> was_received(received_.begin() + first, received_.begin() + first + count);
    status = ingest_->Flush();
    std::vector<std::vector<uint16_t>> old;
    for (size_t i = 0; status.ok() && i < count; ++i) {
      if (!was_received[i]) continue;
      const int64_t z = z0 + static_cast<int64_t>(i);
      std::vector<uint16_t> values(info_.PlaneVoxels());
      status =
          octree::ReadVoxels(*octree(), channel,
                             octree::Box{{0, 0, z}, {info_.size[0], info_.size[1], z + 1}}, values);
      old.push_back(std::move(values));
    }
    if (status.ok()) status = ingest_->Add(channel, z0, nz, stored);
    if (status.ok()) {
      for (const std::vector<uint16_t>& values : old) histogram_.Subtract(channel, values);
      histogram_.Add(channel, stored);
      std::lock_guard claim(claim_mu_);
      std::fill_n(received_.begin() + first, count, 1);
    }
  }
  // 3. Visible now, or within the latency.
  if (status.ok() && wait_visible) status = FlushIngest();
  if (status.ok() && !wait_visible) {
    {
      std::lock_guard lock(mu_);
      if (!flush_due_) flush_due_ = std::chrono::steady_clock::now() + flush_latency_;
    }
    cv_.notify_all();
  }
  RefreshCounters();
  return status;
}

Status Dataset::FlushIngest() {
  Status s = ingest_->Flush();
  if (!s.ok()) {
    // Staged planes stay staged (the next flush retries); viewers should know.
    std::lock_guard lock(mu_);
    error_ = s.ToString();
  }
  return s;
}

void Dataset::RefreshCounters() {
  uint64_t received = 0;
  {
    std::lock_guard claim(claim_mu_);
    received = static_cast<uint64_t>(std::count(received_.begin(), received_.end(), 1));
  }
  const uint64_t inserted = ingest_ ? ingest_->progress().planes_inserted : planes_inserted_;
  bool changed = false;
  {
    std::lock_guard lock(mu_);
    changed = received != planes_received_ || inserted != planes_inserted_;
    planes_received_ = received;
    planes_inserted_ = inserted;
  }
  if (changed) {
    cv_.notify_all();
    Notify();
  }
}

void Dataset::RunFlushTimer(std::stop_token stop) {
  std::unique_lock lock(mu_);
  while (!stop.stop_requested()) {
    if (!flush_due_) {
      cv_.wait(lock, stop, [&] { return flush_due_.has_value(); });
      continue;
    }
    const auto due = *flush_due_;
    if (std::chrono::steady_clock::now() < due) {
      cv_.wait_until(lock, stop, due, [] { return false; });
      continue;
    }
    flush_due_.reset();
    lock.unlock();
    {
      std::shared_lock add(add_mu_);
      if (ingest_) {
        try {
          if (FlushIngest().ok()) RefreshCounters();
        } catch (...) {
          // Exceptions never leave the thread; a failed flush is retried by the next one.
        }
      }
    }
    lock.lock();
  }
}

Status Dataset::Finish() {
  if (kind_ != Kind::kStream) {
    return FailedPreconditionError(name_ + ": not a streaming dataset");
  }
  std::lock_guard life(lifecycle_mu_);
  std::unique_lock add(add_mu_);
  return FinishLocked();
}

Status Dataset::FinishLocked() {
  {
    std::lock_guard lock(mu_);
    if (finished_) return Status::Ok();
    if (!ingest_ || !cache_) return FailedPreconditionError(name_ + ": the stream was closed");
  }
  Status s = FlushIngest();
  if (s.ok()) s = WriteHistogramFile(cache_dir_, histogram_.Snapshot(), identity_);
  if (s.ok()) s = cache_->Commit();
  if (!s.ok()) {
    SetError(s);
    return s;
  }
  RefreshCounters();
  ingest_.reset();
  insert_pool_.reset();
  MarkReady([&] {
    finished_ = true;
    error_.clear();
    missing_planes_ =
        static_cast<uint64_t>(info_.size[2]) * info_.channel_count() - planes_received_;
  });
  return Status::Ok();
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
  if (kind_ == Kind::kStream) {
    // An unfinished stream is committed as Finish does: what arrived stays viewable.
    std::unique_lock add(add_mu_);
    bool unfinished = false;
    {
      std::lock_guard lock(mu_);
      unfinished = !finished_ && ingest_ && cache_;
    }
    if (unfinished) (void)FinishLocked();
  }
  // The worker (a build, or the flush timer) stops first: it may wait for add_mu_.
  if (worker_.joinable()) {
    worker_.request_stop();
    cv_.notify_all();
    worker_.join();
  }
  std::unique_ptr<octree::OctreeCache> cache;
  {
    std::unique_lock add(add_mu_);
    ingest_.reset();
    insert_pool_.reset();
    std::lock_guard lock(mu_);
    if (!cache_ && state_ != DatasetState::kBuilding) return;  // Nothing open.
    tree_.store(nullptr, std::memory_order_release);
    cache = std::move(cache_);
    if (kind_ == Kind::kFile && state_ == DatasetState::kBuilding) state_ = DatasetState::kPending;
    if (kind_ == Kind::kFile && state_ == DatasetState::kReady && !histogram_complete_) {
      // Counting stopped with the worker; the next Open counts again.
    }
  }
  {
    std::lock_guard budget(budget_mu_);
    cache.reset();  // Octree, page cache (flushes what is dirty), store, lock.
  }
  cv_.notify_all();
  Notify();
}

}  // namespace octoscope::dataset
