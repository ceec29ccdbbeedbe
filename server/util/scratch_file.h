// ScratchFile: an anonymous temporary file for data that does not fit the RAM budget for a while
// (e.g. planes of an acquisition staged until a brick layer is complete). It has no name once
// created (O_TMPFILE, or created and unlinked at once), so nothing is left behind when the
// process ends in any way; its pages live in the kernel's page cache and on disk, not in the
// process's memory.
//
// Thread safety: WriteAt and ReadAt use pwrite/pread and may be called from several threads at
// once; concurrent accesses of overlapping byte ranges give unspecified bytes to the reader.
#ifndef OCTOSCOPE_UTIL_SCRATCH_FILE_H_
#define OCTOSCOPE_UTIL_SCRATCH_FILE_H_

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>

#include "util/result.h"
#include "util/status.h"

namespace octoscope {

class ScratchFile {
 public:
  // A new empty scratch file in `dir` (which must exist). Errors name the directory.
  static Result<std::unique_ptr<ScratchFile>> Create(const std::filesystem::path& dir);
  ~ScratchFile();
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;

  // Writes `data` at `offset`, growing the file as needed. IoError names the step (a full disk
  // included).
  Status WriteAt(uint64_t offset, std::span<const std::byte> data);
  // Reads exactly out.size() bytes at `offset`; bytes never written read as zeros up to the
  // file's end, and reading past the end is kCorrupt.
  Status ReadAt(uint64_t offset, std::span<std::byte> out) const;

 private:
  ScratchFile(int fd, std::filesystem::path dir) : fd_(fd), dir_(std::move(dir)) {}
  int fd_;
  std::filesystem::path dir_;
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_SCRATCH_FILE_H_
