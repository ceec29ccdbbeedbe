#include "io/file_gate.h"

#include <fcntl.h>
#include <limits.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <deque>
#include <optional>
#include <system_error>
#include <utility>
#include <vector>

#include "util/file_reading.h"

namespace octoscope::io {
namespace {

namespace fs = std::filesystem;

constexpr int kMaxSymlinks = 40;  // As the kernel allows before ELOOP.

// The components of `path` after `prefix` (an absolute, lexically normal folder); nullopt when
// `path` does not start with it. "." and empty components within the prefix are skipped.
std::optional<std::deque<std::string>> After(const fs::path& path, const fs::path& prefix) {
  auto p = path.begin();
  for (const fs::path& want : prefix) {
    if (want.empty()) continue;  // A trailing separator.
    while (p != path.end() && (p->empty() || *p == ".")) ++p;
    if (p == path.end() || *p != want) return std::nullopt;
    ++p;
  }
  std::deque<std::string> rest;
  for (; p != path.end(); ++p) rest.push_back(p->string());
  return rest;
}

fs::file_type TypeOfMode(mode_t mode) {
  if (S_ISREG(mode)) return fs::file_type::regular;
  if (S_ISDIR(mode)) return fs::file_type::directory;
  if (S_ISCHR(mode)) return fs::file_type::character;
  if (S_ISBLK(mode)) return fs::file_type::block;
  if (S_ISFIFO(mode)) return fs::file_type::fifo;
  if (S_ISSOCK(mode)) return fs::file_type::socket;
  return fs::file_type::unknown;
}

std::string Errno(int err) { return std::strerror(err); }

// Opens `path` for reading as the process may (an unconfined gate).
Result<int> OpenUnconfined(const fs::path& path) {
  const std::string name = path.string();
  const int fd = ::open(name.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) return NotFoundError(name + ": no such file");
    return IoError(name + ": cannot open: " + Errno(err));
  }
  return fd;
}

// Checks that the open `fd` is a regular file; closes it otherwise.
Result<int> RegularOrClose(int fd, const fs::path& path) {
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    ::close(fd);
    return IoError(path.string() + ": cannot stat: " + Errno(err));
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return UnsupportedError(path.string() + ": not a regular file");
  }
  return fd;
}

}  // namespace

// A path resolved beneath the gate's folder: the folders passed through (O_PATH descriptors, the
// gate's folder first, closed with the walk) and what the path names in the last of them.
class FileGate::Walk {
 public:
  Walk() = default;
  ~Walk() {
    for (int fd : folders_) ::close(fd);
  }
  Walk(const Walk&) = delete;
  Walk& operator=(const Walk&) = delete;

  bool at_root() const { return names_.empty(); }
  // REQUIRES: a folder was entered.
  int folder() const { return folders_.back(); }
  // Takes `fd` (the gate's folder, or folder `name` of folder()).
  void Enter(int fd, std::string name) {
    folders_.push_back(fd);
    if (folders_.size() > 1) names_.push_back(std::move(name));
  }
  // REQUIRES: !at_root().
  void Leave() {
    ::close(folders_.back());
    folders_.pop_back();
    names_.pop_back();
  }
  void LeaveAll() {
    while (!at_root()) Leave();
  }
  // The path names nothing from `rest` on. Its ".." components are still not allowed to step out of
  // the folder (the rest is read lexically: nothing that is not there can be a link).
  Status Missing(const std::deque<std::string>& rest) {
    missing.assign(rest.begin(), rest.end());
    size_t depth = names_.size();
    for (const std::string& part : missing) {
      if (part == "..") {
        if (depth == 0) return OutsideFolderError();
        --depth;
      } else if (!part.empty() && part != ".") {
        ++depth;
      }
    }
    return Status::Ok();
  }
  // The resolved path, below `root`.
  fs::path Path(const fs::path& root) const {
    fs::path p = root;
    for (const std::string& n : names_) p /= n;
    if (!leaf.empty()) p /= leaf;
    for (const std::string& m : missing) p /= m;
    return p;
  }

  bool found = false;
  std::string leaf;  // Found: the entry of folder() the path names; "" for folder() itself.
  mode_t mode = 0;   // Found: what the path names.
  // Not found: the components from the first that does not exist.
  std::vector<std::string> missing;

 private:
  std::vector<int> folders_;
  std::vector<std::string> names_;  // names_[i]: folders_[i + 1] in folders_[i].
};

FileGate::FileGate(fs::path spelled, fs::path root)
    : confined_(true), spelled_(std::move(spelled)), root_(std::move(root)) {}

Result<FileGate> FileGate::Within(const fs::path& folder) {
  std::error_code ec;
  fs::path spelled = fs::absolute(folder, ec).lexically_normal();
  if (!ec && spelled.filename().empty()) spelled = spelled.parent_path();
  const fs::path root = ec ? fs::path() : fs::weakly_canonical(spelled, ec);
  if (ec) return IoError(folder.string() + ": cannot resolve the path: " + ec.message());
  return FileGate(std::move(spelled), root);
}

Result<FileGate> FileGate::ForDataset(const fs::path& path) {
  // The path as if it were the folder: spelled and resolved.
  OCTO_ASSIGN_OR_RETURN(FileGate self, Within(path));
  std::error_code ec;
  if (fs::is_directory(self.root_, ec)) return self;
  OCTO_ASSIGN_OR_RETURN(FileGate gate, Within(self.spelled_.parent_path()));
  // The folder the file is listed in must be the folder the file really is in.
  const fs::path real_folder = self.root_.parent_path();
  if (gate.root_ != real_folder) gate.spelled_ = gate.root_ = real_folder;
  return gate;
}

Result<int> FileGate::OpenFolder(const fs::path& path) const {
  int dir = ::open("/", O_PATH | O_DIRECTORY | O_CLOEXEC);
  if (dir < 0) return IoError("/: cannot open: " + Errno(errno));
  for (const fs::path& part : root_.relative_path()) {
    const int fd = ::openat(dir, part.c_str(), O_PATH | O_NOFOLLOW | O_CLOEXEC);
    const int err = errno;
    struct stat st;
    const bool folder = fd >= 0 && ::fstat(fd, &st) == 0 && S_ISDIR(st.st_mode);
    ::close(dir);
    if (!folder) {
      if (fd >= 0) {
        ::close(fd);
        return OutsideFolderError();  // Now a link (or a file): it leads elsewhere.
      }
      if (err == ENOENT) return NotFoundError(path.string() + ": no such file or folder");
      return IoError(path.string() + ": cannot open: " + Errno(err));
    }
    dir = fd;
  }
  return dir;
}

Result<FileGate> FileGate::Pinned() const {
  if (!confined_) return *this;
  OCTO_ASSIGN_OR_RETURN(const int fd, OpenFolder(root_));
  FileGate pinned = *this;
  pinned.pinned_ = std::make_shared<const ScopedFd>(fd);
  return pinned;
}

Status FileGate::WalkTo(const fs::path& path, Walk& walk) const {
  std::error_code ec;
  const fs::path absolute = path.is_absolute() ? path : fs::absolute(path, ec);
  if (ec) return IoError(path.string() + ": cannot resolve the path: " + ec.message());
  std::optional<std::deque<std::string>> todo = After(absolute, spelled_);
  if (!todo) todo = After(absolute, root_);
  if (!todo) return OutsideFolderError();

  if (pinned_) {
    const int fd = ::fcntl(pinned_->get(), F_DUPFD_CLOEXEC, 0);
    if (fd < 0) return IoError(path.string() + ": cannot open: " + Errno(errno));
    walk.Enter(fd, "");
  } else {
    Result<int> folder = OpenFolder(path);
    if (!folder.ok() && folder.status().code() == StatusCode::kNotFound) {
      return walk.Missing(*todo);  // The folder is gone.
    }
    if (!folder.ok()) return folder.status();
    walk.Enter(*folder, "");
  }

  int links = 0;
  while (!todo->empty()) {
    std::string name = std::move(todo->front());
    todo->pop_front();
    if (name.empty() || name == ".") continue;
    if (name == "..") {
      if (walk.at_root()) return OutsideFolderError();
      walk.Leave();
      continue;
    }
    const int fd = ::openat(walk.folder(), name.c_str(), O_PATH | O_NOFOLLOW | O_CLOEXEC);
    if (fd < 0) {
      const int err = errno;
      if (err != ENOENT && err != ENOTDIR) {
        return IoError(path.string() + ": cannot open: " + Errno(err));
      }
      todo->push_front(std::move(name));
      return walk.Missing(*todo);
    }
    struct stat st;
    if (::fstat(fd, &st) != 0) {
      const int err = errno;
      ::close(fd);
      return IoError(path.string() + ": cannot stat: " + Errno(err));
    }
    if (S_ISDIR(st.st_mode)) {
      walk.Enter(fd, std::move(name));
      continue;
    }
    if (S_ISLNK(st.st_mode)) {
      char target[PATH_MAX + 1];
      const ssize_t n = ::readlinkat(fd, "", target, sizeof target);
      const int err = errno;
      ::close(fd);
      if (n < 0) return IoError(path.string() + ": cannot read a link: " + Errno(err));
      if (static_cast<size_t>(n) >= sizeof target || ++links > kMaxSymlinks) {
        return IoError(path.string() + ": too many levels of symbolic links");
      }
      const fs::path to(std::string(target, static_cast<size_t>(n)));
      std::deque<std::string> parts;
      if (to.is_absolute()) {
        std::optional<std::deque<std::string>> inside = After(to, spelled_);
        if (!inside) inside = After(to, root_);
        if (!inside) return OutsideFolderError();
        walk.LeaveAll();
        parts = std::move(*inside);
      } else {
        for (const fs::path& part : to) parts.push_back(part.string());
      }
      todo->insert(todo->begin(), parts.begin(), parts.end());
      continue;
    }
    ::close(fd);
    if (!todo->empty()) {  // "file/more": names nothing.
      todo->push_front(std::move(name));
      return walk.Missing(*todo);
    }
    walk.found = true;
    walk.leaf = std::move(name);
    walk.mode = st.st_mode;
    return Status::Ok();
  }
  walk.found = true;
  walk.mode = S_IFDIR;
  return Status::Ok();
}

Result<fs::path> FileGate::Resolve(const fs::path& path) const {
  if (!confined_) return path;
  Walk walk;
  OCTO_RETURN_IF_ERROR(WalkTo(path, walk));
  // What follows a missing component is not resolved: refuse to guess where ".." would lead.
  if (std::find(walk.missing.begin(), walk.missing.end(), "..") != walk.missing.end()) {
    return NotFoundError(path.string() + ": no such file or folder");
  }
  return walk.Path(root_);
}

Result<fs::file_type> FileGate::Type(const fs::path& path) const {
  if (!confined_) {
    std::error_code ec;
    const fs::file_status status = fs::status(path, ec);
    return ec ? fs::file_type::not_found : status.type();
  }
  Walk walk;
  OCTO_RETURN_IF_ERROR(WalkTo(path, walk));
  return walk.found ? TypeOfMode(walk.mode) : fs::file_type::not_found;
}

Result<int> FileGate::OpenForReading(const fs::path& path) const {
  if (!confined_) {
    OCTO_ASSIGN_OR_RETURN(const int fd, OpenUnconfined(path));
    return RegularOrClose(fd, path);
  }
  Walk walk;
  OCTO_RETURN_IF_ERROR(WalkTo(path, walk));
  if (!walk.found) return NotFoundError(path.string() + ": no such file");
  if (!S_ISREG(walk.mode)) return UnsupportedError(path.string() + ": not a regular file");
  const int fd =
      ::openat(walk.folder(), walk.leaf.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
  if (fd < 0) {
    const int err = errno;
    if (err == ELOOP) return OutsideFolderError();  // Replaced by a link since it was resolved.
    if (err == ENOENT) return NotFoundError(path.string() + ": no such file");
    return IoError(path.string() + ": cannot open: " + Errno(err));
  }
  return RegularOrClose(fd, path);
}

Result<std::string> FileGate::ReadSmallFile(const fs::path& path, uint64_t max_bytes) const {
  OCTO_ASSIGN_OR_RETURN(const int fd, OpenForReading(path));
  ScopedFd owned(fd);
  return ReadSmallOpenFile(fd, path.string(), max_bytes);
}

Status OutsideFolderError() { return PermissionDeniedError(std::string(kOutsideFolderMessage)); }

bool IsOutsideFolderError(const Status& status) {
  return status.code() == StatusCode::kPermissionDenied;
}

Status OutsideFolderErrorOf(const Status& status, const fs::path& dataset) {
  if (!IsOutsideFolderError(status)) return status;
  return OutsideFolderError().WithContext(dataset.string());
}

}  // namespace octoscope::io
