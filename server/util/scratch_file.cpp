#include "util/scratch_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

#include "util/file_reading.h"

namespace octoscope {
namespace {

Status Errno(const std::string& what, const std::filesystem::path& dir, int err) {
  return IoError("scratch file in " + dir.string() + ": " + what + ": " + std::strerror(err));
}

}  // namespace

Result<std::unique_ptr<ScratchFile>> ScratchFile::Create(const std::filesystem::path& dir) {
  int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd < 0 && (errno == EOPNOTSUPP || errno == EISDIR || errno == ENOENT)) {
    // File systems without O_TMPFILE: a unique name, unlinked at once.
    std::string name = (dir / "octoscope-scratch-XXXXXX").string();
    fd = ::mkostemp(name.data(), O_CLOEXEC);
    if (fd >= 0) ::unlink(name.c_str());
  }
  if (fd < 0) return Errno("create", dir, errno);
  return std::unique_ptr<ScratchFile>(new ScratchFile(fd, dir));
}

ScratchFile::~ScratchFile() { ::close(fd_); }

Status ScratchFile::WriteAt(uint64_t offset, std::span<const std::byte> data) {
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n =
        ::pwrite(fd_, data.data() + done, data.size() - done, static_cast<off_t>(offset + done));
    if (n < 0) {
      if (errno == EINTR) continue;
      return Errno("pwrite", dir_, errno);
    }
    if (n == 0) return Errno("pwrite", dir_, ENOSPC);  // No progress: treat as a full disk.
    done += static_cast<size_t>(n);
  }
  return Status::Ok();
}

Status ScratchFile::ReadAt(uint64_t offset, std::span<std::byte> out) const {
  return ReadFully(fd_, offset, out, (dir_ / "<scratch file>").string());
}

}  // namespace octoscope
