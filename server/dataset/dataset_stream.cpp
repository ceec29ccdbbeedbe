// Dataset, the streaming half (dataset.h): creating and restoring streams, slabs, the timer that
// flushes and checkpoints, suspending and resuming, finishing, and the stream's record.
#include <algorithm>
#include <bit>
#include <cmath>
#include <random>
#include <system_error>

#include "dataset/cache_setup.h"
#include "dataset/dataset.h"
#include "dataset/stream_checkpoint.h"
#include "dataset/stream_record.h"
#include "io/tiff_planes.h"
#include "octree/voxel_reader.h"
#include "util/byte_swap.h"
#include "util/checked_math.h"
#include "util/durable_file.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// A failed checkpoint is retried this long after.
constexpr auto kCheckpointRetry = std::chrono::seconds(5);

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

void SetStreamShape(const protocol::StreamRequest& shape, StreamSpec& spec) {
  spec.name = shape.name;
  spec.size = shape.size;
  spec.channels = shape.channels;
  spec.dtype = shape.dtype;
  spec.spacing_um = shape.spacing_um;
  spec.channel_names = shape.channel_names;
}

Result<std::shared_ptr<Dataset>> Dataset::NewStream(const StreamSpec& spec) {
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
  d->checkpoint_quiet_ = spec.checkpoint_quiet;
  d->checkpoint_interval_ = spec.checkpoint_interval;
  d->creator_ = spec.creator;
  d->watch_folder_ = spec.watch_folder;
  d->record_dir_ = spec.record_dir;
  d->on_resume_ = spec.on_resume;
  d->ram_bytes_ = spec.ram_bytes;
  d->received_.assign(static_cast<size_t>(info.size[2]) * info.channel_count(), 0);
  d->maps_ = FixedMapping(info).value_maps;
  d->histogram_.Reset(d->maps_);
  return d;
}

Result<std::shared_ptr<Dataset>> Dataset::CreateStream(const StreamSpec& spec) {
  OCTO_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> d, NewStream(spec));
  d->identity_ = StreamIdentity(spec.id);
  d->created_unix_ms_ = std::chrono::duration_cast<std::chrono::milliseconds>(
                            std::chrono::system_clock::now().time_since_epoch())
                            .count();
  // A fresh resumable cache, checkpointed empty at once: from now on there is always a
  // checkpoint to resume from.
  const octree::BuildBudget budget = d->StreamBudget();
  OCTO_ASSIGN_OR_RETURN(
      std::unique_ptr<octree::OctreeCache> cache,
      octree::OctreeCache::CreateResumable(d->cache_dir_, d->identity_, d->StreamParams(),
                                           budget.page_bytes, FixedMapping(d->info_)));
  std::error_code ec;
  fs::remove(d->cache_dir_ / kHistogramFile, ec);
  OCTO_RETURN_IF_ERROR(cache->Checkpoint(d->CheckpointAttachmentsNow()));
  {
    std::lock_guard lock(d->mu_);
    d->state_ = DatasetState::kStreaming;
  }
  OCTO_RETURN_IF_ERROR(d->StartIngest(std::move(cache), budget));
  OCTO_RETURN_IF_ERROR(d->WriteRecord());
  return d;
}

Result<std::shared_ptr<Dataset>> Dataset::RestoreStream(const protocol::StreamRecord& record,
                                                        const StreamSpec& defaults) {
  StreamSpec spec = defaults;
  spec.id = record.id;
  SetStreamShape(record.shape, spec);
  spec.creator = record.creator;
  spec.watch_folder = record.watch;
  OCTO_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> d, NewStream(spec));
  d->created_unix_ms_ = record.created_unix_ms;
  d->warnings_ = record.warnings;
  const uint64_t total = static_cast<uint64_t>(d->info_.size[2]) * d->info_.channel_count();
  auto broken = [&](const std::string& why) {
    d->restore_error_ =
        "the stream's cache " + d->cache_dir_.string() + " " + why + "; what it received is lost";
    d->state_ = DatasetState::kError;
    d->error_ = d->restore_error_;
    return d;
  };
  auto contents = octree::OctreeCache::Inspect(d->cache_dir_);
  if (!contents.ok()) {
    return broken(contents.status().code() == StatusCode::kNotFound
                      ? "is missing"
                      : "is damaged (" + contents.status().message() + ")");
  }
  const octree::CacheManifest& manifest = contents->manifest;
  const volume::VolumeInfo& cached = manifest.params.info;
  if (cached.size != d->info_.size || cached.channel_count() != d->info_.channel_count() ||
      cached.dtype != d->info_.dtype) {
    return broken("holds another volume (" + cached.ToString() + ")");
  }
  d->identity_ = manifest.source;
  d->maps_ = manifest.mapping.value_maps;
  if (manifest.state == octree::CacheManifest::State::kComplete) {
    // Finished: it opens from its complete cache as any finished stream does.
    d->finished_ = true;
    d->state_ = DatasetState::kReady;
    auto histogram = ReadHistogramFile(d->cache_dir_, d->identity_, d->maps_);
    uint64_t received = total;
    if (histogram.ok()) {
      // Every received plane counted its voxels once.
      uint64_t voxels = 0;
      for (int c = 0; c < histogram->channels(); ++c) voxels += histogram->total(c);
      received = voxels / d->info_.PlaneVoxels();
      d->histogram_.Assign(std::move(*histogram));
      d->histogram_complete_ = true;
    }
    d->missing_planes_ =
        record.finished && record.missing_planes ? *record.missing_planes : total - received;
    d->planes_received_ = d->planes_inserted_ = total - *d->missing_planes_;
    // The cache is what counts: a record written before its Finish completed is brought up to
    // date (best effort; it is checked again at the next start).
    if (!record.finished) (void)d->WriteRecord();
    return d;
  }
  auto progress = ParseStreamAttachments(contents->attachments, d->info_.channel_count(),
                                         d->info_.size[2], d->identity_, d->maps_);
  if (!progress.ok()) return broken("is damaged (" + progress.status().message() + ")");
  d->received_ = std::move(progress->received);
  d->histogram_.Assign(std::move(progress->histogram));
  d->histogram_complete_ = true;
  d->planes_received_ = d->planes_inserted_ =
      static_cast<uint64_t>(std::count(d->received_.begin(), d->received_.end(), uint8_t{1}));
  d->state_ = DatasetState::kStreaming;
  if (contents->unclean) {
    d->AddWarning(d->UncleanStopWarning(d->received_));
  } else if (record.finished) {
    (void)d->WriteRecord();  // Its Finish did not complete: it is still streaming.
  }
  return d;
}

// ---------------------------------------------------------------------------------------------
// The stream's cache, ingest and timer.

octree::CacheParams Dataset::StreamParams() const {
  octree::CacheParams params;
  params.info = info_;
  params.brick_size = BrickSizeFor(info_, {0, 0, 0});
  params.threshold = 0;
  return params;
}

octree::BuildBudget Dataset::StreamBudget() const {
  uint64_t ram = 0;
  {
    std::lock_guard lock(mu_);
    ram = ram_bytes_;
  }
  return BuildBudgetFor(info_, BrickSizeFor(info_, {0, 0, 0}), ram);
}

octree::CheckpointAttachments Dataset::CheckpointAttachmentsNow() {
  StreamProgress progress;
  {
    std::lock_guard claim(claim_mu_);
    progress.received = received_;
  }
  progress.histogram = histogram_.Snapshot();
  return StreamAttachments(progress, info_.channel_count(), info_.size[2], identity_);
}

Status Dataset::StartIngest(std::unique_ptr<octree::OctreeCache> cache,
                            const octree::BuildBudget& budget) {
  const unsigned hardware = std::max(1u, std::thread::hardware_concurrency());
  auto pool = std::make_unique<WorkerPool>(static_cast<int>(std::min(hardware, 4u)));
  octree::IngestOptions options;
  options.staging_bytes = budget.staging_bytes;
  options.scratch_dir = cache_dir_;
  options.workers = pool.get();
  {
    std::lock_guard claim(claim_mu_);
    if (std::find(received_.begin(), received_.end(), 1) != received_.end()) {
      options.inserted = received_;  // Resumed: these planes are in the tree.
    }
  }
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<octree::SlabIngest> ingest,
                        octree::SlabIngest::Create(&cache->octree(), options));
  insert_pool_ = std::move(pool);
  ingest_ = std::move(ingest);
  {
    std::lock_guard lock(mu_);
    changed_since_checkpoint_ = false;
    last_checkpoint_ = Clock::now();
  }
  Publish(std::move(cache), budget.slab_bytes + budget.staging_bytes);
  return EnsureStreamTimer();
}

Status Dataset::EnsureStreamTimer() {
  if (stream_timer_.joinable()) return Status::Ok();
  try {
    stream_timer_ = std::jthread([this](std::stop_token stop) { RunStreamTimer(stop); });
  } catch (const std::system_error& e) {
    return ResourceExhaustedError(name_ + ": cannot start the stream's timer: " + e.what());
  }
  return Status::Ok();
}

void Dataset::RunStreamTimer(std::stop_token stop) {
  std::unique_lock lock(mu_);
  while (!stop.stop_requested()) {
    const auto now = Clock::now();
    std::optional<Clock::time_point> checkpoint_due;
    if (changed_since_checkpoint_ && !finished_ && cache_ != nullptr) {
      checkpoint_due = std::max(
          std::min(last_slab_ + checkpoint_quiet_, last_checkpoint_ + checkpoint_interval_),
          checkpoint_retry_);
    }
    const bool flush = flush_due_ && *flush_due_ <= now;
    const bool checkpoint = checkpoint_due && *checkpoint_due <= now;
    if (!flush && !checkpoint) {
      std::optional<Clock::time_point> next = flush_due_;
      if (checkpoint_due && (!next || *checkpoint_due < *next)) next = checkpoint_due;
      // Woken early when a flush becomes due (a slab staged meanwhile) or the first change
      // after a checkpoint arrives; the deadlines are then worked out again.
      const std::optional<Clock::time_point> flush_before = flush_due_;
      const bool changed_before = changed_since_checkpoint_;
      auto news = [&] {
        return flush_due_ != flush_before || changed_since_checkpoint_ != changed_before;
      };
      if (next) {
        cv_.wait_until(lock, stop, *next, news);
      } else {
        cv_.wait(lock, stop, news);
      }
      continue;
    }
    if (flush) flush_due_.reset();
    lock.unlock();
    // Exceptions never leave the thread; a failed flush or checkpoint is retried later.
    try {
      if (checkpoint) {
        std::unique_lock add(add_mu_);
        (void)CheckpointLocked();
      } else {
        std::shared_lock add(add_mu_);
        if (ingest_ && FlushIngest().ok()) RefreshCounters();
      }
    } catch (...) {
    }
    lock.lock();
  }
}

Status Dataset::CheckpointLocked() {
  octree::OctreeCache* cache = nullptr;
  {
    std::lock_guard lock(mu_);
    if (finished_ || !ingest_ || !cache_ || !changed_since_checkpoint_) return Status::Ok();
    cache = cache_.get();
  }
  // Everything staged goes into the tree first: the checkpoint holds every plane received.
  Status s = FlushIngest();
  if (s.ok()) s = cache->Checkpoint(CheckpointAttachmentsNow());
  {
    std::lock_guard lock(mu_);
    if (s.ok()) {
      changed_since_checkpoint_ = false;
      last_checkpoint_ = Clock::now();
    } else {
      checkpoint_retry_ = Clock::now() + kCheckpointRetry;
      error_ = name_ + ": checkpoint failed (retried): " + s.message();
    }
  }
  if (s.ok()) RefreshCounters();
  return s;
}

Status Dataset::ResumeStream() {
  bool resumed = false;
  Status s;
  {
    std::unique_lock add(add_mu_);
    s = ResumeLocked(&resumed);
  }
  if (!s.ok()) return s;
  if (resumed) {
    cv_.notify_all();
    Notify();
    if (on_resume_) on_resume_();
  }
  return s;
}

Status Dataset::ResumeLocked(bool* resumed) {
  *resumed = false;
  {
    std::lock_guard lock(mu_);
    if (!restore_error_.empty()) return FailedPreconditionError(name_ + ": " + restore_error_);
    if (finished_ || ingest_) return Status::Ok();
  }
  const octree::BuildBudget budget = StreamBudget();
  auto opened = octree::OctreeCache::Resume(cache_dir_, budget.page_bytes);
  if (!opened.ok()) {
    const Status s = opened.status().WithContext(name_ + ": resuming the stream");
    SetError(s);
    return s;
  }
  auto progress = ParseStreamAttachments(opened->attachments, info_.channel_count(), info_.size[2],
                                         identity_, value_maps());
  if (!progress.ok()) {
    const Status s = progress.status().WithContext(name_ + ": resuming the stream");
    SetError(s);
    return s;
  }
  // The checkpoint is the truth. It differs from what this process counted only when the last
  // checkpoint before the suspension failed, or after an unclean stop: then say what was lost.
  bool lost = opened->unclean;
  {
    std::lock_guard claim(claim_mu_);
    lost = lost || received_ != progress->received;
    received_ = progress->received;
  }
  histogram_.Assign(std::move(progress->histogram));
  const uint64_t received = static_cast<uint64_t>(
      std::count(progress->received.begin(), progress->received.end(), uint8_t{1}));
  {
    std::lock_guard lock(mu_);
    state_ = DatasetState::kStreaming;
    error_.clear();
    histogram_complete_ = true;
    planes_received_ = planes_inserted_ = received;
  }
  if (lost) AddWarning(UncleanStopWarning(progress->received));
  OCTO_RETURN_IF_ERROR(StartIngest(std::move(opened->cache), budget));
  *resumed = true;
  return Status::Ok();
}

std::vector<bool> Dataset::received_planes() const {
  std::lock_guard claim(claim_mu_);
  return std::vector<bool>(received_.begin(), received_.end());
}

// ---------------------------------------------------------------------------------------------
// Slabs.

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
  volume::ValueMap map;
  {
    std::lock_guard lock(mu_);
    map = maps_[channel];
  }
  std::vector<std::byte> scratch;
  const std::span<const std::byte> stored = ToStored(map, native, scratch);
  // A suspended stream is resumed and the slab tried again (a close may suspend it meanwhile).
  for (;;) {
    bool suspended = false;
    Status s = AddToOpenStream(channel, z0, nz, stored, wait_visible, &suspended);
    if (!suspended) return s;
    OCTO_RETURN_IF_ERROR(ResumeStream());
  }
}

Status Dataset::AddToOpenStream(int channel, int64_t z0, int64_t nz,
                                std::span<const std::byte> stored, bool wait_visible,
                                bool* suspended) {
  std::shared_lock add(add_mu_);
  octree::OctreeCache* cache = nullptr;
  {
    std::lock_guard lock(mu_);
    if (finished_) {
      return FailedPreconditionError(name_ + ": the acquisition was finished; no more slabs");
    }
    if (!restore_error_.empty()) return FailedPreconditionError(name_ + ": " + restore_error_);
    if (!ingest_) {
      *suspended = true;
      return Status::Ok();
    }
    cache = cache_.get();
  }
  // Durably "changed since the checkpoint" before anything changes (an unclean stop is then
  // recognised as one).
  OCTO_RETURN_IF_ERROR(cache->MarkDirty());
  bool first_change = false;
  {
    std::lock_guard lock(mu_);
    first_change = !changed_since_checkpoint_;
    changed_since_checkpoint_ = true;
    last_slab_ = Clock::now();
  }
  if (first_change) cv_.notify_all();  // The timer schedules a checkpoint.
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
      if (finished_) {
        return FailedPreconditionError(name_ + ": the acquisition was finished; no more slabs");
      }
      if (!ingest_ || cache_.get() != cache) {
        // Suspended (and perhaps resumed) meanwhile: the caller resumes it and tries again.
        *suspended = true;
        return Status::Ok();
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
  bool flush_scheduled = false;
  {
    std::lock_guard lock(mu_);
    last_slab_ = Clock::now();
    if (status.ok() && !wait_visible && !flush_due_) {
      flush_due_ = last_slab_ + flush_latency_;
      flush_scheduled = true;
    }
  }
  if (flush_scheduled) cv_.notify_all();
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

// ---------------------------------------------------------------------------------------------
// Finishing, releasing, the record.

Status Dataset::Finish() {
  if (kind_ != Kind::kStream) {
    return FailedPreconditionError(name_ + ": not a streaming dataset");
  }
  std::lock_guard life(lifecycle_mu_);
  bool resumed = false;
  Status s;
  {
    std::unique_lock add(add_mu_);
    s = ResumeLocked(&resumed);
    if (s.ok()) s = FinishLocked();
  }
  if (resumed && on_resume_) on_resume_();
  return s;
}

Status Dataset::FinishLocked() {
  {
    std::lock_guard lock(mu_);
    if (finished_) return Status::Ok();
    if (!ingest_ || !cache_) return FailedPreconditionError(name_ + ": the stream was closed");
  }
  // Checkpointed first (staged planes inserted): the cache is complete only once all of it is
  // in the pool, and until then the checkpoint is what a crash resumes from.
  Status s = CheckpointLocked();
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
    changed_since_checkpoint_ = false;
    missing_planes_ =
        static_cast<uint64_t>(info_.size[2]) * info_.channel_count() - planes_received_;
  });
  // The cache is complete whatever the record says; a stale record is corrected at the next
  // start (RestoreStream), so a failure here is only reported.
  if (Status recorded = WriteRecord(); !recorded.ok()) {
    std::lock_guard lock(mu_);
    error_ = recorded.message();
  }
  return Status::Ok();
}

Status Dataset::Release(std::chrono::milliseconds quiet) {
  std::lock_guard life(lifecycle_mu_);
  if (kind_ == Kind::kStream) {
    std::unique_lock add(add_mu_);  // No slab in flight from here on.
    {
      std::lock_guard lock(mu_);
      if (!finished_ && ingest_ && Clock::now() - last_slab_ < quiet) {
        return FailedPreconditionError(name_ + ": still receiving slabs; not released");
      }
    }
    // Checkpointed before it is closed; a failure keeps it open (CloseLocked would close it).
    OCTO_RETURN_IF_ERROR(CheckpointLocked());
  }
  CloseLocked();
  return Status::Ok();
}

Status Dataset::WriteRecord() {
  if (record_dir_.empty()) return Status::Ok();
  protocol::StreamRecord record;
  record.id = id_;
  protocol::StreamRequest& shape = record.shape;
  shape.name = name_;
  shape.size = info_.size;
  shape.channels = info_.channel_count();
  shape.dtype = info_.dtype;
  shape.spacing_um = spacing_um();
  for (const volume::ChannelInfo& c : info_.channels) shape.channel_names.push_back(c.name);
  if (std::all_of(shape.channel_names.begin(), shape.channel_names.end(),
                  [](const std::string& n) { return n.empty(); })) {
    shape.channel_names.clear();  // None given.
  }
  record.creator = creator_;
  record.watch = watch_folder_.string();
  record.cache = cache_dir_.string();
  record.created_unix_ms = created_unix_ms_;
  {
    std::lock_guard lock(mu_);
    record.finished = finished_;
    record.missing_planes = missing_planes_;
    record.warnings = warnings_;
  }
  return WriteStreamRecord(record_dir_, record);
}

void Dataset::AddWarning(const std::string& warning) {
  {
    std::lock_guard lock(mu_);
    if (std::find(warnings_.begin(), warnings_.end(), warning) != warnings_.end()) return;
    if (warnings_.size() >= protocol::kMaxStreamRecordWarnings) warnings_.erase(warnings_.begin());
    warnings_.push_back(warning);
  }
  // Kept with the record so that it is still shown after a later restart (best effort).
  (void)WriteRecord();
}

std::string Dataset::UncleanStopWarning(const std::vector<uint8_t>& received) const {
  const uint64_t total = static_cast<uint64_t>(info_.size[2]) * info_.channel_count();
  const uint64_t have =
      static_cast<uint64_t>(std::count(received.begin(), received.end(), uint8_t{1}));
  return "the server stopped without checkpointing this stream (killed or crashed): it resumed "
         "from its last checkpoint, and planes that arrived after it are lost; " +
         std::to_string(have) + " of " + std::to_string(total) +
         " planes are stored; send again every plane not stored: " +
         DescribeMissingPlanes(received, info_.channel_count(), info_.size[2]);
}

}  // namespace octoscope::dataset
