#include "dataset/dataset_registry.h"

#include <algorithm>
#include <system_error>

#include "dataset/stream_record.h"
#include "util/random_token.h"

namespace octoscope::dataset {
namespace {

namespace fs = std::filesystem;

constexpr char kDemoId[] = "demospecimen";

// File names a reader may accept (a folder is always tried: slice folders, OME-Zarr).
bool MayBeScan(const fs::path& path) {
  std::string name = path.filename().string();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  for (const char* ext :
       {".tif", ".tiff", ".btf", ".tf2", ".tf8", ".ome", ".ims", ".vvd", ".raw"}) {
    if (name.ends_with(ext)) return true;
  }
  return false;
}

uint64_t Fnv1a(std::string_view text, uint64_t h = 1469598103934665603ull) {
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

// Paths compared as the file system resolves them (a watched folder given another way).
fs::path Canonical(const fs::path& path) {
  std::error_code ec;
  fs::path canonical = fs::weakly_canonical(fs::absolute(path, ec), ec);
  return ec ? path.lexically_normal() : canonical;
}

}  // namespace

std::string ScanDatasetId(size_t root_index, const fs::path& relative_path) {
  // 60 bits of a hash of the folder number and the relative path, in base 32 (a-z, 0-9 minus
  // look-alikes are not needed: ids are not typed by hand).
  uint64_t h = Fnv1a(std::to_string(root_index) + ":" + relative_path.generic_string());
  static constexpr char kDigits[] = "0123456789abcdefghijklmnopqrstuv";
  std::string id(12, '0');
  for (int i = 11; i >= 0; --i) {
    id[i] = kDigits[h & 31];
    h >>= 5;
  }
  return id;
}

DatasetRegistry::DatasetRegistry(RegistryOptions options)
    : options_(std::move(options)),
      record_dir_(options_.state_dir.empty() ? fs::path() : StreamRecordDir(options_.state_dir)),
      hook_(std::make_shared<Hook>()) {
  hook_->registry = this;
}

Result<std::unique_ptr<DatasetRegistry>> DatasetRegistry::Create(const RegistryOptions& options) {
  std::error_code ec;
  for (const fs::path& dir : options.data_dirs) {
    if (!fs::is_directory(dir, ec)) return NotFoundError(dir.string() + ": not a folder");
  }
  fs::create_directories(options.cache_root, ec);
  if (ec) return IoError(options.cache_root.string() + ": cannot create: " + ec.message());
  std::unique_ptr<DatasetRegistry> registry(new DatasetRegistry(options));
  if (!registry->record_dir_.empty()) {
    OCTO_RETURN_IF_ERROR(EnsureStreamRecordDir(registry->record_dir_));
  }
  for (size_t i = 0; i < options.data_dirs.size(); ++i) registry->Scan(options.data_dirs[i], i);
  if (!registry->record_dir_.empty()) registry->RestoreStreams();
  return registry;
}

DatasetRegistry::~DatasetRegistry() { Close(); }

StreamSpec DatasetRegistry::StreamDefaults() const {
  StreamSpec spec;
  spec.cache_root = options_.cache_root;
  spec.ram_bytes = options_.ram_bytes;
  spec.flush_latency = options_.stream_flush_latency;
  spec.checkpoint_quiet = options_.stream_checkpoint_quiet;
  spec.checkpoint_interval = options_.stream_checkpoint_interval;
  spec.record_dir = record_dir_;
  spec.on_resume = [hook = hook_] {
    std::lock_guard<std::mutex> lock(hook->mu);
    if (hook->registry != nullptr) hook->registry->Rebalance();
  };
  return spec;
}

void DatasetRegistry::RestoreStreams() {
  auto found = ReadStreamRecords(record_dir_);
  if (!found.ok()) {
    restore_messages_.push_back("streams not restored: " + found.status().message());
    return;
  }
  for (FoundStreamRecord& f : *found) {
    if (!f.record.ok()) {
      restore_messages_.push_back("stream record skipped: " + f.record.status().message());
      continue;
    }
    const protocol::StreamRecord& record = *f.record;
    // Another cache root's stream (another configuration of the server): not ours to list.
    if (Canonical(record.cache) != Canonical(options_.cache_root / record.id)) continue;
    if (Find(record.id) != nullptr) {
      restore_messages_.push_back("stream " + record.id + " skipped: its id is taken");
      continue;
    }
    auto restored = Dataset::RestoreStream(record, StreamDefaults());
    if (!restored.ok()) {
      restore_messages_.push_back("stream record " + f.path.string() +
                                  " skipped: " + restored.status().message());
      continue;
    }
    const DatasetStatus status = (*restored)->status();
    if (status.state == DatasetState::kError) {
      restore_messages_.push_back("stream " + record.id + ": " + status.error);
    }
    for (const std::string& warning : status.warnings) {
      restore_messages_.push_back("stream " + record.id + ": " + warning);
    }
    std::lock_guard<std::mutex> lock(mu_);
    by_id_.emplace(record.id, *restored);
    ordered_.push_back(std::move(*restored));
  }
}

void DatasetRegistry::Scan(const fs::path& root, size_t root_index) {
  // A data folder that is itself one dataset (a slice folder, an OME-Zarr) is listed as such.
  if (TryAdd(root, root_index, root)) return;
  ScanFolder(root, root_index, root, 0);
}

void DatasetRegistry::ScanFolder(const fs::path& root, size_t root_index, const fs::path& folder,
                                 int depth) {
  std::error_code ec;
  std::vector<fs::path> entries;
  for (fs::directory_iterator it(folder, fs::directory_options::skip_permission_denied, ec), end;
       !ec && it != end; it.increment(ec)) {
    entries.push_back(it->path());
  }
  std::sort(entries.begin(), entries.end());
  for (const fs::path& path : entries) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (ordered_.size() >= options_.max_datasets) return;
    }
    if (path.filename().string().starts_with(".")) continue;
    if (fs::is_directory(path, ec)) {
      if (!TryAdd(root, root_index, path) && depth + 1 < options_.max_scan_depth) {
        ScanFolder(root, root_index, path, depth + 1);
      }
    } else if (MayBeScan(path)) {
      TryAdd(root, root_index, path);
    }
  }
}

bool DatasetRegistry::TryAdd(const fs::path& root, size_t root_index, const fs::path& path) {
  SourceSpec spec;
  // The path as scanned, links not followed: a link in one user's folder never takes the id of
  // (and so hides) the dataset it points to.
  spec.id = ScanDatasetId(root_index, path.lexically_relative(root));
  spec.path = path;
  spec.open = options_.open;
  spec.cache_root = options_.cache_root;
  spec.ram_bytes = options_.ram_bytes;
  std::shared_ptr<Dataset> dataset = Dataset::ForSource(spec);
  std::error_code ec;
  // Folders no reader accepts are containers (searched further); files with a scan's name that
  // cannot be read are listed with their error, so that users see why. A folder refused for
  // referring outside itself (a slice that links elsewhere) is both: listed with the refusal and
  // searched further.
  const bool folder = fs::is_directory(path, ec);
  if (dataset->status().state == DatasetState::kError && folder && !dataset->refers_outside()) {
    return false;
  }
  const bool search_further = folder && dataset->refers_outside();
  std::lock_guard<std::mutex> lock(mu_);
  if (by_id_.count(spec.id) != 0) return !search_further;
  by_id_.emplace(spec.id, dataset);
  ordered_.push_back(std::move(dataset));
  return !search_further;
}

std::vector<std::shared_ptr<Dataset>> DatasetRegistry::List() const {
  std::lock_guard<std::mutex> lock(mu_);
  return ordered_;
}

std::shared_ptr<Dataset> DatasetRegistry::Find(std::string_view id) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = by_id_.find(id);
  return it == by_id_.end() ? nullptr : it->second;
}

Result<std::shared_ptr<Dataset>> DatasetRegistry::Open(std::string_view id) {
  std::shared_ptr<Dataset> dataset = Find(id);
  if (dataset == nullptr) return NotFoundError("no dataset '" + std::string(id) + "'");
  OCTO_RETURN_IF_ERROR(dataset->Open());
  Rebalance();
  return dataset;
}

Result<std::shared_ptr<Dataset>> DatasetRegistry::CreateStream(
    const protocol::StreamRequest& request, const std::string& creator) {
  for (int attempt = 0; attempt < 8; ++attempt) {
    OCTO_ASSIGN_OR_RETURN(std::string hex, RandomHex(6));
    if (Find(hex) == nullptr) return AddStream(request, hex, creator, {});
  }
  return InternalError("no free stream id");
}

Result<std::shared_ptr<Dataset>> DatasetRegistry::CreateStreamWithId(
    const protocol::StreamRequest& request, const std::string& id, const std::string& creator) {
  return AddStream(request, id, creator, {});
}

Result<std::shared_ptr<Dataset>> DatasetRegistry::CreateWatchedStream(
    const protocol::StreamRequest& request, const fs::path& folder) {
  for (int attempt = 0; attempt < 8; ++attempt) {
    OCTO_ASSIGN_OR_RETURN(std::string hex, RandomHex(6));
    if (Find(hex) == nullptr) return AddStream(request, hex, "", Canonical(folder));
  }
  return InternalError("no free stream id");
}

std::shared_ptr<Dataset> DatasetRegistry::FindWatchedStream(const fs::path& folder) const {
  const fs::path canonical = Canonical(folder);
  const std::vector<std::shared_ptr<Dataset>> all = List();
  for (auto it = all.rbegin(); it != all.rend(); ++it) {
    if (!(*it)->watch_folder().empty() && Canonical((*it)->watch_folder()) == canonical) return *it;
  }
  return nullptr;
}

Result<std::shared_ptr<Dataset>> DatasetRegistry::AddStream(const protocol::StreamRequest& request,
                                                            const std::string& id,
                                                            const std::string& creator,
                                                            const fs::path& watch_folder) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return UnavailableError("the server is shutting down");
    if (by_id_.count(id) != 0) return FailedPreconditionError("dataset '" + id + "' exists");
  }
  StreamSpec spec = StreamDefaults();
  spec.id = id;
  SetStreamShape(request, spec);
  spec.creator = creator;
  spec.watch_folder = watch_folder;
  // The demo streams afresh on every start: it has no record.
  if (id == kDemoId) spec.record_dir.clear();
  std::error_code ec;
  fs::remove_all(options_.cache_root / id, ec);  // A fresh acquisition replaces an old one.
  OCTO_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> dataset, Dataset::CreateStream(spec));
  {
    std::lock_guard<std::mutex> lock(mu_);
    by_id_.emplace(id, dataset);
    ordered_.push_back(dataset);
  }
  Rebalance();
  return dataset;
}

void DatasetRegistry::Rebalance() {
  std::vector<std::shared_ptr<Dataset>> open;
  for (const auto& dataset : List()) {
    // Opening ones count too: their build or cache load starts with its share.
    const DatasetStatus status = dataset->status();
    if (status.open || status.state == DatasetState::kBuilding) open.push_back(dataset);
  }
  if (open.empty()) return;
  const uint64_t share = options_.ram_bytes / open.size();
  for (const auto& dataset : open) {
    if (dataset->ram_budget() != share) dataset->SetRamBudget(share);
  }
}

void DatasetRegistry::Close() {
  {
    std::lock_guard<std::mutex> lock(hook_->mu);
    hook_->registry = nullptr;
  }
  std::vector<std::shared_ptr<Dataset>> all;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    closed_ = true;
    all = ordered_;
  }
  for (const auto& dataset : all) dataset->Close();
}

std::string_view DemoDatasetId() { return kDemoId; }

}  // namespace octoscope::dataset
