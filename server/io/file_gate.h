// FileGate: which files a reader may touch. `octoscope serve` admits a dataset to a user by its
// own file or folder (a folder grant, docs/server.md "Users and access"); what that file refers
// to — the files an OME companion or master names, a BinaryOnly MetadataFile, a slice that is a
// symbolic link, a raw sidecar's data file, a Zarr chunk — must lie inside that grant too. A
// confined gate admits only paths inside one folder: the dataset's own folder (the folder that
// holds its main file, or the dataset's folder itself), which every grant admitting the dataset
// contains. The server's readers go through the gate (OpenOptions::file_gate) for every file they
// open, stat or list; the default gate admits every path (the command-line tools run with the
// invoking user's own permissions).
//
// Confinement: a path is resolved component by component beneath the folder, as the kernel
// resolves it — symbolic links are followed (an absolute target must name the folder), `..` steps
// up — but a step out of the folder is refused at once, before anything outside is looked at. So
// a refusal never depends on what lies outside (not even on whether the named file exists), and
// it is always the same status: kPermissionDenied with kOutsideFolderMessage, which names no
// path. Files are then opened beneath the folder without following any symbolic link (the folder
// itself from `/`, one component at a time), so a component replaced by a link after it was
// resolved is refused, never followed.
//
// Thread safety: an immutable value; every member function may be called from any thread.
#ifndef OCTOSCOPE_IO_FILE_GATE_H_
#define OCTOSCOPE_IO_FILE_GATE_H_

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>

#include "util/file_reading.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::io {

// The whole message of a refusal (no path: the dataset that refers outside is named by
// OutsideFolderErrorOf).
inline constexpr std::string_view kOutsideFolderMessage =
    "it refers to a file outside its own folder";

class FileGate {
 public:
  // Admits every path.
  FileGate() = default;
  // Admits the paths inside `folder` (resolved now; it need not exist yet).
  static Result<FileGate> Within(const std::filesystem::path& folder);
  // The gate of the dataset whose main file or folder is `path`: within the folder itself, or
  // within the folder that holds the file after resolving symbolic links. A main file that is a
  // link into another folder is outside the folder it is listed in: every path is refused then.
  static Result<FileGate> ForDataset(const std::filesystem::path& path);

  bool confined() const { return confined_; }

  // The same gate holding its folder open (once resolved from "/" as every walk does), so that
  // each path is resolved from there: for readers that open many files (Zarr chunks). The folder
  // stays the one opened even if it is moved. Unconfined: a copy.
  Result<FileGate> Pinned() const;

  // Where `path` leads: `path` itself when unconfined; confined, the resolved path inside the
  // folder (no symbolic links; it may name nothing), or a refusal.
  Result<std::filesystem::path> Resolve(const std::filesystem::path& path) const;
  // What `path` leads to, as std::filesystem::status says (not_found when nothing or when it
  // cannot be examined), or a refusal.
  Result<std::filesystem::file_type> Type(const std::filesystem::path& path) const;
  // Opens the regular file `path` for reading; the caller owns (closes) the descriptor. Errors
  // name `path`: NotFound ("no such file"), Unsupported ("not a regular file"), IoError, or a
  // refusal. Never blocks on a FIFO.
  Result<int> OpenForReading(const std::filesystem::path& path) const;
  // The whole regular file `path` (ReadSmallFile through the gate).
  Result<std::string> ReadSmallFile(const std::filesystem::path& path, uint64_t max_bytes) const;

 private:
  class Walk;
  FileGate(std::filesystem::path spelled, std::filesystem::path root);
  // Opens the folder from "/" without following links; NotFound when it is gone.
  Result<int> OpenFolder(const std::filesystem::path& path) const;
  // Resolves `path` beneath the folder into `walk`. REQUIRES: confined().
  Status WalkTo(const std::filesystem::path& path, Walk& walk) const;

  bool confined_ = false;
  // The folder as readers spell it (absolute, lexically normal), and resolved (canonical).
  std::filesystem::path spelled_;
  std::filesystem::path root_;
  std::shared_ptr<const ScopedFd> pinned_;  // The folder, held open (Pinned()).
};

// The refusal: kPermissionDenied, kOutsideFolderMessage.
Status OutsideFolderError();
bool IsOutsideFolderError(const Status& status);
// `status`; a refusal becomes the one refusal of the dataset at `dataset`, whatever context was
// added to it: "permission denied: <dataset>: it refers to a file outside its own folder".
Status OutsideFolderErrorOf(const Status& status, const std::filesystem::path& dataset);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_FILE_GATE_H_
