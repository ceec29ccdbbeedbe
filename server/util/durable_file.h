// Durable files: writes that survive a crash or power loss in one piece or not at all, for
// metadata (cache manifests, node tables). The content goes to "<path>.tmp", is fsynced, renamed
// over <path>, and the directory is fsynced so the rename itself is durable.
//
// Thread safety: pure functions of the file system; concurrent writers of the same path race
// (the last rename wins), never tear.
#ifndef OCTOSCOPE_UTIL_DURABLE_FILE_H_
#define OCTOSCOPE_UTIL_DURABLE_FILE_H_

#include <filesystem>
#include <string_view>

#include "util/status.h"

namespace octoscope {

// Replaces `path` atomically with `content`. Errors name the file and the failing step.
// `temp_suffix` names the temporary file (<path><temp_suffix>); writers that may race on one
// path from several processes give each process its own suffix.
// `mode`: the new file's permission bits (before the umask).
Status WriteFileDurably(const std::filesystem::path& path, std::string_view content,
                        std::string_view temp_suffix = ".tmp", unsigned mode = 0644);

// fsync()s a directory, making renames and removals inside it durable.
Status SyncDirectory(const std::filesystem::path& dir);

// 64-bit FNV-1a of `bytes`, continuing from `hash` (for checksums and identities; not
// cryptographic).
inline constexpr uint64_t kFnvOffsetBasis = 0xcbf29ce484222325ull;
uint64_t Fnv1a64(std::string_view bytes, uint64_t hash = kFnvOffsetBasis);

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_DURABLE_FILE_H_
