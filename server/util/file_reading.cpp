#include "util/file_reading.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace octoscope {
ScopedFd::~ScopedFd() {
  if (fd_ >= 0) ::close(fd_);
}

Status ReadFully(int fd, uint64_t offset, std::span<std::byte> out,
                 std::string_view path_for_messages) {
  size_t done = 0;
  while (done < out.size()) {
    // One call reads at most 1 GiB: some kernels cap a single read below 2 GiB anyway.
    const size_t want = std::min<size_t>(out.size() - done, size_t{1} << 30);
    const ssize_t n = ::pread(fd, out.data() + done, want, static_cast<off_t>(offset + done));
    if (n < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      return IoError(std::string(path_for_messages) + ": read of " + std::to_string(out.size()) +
                     " bytes at offset " + std::to_string(offset) +
                     " failed: " + std::strerror(err));
    }
    if (n == 0) {
      return CorruptError(std::string(path_for_messages) + ": the file ends at offset " +
                          std::to_string(offset + done) + ", " + std::to_string(out.size()) +
                          " bytes were needed from offset " + std::to_string(offset) +
                          ": the file is truncated");
    }
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

Result<std::string> ReadSmallFile(const std::filesystem::path& path, uint64_t max_bytes) {
  const std::string name = path.string();
  ScopedFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) return NotFoundError(name + ": no such file");
    return IoError(name + ": cannot open: " + std::strerror(err));
  }
  return ReadSmallOpenFile(fd.get(), name, max_bytes);
}

Result<std::string> ReadSmallOpenFile(int fd, std::string_view name, uint64_t max_bytes) {
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    return IoError(std::string(name) + ": cannot stat: " + std::strerror(err));
  }
  if (!S_ISREG(st.st_mode)) return UnsupportedError(std::string(name) + ": not a regular file");
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  if (size > max_bytes) {
    return ResourceExhaustedError(std::string(name) + ": " + std::to_string(size) +
                                  " bytes, more than the limit of " + std::to_string(max_bytes) +
                                  " for this kind of file");
  }
  std::string text(static_cast<size_t>(size), '\0');
  OCTO_RETURN_IF_ERROR(
      ReadFully(fd, 0, std::as_writable_bytes(std::span<char>(text.data(), text.size())), name));
  return text;
}

}  // namespace octoscope
