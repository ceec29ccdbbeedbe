// Reading files safely: positioned reads that fill a whole buffer (retrying interrupted and short
// reads, reporting the end of the file as corruption), and whole reads of small text files (a
// sidecar, an XML header) bounded by a size limit checked before anything is allocated.
//
// Thread safety: pure functions of the file system; ReadFully uses pread, which keeps no shared
// file offset, so many threads may read through one descriptor at once.
#ifndef OCTOSCOPE_UTIL_FILE_READING_H_
#define OCTOSCOPE_UTIL_FILE_READING_H_

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>

#include "util/result.h"

namespace octoscope {

// Owns a file descriptor (closed on destruction; -1 holds none).
class ScopedFd {
 public:
  explicit ScopedFd(int fd) : fd_(fd) {}
  ~ScopedFd();
  ScopedFd(const ScopedFd&) = delete;
  ScopedFd& operator=(const ScopedFd&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

// Reads exactly out.size() bytes at `offset` of the open descriptor `fd`. Errors (naming
// `path_for_messages`): IoError when the system refuses the read, CorruptError when the file ends
// before the buffer is full ("the file is truncated").
// REQUIRES: fd is open for reading.
Status ReadFully(int fd, uint64_t offset, std::span<std::byte> out,
                 std::string_view path_for_messages);

// The whole content of the regular file `path`. Errors: NotFound (no such file), Unsupported (not
// a regular file), ResourceExhausted (larger than `max_bytes`, refused unread), IoError.
Result<std::string> ReadSmallFile(const std::filesystem::path& path, uint64_t max_bytes);
// The same for a file already open for reading as `fd` (the caller keeps and closes it); `name`
// stands for it in messages.
Result<std::string> ReadSmallOpenFile(int fd, std::string_view name, uint64_t max_bytes);

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_FILE_READING_H_
