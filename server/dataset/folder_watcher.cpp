#include "dataset/folder_watcher.h"

#include <algorithm>
#include <condition_variable>
#include <fstream>
#include <sstream>

#include "io/slice_names.h"
#include "protocol/dataset_json.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;

bool IsTiffName(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return (ext == ".tif" || ext == ".tiff") && !path.filename().string().starts_with(".");
}

Result<std::vector<std::byte>> ReadWhole(const fs::path& path, uint64_t max_bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return IoError(path.string() + ": cannot open");
  in.seekg(0, std::ios::end);
  const auto size = static_cast<uint64_t>(in.tellg());
  if (size > max_bytes)
    return ResourceExhaustedError(path.string() + ": larger than a plane may be");
  in.seekg(0);
  std::vector<std::byte> bytes(size);
  in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(size));
  if (!in) return IoError(path.string() + ": read failed");
  return bytes;
}

}  // namespace

Result<std::unique_ptr<FolderWatcher>> FolderWatcher::Start(DatasetRegistry* registry,
                                                            const fs::path& dir, Logger* logger,
                                                            const WatchOptions& options) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return NotFoundError(dir.string() + ": not a folder (--watch)");
  std::unique_ptr<FolderWatcher> watcher(new FolderWatcher);
  watcher->registry_ = registry;
  watcher->logger_ = logger;
  watcher->dir_ = dir;
  watcher->options_ = options;
  watcher->thread_ = std::jthread([w = watcher.get()](std::stop_token stop) { w->Run(stop); });
  return watcher;
}

FolderWatcher::~FolderWatcher() {
  thread_.request_stop();
  if (thread_.joinable()) thread_.join();
}

WatchStats FolderWatcher::stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_;
}

void FolderWatcher::Report(const std::string& message) {
  logger_->Log(LogLevel::kWarning, "watch " + dir_.string() + ": " + message);
  std::lock_guard<std::mutex> lock(mu_);
  stats_.last_error = message;
}

void FolderWatcher::Run(std::stop_token stop) {
  std::mutex mu;
  std::condition_variable_any cv;
  while (!stop.stop_requested() && !finished_) {
    // Exceptions never leave the watcher's thread (bad_alloc on a huge file, for instance).
    try {
      if (dataset_ == nullptr) {
        ReadSidecar();
      } else {
        Poll();
      }
    } catch (const std::exception& e) {
      Report(std::string("internal error: ") + e.what());
    }
    std::unique_lock<std::mutex> lock(mu);
    cv.wait_for(lock, stop, options_.poll_interval, [] { return false; });
  }
}

void FolderWatcher::ReadSidecar() {
  const fs::path sidecar = dir_ / kWatchSidecarName;
  std::error_code ec;
  if (!fs::is_regular_file(sidecar, ec)) return;
  auto bytes = ReadWhole(sidecar, protocol::kMaxStreamRequestBytes);
  if (!bytes.ok()) return;
  const std::string text(reinterpret_cast<const char*>(bytes->data()), bytes->size());
  auto request =
      protocol::ParseStreamRequest(text, protocol::StreamRequestKind::kSidecar, sidecar.string());
  if (!request.ok()) {
    // The sidecar may still be being written: report each distinct problem once.
    if (stats().last_error != request.status().message()) Report(request.status().message());
    return;
  }
  if (request->name.empty()) request->name = dir_.filename().string();
  index_base_ = request->index_base;
  received_.assign(static_cast<size_t>(request->channels) * request->size[2], false);
  // The folder's stream from before a restart goes on, if it is this acquisition.
  std::shared_ptr<Dataset> previous = registry_->FindWatchedStream(dir_);
  if (previous != nullptr) {
    const volume::VolumeInfo& info = previous->info();
    const DatasetStatus status = previous->status();
    if (status.state == DatasetState::kError) {
      // Its cache is lost; the folder still holds the planes.
      Report("stream " + previous->id() + " cannot go on (" + status.error +
             "); streaming the folder into a new dataset");
    } else if (info.size == request->size && info.channel_count() == request->channels &&
               info.dtype == request->dtype) {
      Resume(std::move(previous));
      return;
    } else {
      Report("the sidecar describes another acquisition than stream " + previous->id() +
             "; streaming into a new dataset");
    }
  }
  auto created = registry_->CreateWatchedStream(*request, dir_);
  if (!created.ok()) {
    Report("cannot create the stream: " + created.status().message());
    finished_ = true;
    return;
  }
  dataset_ = *created;
  logger_->Log(LogLevel::kInfo,
               "watch " + dir_.string() + ": streaming into dataset " + dataset_->id());
  std::lock_guard<std::mutex> lock(mu_);
  stats_.dataset_id = dataset_->id();
}

void FolderWatcher::Resume(std::shared_ptr<Dataset> dataset) {
  dataset_ = std::move(dataset);
  const DatasetStatus status = dataset_->status();
  if (status.state == DatasetState::kReady) {
    finished_ = true;
    logger_->Log(LogLevel::kInfo,
                 "watch " + dir_.string() + ": dataset " + dataset_->id() + " is complete already");
  } else {
    // Planes received before are not read again: their files are taken as ingested.
    already_received_ = dataset_->received_planes();
    received_ = already_received_;
    logger_->Log(LogLevel::kInfo,
                 "watch " + dir_.string() + ": resuming dataset " + dataset_->id() + " (" +
                     std::to_string(status.planes_received) + " of " +
                     std::to_string(status.planes_total) + " planes received before)");
  }
  std::lock_guard<std::mutex> lock(mu_);
  stats_.dataset_id = dataset_->id();
}

std::optional<std::pair<int, int64_t>> FolderWatcher::PlaneOf(
    const fs::path& path, std::optional<uint64_t> folder_channel) {
  auto name = io::ParsePlaneName(path.stem().string());
  const int channels = dataset_->info().channel_count();
  std::optional<uint64_t> channel =
      folder_channel ? folder_channel : (name.ok() ? name->channel : std::nullopt);
  if (!name.ok()) return std::nullopt;
  const int64_t z = static_cast<int64_t>(name->z) - index_base_;
  int64_t c = channel ? static_cast<int64_t>(*channel) - index_base_ : 0;
  if (!channel && channels > 1) return std::nullopt;  // Which channel is ambiguous.
  if (c < 0 || c >= channels || z < 0 || z >= dataset_->info().size[2]) return std::nullopt;
  return std::pair<int, int64_t>{static_cast<int>(c), z};
}

void FolderWatcher::Poll() {
  std::error_code ec;
  std::vector<std::pair<fs::path, std::optional<uint64_t>>> candidates;
  for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& p = it->path();
    if (it->is_directory(ec)) {
      if (auto c = io::ChannelFolderNumber(p.filename().string())) {
        std::error_code sub_ec;
        for (fs::directory_iterator sub(p, sub_ec), sub_end; !sub_ec && sub != sub_end;
             sub.increment(sub_ec)) {
          if (IsTiffName(sub->path())) candidates.emplace_back(sub->path(), c);
        }
      }
    } else if (IsTiffName(p)) {
      candidates.emplace_back(p, std::nullopt);
    }
  }
  std::sort(candidates.begin(), candidates.end());
  for (const auto& [path, folder_channel] : candidates) {
    auto plane = PlaneOf(path, folder_channel);
    if (!plane) {
      FileState& state = files_[path];
      if (!state.reported) {
        state.reported = true;
        Report(path.filename().string() + ": the name gives no plane of this acquisition");
      }
      continue;
    }
    Consider(path, plane->first, plane->second);
  }
  if (!finished_ && std::all_of(received_.begin(), received_.end(), [](bool r) { return r; })) {
    Status status = dataset_->Finish();
    finished_ = true;
    if (!status.ok()) {
      Report("finishing: " + status.message());
    } else {
      logger_->Log(LogLevel::kInfo, "watch " + dir_.string() + ": acquisition complete");
    }
  }
}

void FolderWatcher::Consider(const fs::path& path, int channel, int64_t z) {
  std::error_code ec;
  const uint64_t size = fs::file_size(path, ec);
  if (ec) return;
  const fs::file_time_type mtime = fs::last_write_time(path, ec);
  if (ec) return;
  const auto now = std::chrono::steady_clock::now();
  FileState& state = files_[path];
  const size_t plane = static_cast<size_t>(channel) * dataset_->info().size[2] + z;
  if (state.stable_since == decltype(now){} && !already_received_.empty() &&
      already_received_[plane]) {
    // A resumed stream received this plane before the restart: its file counts as ingested
    // until it changes.
    state = FileState{size, mtime, now, true, false};
    return;
  }
  if (state.size != size || state.mtime != mtime || state.stable_since == decltype(now){}) {
    // New or still changing: wait until it has been quiet for settle_time.
    state = FileState{size, mtime, now, false, false};
    return;
  }
  if (state.done || state.reported || now - state.stable_since < options_.settle_time) return;
  auto bytes = ReadWhole(path, kMaxTiffSlabBytes);
  Status status = bytes.ok() ? dataset_->AddTiffSlab(channel, z, 1, *bytes, false) : bytes.status();
  if (status.ok()) {
    state.done = true;
    received_[plane] = true;
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.planes_ingested;
    return;
  }
  if (status.code() == StatusCode::kFailedPrecondition) {
    finished_ = true;  // The dataset was finished or closed elsewhere.
    return;
  }
  // Not decodable yet: a writer that pauses mid-file looks quiet. Give it time, then report.
  if (now - state.stable_since >= options_.give_up_after) {
    state.reported = true;
    Report(path.filename().string() + ": " + status.message());
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.bad_files;
  }
}

}  // namespace octoscope::dataset
