#include "net/static_files.h"

#include <sys/stat.h>

#include <cstdio>
#include <system_error>

#include "util/strings.h"

namespace octoscope::net {
namespace fs = std::filesystem;

std::string_view MimeTypeFor(std::string_view path) {
  struct Entry {
    std::string_view extension;
    std::string_view mime;
  };
  static constexpr Entry kTypes[] = {
      {".html", "text/html; charset=utf-8"},
      {".htm", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".json", "application/json"},
      {".map", "application/json"},
      {".txt", "text/plain; charset=utf-8"},
      {".png", "image/png"},
      {".jpg", "image/jpeg"},
      {".jpeg", "image/jpeg"},
      {".gif", "image/gif"},
      {".svg", "image/svg+xml"},
      {".ico", "image/x-icon"},
      {".webp", "image/webp"},
      {".woff2", "font/woff2"},
      {".woff", "font/woff"},
      {".wasm", "application/wasm"},
  };
  for (const Entry& e : kTypes) {
    if (EndsWithIgnoreCase(path, e.extension)) return e.mime;
  }
  return "application/octet-stream";
}

std::optional<StaticFile> ResolveStaticFile(const fs::path& root, std::string_view url_path) {
  if (url_path.empty() || url_path[0] != '/') return std::nullopt;
  std::string relative(url_path.substr(1));
  if (relative.empty() || relative.back() == '/') relative += "index.html";
  // Every segment must be an ordinary, visible name: no "", ".", "..", ".hidden".
  for (std::string_view segment : Split(relative, '/')) {
    if (segment.empty() || segment[0] == '.') return std::nullopt;
    for (char c : segment) {
      if (c == '\\' || c == '\0' || static_cast<unsigned char>(c) < 0x20) return std::nullopt;
    }
  }
  std::error_code ec;
  const fs::path candidate = fs::canonical(root / relative, ec);
  if (ec) return std::nullopt;
  // Symbolic links may point anywhere: the resolved file must still be below the root.
  auto [root_end, unused] = std::mismatch(root.begin(), root.end(), candidate.begin(),
                                          candidate.end());
  (void)unused;
  if (root_end != root.end()) return std::nullopt;
  struct stat st {};
  if (::stat(candidate.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return std::nullopt;
  StaticFile file;
  file.path = candidate;
  file.size = static_cast<uint64_t>(st.st_size);
  const uint64_t mtime_ns =
      static_cast<uint64_t>(st.st_mtim.tv_sec) * 1000000000ull + st.st_mtim.tv_nsec;
  char etag[64];
  std::snprintf(etag, sizeof etag, "\"%llx-%llx\"", static_cast<unsigned long long>(file.size),
                static_cast<unsigned long long>(mtime_ns));
  file.etag = etag;
  return file;
}

bool EtagMatches(std::string_view if_none_match, std::string_view etag) {
  auto strip_weak = [](std::string_view tag) {
    tag = TrimWhitespace(tag);
    if (tag.starts_with("W/")) tag.remove_prefix(2);
    return tag;
  };
  for (std::string_view candidate : Split(if_none_match, ',')) {
    candidate = TrimWhitespace(candidate);
    if (candidate == "*" || strip_weak(candidate) == strip_weak(etag)) return true;
  }
  return false;
}

}  // namespace octoscope::net
