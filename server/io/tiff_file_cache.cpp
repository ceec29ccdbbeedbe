#include "io/tiff_file_cache.h"

#include <algorithm>
#include <utility>

namespace octoscope::io {

TiffFile::Limits TiffFileCache::PerFileLimits(TiffFile::Limits limits, size_t capacity) {
  limits.max_cached_bytes /= std::max<size_t>(capacity, 1);
  return limits;
}

TiffFileCache::TiffFileCache(TiffFile::Limits limits, size_t capacity, FileGate gate)
    : limits_(PerFileLimits(limits, capacity)),
      capacity_(capacity < 1 ? 1 : capacity),
      gate_(std::move(gate)) {}

Result<std::shared_ptr<TiffFile>> TiffFileCache::Get(const std::filesystem::path& path) {
  {
    std::lock_guard lock(mutex_);
    if (auto it = entries_.find(path.string()); it != entries_.end()) {
      order_.splice(order_.begin(), order_, it->second.position);
      return it->second.file;
    }
  }
  // Index the file outside the lock (it reads every IFD).
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<TiffFile> opened, TiffFile::Open(path, limits_, gate_));
  std::shared_ptr<TiffFile> file(std::move(opened));
  Put(path, file);
  return file;
}

void TiffFileCache::Put(const std::filesystem::path& path, std::shared_ptr<TiffFile> file) {
  std::lock_guard lock(mutex_);
  const std::string key = path.string();
  if (entries_.count(key) != 0) return;  // Another thread cached it first; keep that handle.
  order_.push_front(key);
  entries_.emplace(key, Entry{std::move(file), order_.begin()});
  while (entries_.size() > capacity_) {
    entries_.erase(order_.back());
    order_.pop_back();
  }
}

size_t TiffFileCache::size() const {
  std::lock_guard lock(mutex_);
  return entries_.size();
}

}  // namespace octoscope::io
