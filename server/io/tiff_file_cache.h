// TiffFileCache: a bounded set of open TiffFiles keyed by path, least recently used closed first,
// so a series of thousands of files never exhausts file descriptors. Handles are shared_ptrs:
// an evicted file stays open until the reads already using it finish.
//
// The files share one budget for the decoded pages TiffFile keeps (TiffFile::Limits::
// max_cached_bytes): each file opened here gets 1/capacity of it, so the cache as a whole keeps
// no more than one file alone would.
//
// Files are opened through the cache's FileGate (the reader's OpenOptions::file_gate).
//
// Invariant: at most `capacity` files are held by the cache (callers may briefly hold more).
// Thread safety: thread-safe. Opening (indexing) a file happens outside the lock, so other
// threads keep reading cached files meanwhile; if two threads open the same file at once, the
// first one cached wins and the other handle is dropped when its reader is done.
#ifndef OCTOSCOPE_IO_TIFF_FILE_CACHE_H_
#define OCTOSCOPE_IO_TIFF_FILE_CACHE_H_

#include <cstddef>
#include <filesystem>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include "io/file_gate.h"
#include "io/tiff_file.h"
#include "util/result.h"

namespace octoscope::io {

class TiffFileCache {
 public:
  // REQUIRES: capacity >= 1.
  TiffFileCache(TiffFile::Limits limits, size_t capacity, FileGate gate = FileGate());

  // `limits` with max_cached_bytes shared among `capacity` files: what the cache opens files with
  // (and what files opened elsewhere and Put here should be opened with).
  static TiffFile::Limits PerFileLimits(TiffFile::Limits limits, size_t capacity);

  // The open file at `path`, opening and indexing it when not cached.
  Result<std::shared_ptr<TiffFile>> Get(const std::filesystem::path& path);

  // Adds an already open file (e.g. one opened to check it); keeps an existing entry.
  void Put(const std::filesystem::path& path, std::shared_ptr<TiffFile> file);

  size_t size() const;
  size_t capacity() const { return capacity_; }
  // The gate every file is opened through.
  const FileGate& gate() const { return gate_; }

 private:
  using Order = std::list<std::string>;  // Most recently used first.
  struct Entry {
    std::shared_ptr<TiffFile> file;
    Order::iterator position;
  };

  const TiffFile::Limits limits_;
  const size_t capacity_;
  const FileGate gate_;
  mutable std::mutex mutex_;
  Order order_;                                     // GUARDED_BY(mutex_)
  std::unordered_map<std::string, Entry> entries_;  // GUARDED_BY(mutex_)
};

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_TIFF_FILE_CACHE_H_
