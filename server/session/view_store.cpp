#include "session/view_store.h"

#include <sys/random.h>
#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <system_error>
#include <utility>

#include "util/durable_file.h"
#include "util/file_reading.h"

namespace octoscope::session {
namespace fs = std::filesystem;

Result<std::string> RandomBase64Url(int bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";
  unsigned char raw[64];
  if (bytes < 1 || bytes > 64) return InvalidArgumentError("RandomBase64Url: bad length");
  size_t got = 0;
  while (got < static_cast<size_t>(bytes)) {
    const ssize_t n = getrandom(raw + got, bytes - got, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return InternalError(std::string("getrandom: ") + std::strerror(errno));
    got += static_cast<size_t>(n);
  }
  // Six bits per character, most significant first; the last character holds what is left.
  std::string out;
  uint32_t buffer = 0;
  int bits = 0;
  for (int i = 0; i < bytes; ++i) {
    buffer = (buffer << 8) | raw[i];
    bits += 8;
    while (bits >= 6) {
      bits -= 6;
      out += kAlphabet[(buffer >> bits) & 63];
    }
  }
  if (bits > 0) out += kAlphabet[(buffer << (6 - bits)) & 63];
  return out;
}

Result<std::unique_ptr<ViewStore>> ViewStore::Open(const fs::path& state_dir) {
  const fs::path dir = state_dir / "views";
  std::error_code error;
  fs::create_directories(dir, error);
  if (error) {
    return IoError(dir.string() + ": cannot create the view-link folder: " + error.message());
  }
  // Only the server's user may read view links (they name datasets and what users looked at).
  ::chmod(dir.c_str(), 0700);
  std::unique_ptr<ViewStore> store(new ViewStore(dir));
  for (fs::directory_iterator it(dir, error), end; !error && it != end; it.increment(error)) {
    const fs::path& path = it->path();
    if (path.extension() != ".json") continue;
    const std::string id = path.stem().string();
    if (!protocol::IsViewLinkId(id)) continue;
    // The dataset and grant of each view, so that access checks never read the disk later.
    auto link = store->Load(id);
    store->entries_[id] = link.ok() ? Entry{link->dataset, link->grant} : Entry{};
  }
  if (error) return IoError(dir.string() + ": cannot list view links: " + error.message());
  return store;
}

fs::path ViewStore::PathOf(std::string_view id) const { return dir_ / (std::string(id) + ".json"); }

Result<std::string> ViewStore::Save(std::string_view dataset, const protocol::ViewState& state,
                                    const protocol::ViewLinkGrant& grant) {
  OCTO_ASSIGN_OR_RETURN(std::string id, RandomBase64Url(16));
  const std::string document = protocol::ViewLinkJson(dataset, state, grant);
  Status written = WriteFileDurably(PathOf(id), document, ".tmp", 0600);
  if (!written.ok()) return written.WithContext("saving a view link");
  std::lock_guard<std::mutex> lock(mu_);
  entries_[id] = Entry{std::string(dataset), grant};
  return id;
}

Status ViewStore::Delete(std::string_view id) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = entries_.find(id);
    if (it == entries_.end()) return NotFoundError("no such view link");
    // Out of the index first: the link stops opening even should the unlink fail.
    entries_.erase(it);
  }
  std::error_code error;
  fs::remove(PathOf(id), error);
  if (error) {
    return IoError("view link " + std::string(id) + ": cannot delete: " + error.message());
  }
  return SyncDirectory(dir_);
}

Result<std::string> ViewStore::LoadText(std::string_view id) const {
  if (!protocol::IsViewLinkId(id)) return NotFoundError("no such view link");
  const fs::path path = PathOf(id);
  auto text = ReadSmallFile(path, kMaxViewDocumentBytes);
  if (!text.ok()) {
    if (text.status().code() == StatusCode::kNotFound) return NotFoundError("no such view link");
    return CorruptError("view link " + std::string(id) + " (" + path.string() +
                        "): " + text.status().message());
  }
  return text;
}

Result<protocol::ViewLink> ViewStore::Load(std::string_view id) const {
  OCTO_ASSIGN_OR_RETURN(std::string text, LoadText(id));
  auto link = protocol::ParseViewLink(text);
  if (!link.ok()) {
    return CorruptError("view link " + std::string(id) + " (" + PathOf(id).string() +
                        ") is not a valid view document: " + link.status().message());
  }
  return link;
}

std::optional<ViewStore::Entry> ViewStore::Find(std::string_view id) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = entries_.find(id);
  if (it == entries_.end()) return std::nullopt;
  return it->second;
}

std::vector<std::pair<std::string, ViewStore::Entry>> ViewStore::List() const {
  std::lock_guard<std::mutex> lock(mu_);
  return {entries_.begin(), entries_.end()};
}

size_t ViewStore::OwnedBy(const protocol::GrantRef& owner) const {
  std::lock_guard<std::mutex> lock(mu_);
  size_t n = 0;
  for (const auto& [id, entry] : entries_) n += entry.grant && entry.grant->owner == owner;
  return n;
}

}  // namespace octoscope::session
