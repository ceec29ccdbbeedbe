// Static files: how the server maps a request path onto the web client's files (docs/api.md,
// "Static files"): the file under the web root, its MIME type and its validator (ETag). Paths
// that could leave the root — "..", ".", empty or hidden segments, backslashes, NUL, symbolic
// links pointing outside — resolve to nothing (404), never to a file elsewhere.
//
// Thread safety: pure functions (they read the file system).
#ifndef OCTOSCOPE_NET_STATIC_FILES_H_
#define OCTOSCOPE_NET_STATIC_FILES_H_

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

namespace octoscope::net {

// "text/html; charset=utf-8", "text/javascript; charset=utf-8", "image/png", ...; by the
// extension (case-insensitive); "application/octet-stream" when unknown.
std::string_view MimeTypeFor(std::string_view path);

struct StaticFile {
  std::filesystem::path path;  // Canonical.
  uint64_t size = 0;
  std::string etag;  // Strong validator "\"<size hex>-<mtime ns hex>\"".
};

// The regular file that decoded request path `url_path` names below `root` (REQUIRES: canonical
// directory): "/" and paths ending in "/" mean that directory's index.html. nullopt when there
// is none or the path is refused.
std::optional<StaticFile> ResolveStaticFile(const std::filesystem::path& root,
                                            std::string_view url_path);

// True when an If-None-Match header value lists `etag` (weak comparison, "W/" ignored) or is "*".
bool EtagMatches(std::string_view if_none_match, std::string_view etag);

}  // namespace octoscope::net

#endif  // OCTOSCOPE_NET_STATIC_FILES_H_
