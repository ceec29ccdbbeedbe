#include "util/durable_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

namespace octoscope {
namespace {

Status Errno(const std::filesystem::path& path, const char* step) {
  return IoError(path.string() + ": " + step + ": " + std::strerror(errno));
}

}  // namespace

Status WriteFileDurably(const std::filesystem::path& path, std::string_view content,
                        std::string_view temp_suffix, unsigned mode) {
  std::filesystem::path tmp = path;
  tmp += temp_suffix;
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, static_cast<mode_t>(mode));
  if (fd < 0) return Errno(tmp, "open");
  // Write everything, retrying short writes and interrupted calls.
  size_t done = 0;
  while (done < content.size()) {
    ssize_t n = ::write(fd, content.data() + done, content.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      Status s = Errno(tmp, "write");
      ::close(fd);
      ::unlink(tmp.c_str());
      return s;
    }
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) {
    Status s = Errno(tmp, "fsync");
    ::close(fd);
    ::unlink(tmp.c_str());
    return s;
  }
  if (::close(fd) != 0) return Errno(tmp, "close");
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    Status s = Errno(path, "rename");
    ::unlink(tmp.c_str());
    return s;
  }
  return SyncDirectory(path.has_parent_path() ? path.parent_path() : ".");
}

Status SyncDirectory(const std::filesystem::path& dir) {
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return Errno(dir, "open directory");
  int rc = ::fsync(fd);
  Status s = rc == 0 ? Status::Ok() : Errno(dir, "fsync directory");
  ::close(fd);
  return s;
}

uint64_t Fnv1a64(std::string_view bytes, uint64_t hash) {
  for (unsigned char c : bytes) {
    hash ^= c;
    hash *= 0x100000001b3ull;
  }
  return hash;
}

}  // namespace octoscope
