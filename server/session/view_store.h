// ViewStore: the server's view links (docs/protocol.md, "View links"): each is a JSON document
// (protocol::ViewLinkJson: dataset id, the grant it was made under, its owner, when it was made
// and when it expires, and the full state) in STATE_DIR/views/ID.json, ID being 22 characters of
// base64url (128 random bits). Written atomically (temporary file, fsync, rename, directory
// fsync) with mode 0600; never changed afterwards, only deleted. Read back strictly: a file that
// is unreadable or not a valid view document is a kCorrupt error naming the view and the problem.
//
// Thread safety: thread-safe. Find(), List() and OwnedBy() answer from memory (the documents
// indexed at Open and saved since), so they may run on I/O threads; Save, Load and Delete touch
// the disk.
#ifndef OCTOSCOPE_SESSION_VIEW_STORE_H_
#define OCTOSCOPE_SESSION_VIEW_STORE_H_

#include <filesystem>
#include <memory>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "protocol/ws_messages.h"
#include "util/result.h"

namespace octoscope::session {

// Largest view document read back (a state document is a few KiB).
inline constexpr uint64_t kMaxViewDocumentBytes = 64 << 10;

class ViewStore {
 public:
  // Creates STATE_DIR/views (mode 0700) when missing and indexes the ids there.
  static Result<std::unique_ptr<ViewStore>> Open(const std::filesystem::path& state_dir);

  // What the index holds of one view link (no disk access to read it).
  struct Entry {
    std::string dataset;  // "" for a file that did not read back at Open.
    std::optional<protocol::ViewLinkGrant> grant;  // nullopt: a version 1 document, or unreadable.
  };

  // Stores `state` of dataset `dataset`, made under `grant`, under a new id; returns the id.
  Result<std::string> Save(std::string_view dataset, const protocol::ViewState& state,
                           const protocol::ViewLinkGrant& grant);
  // The stored document as written (kNotFound for an unknown or malformed id; kCorrupt when the
  // file does not hold a valid view document).
  Result<std::string> LoadText(std::string_view id) const;
  // The stored view, parsed strictly.
  Result<protocol::ViewLink> Load(std::string_view id) const;
  // Removes the view link (its file, then the directory entry made durable); kNotFound for an
  // unknown id.
  Status Delete(std::string_view id);
  // The index entry of view `id`, or nullopt for an unknown id (from memory).
  std::optional<Entry> Find(std::string_view id) const;
  // Every view link, by id (from memory).
  std::vector<std::pair<std::string, Entry>> List() const;
  // How many view links `owner` owns (from memory).
  size_t OwnedBy(const protocol::GrantRef& owner) const;

  const std::filesystem::path& dir() const { return dir_; }

 private:
  explicit ViewStore(std::filesystem::path dir) : dir_(std::move(dir)) {}
  std::filesystem::path PathOf(std::string_view id) const;

  const std::filesystem::path dir_;
  mutable std::mutex mu_;
  std::map<std::string, Entry, std::less<>> entries_;  // By view id.
};

// `bytes` random bytes as unpadded base64url (RFC 4648 §5). REQUIRES: 1 <= bytes <= 64.
Result<std::string> RandomBase64Url(int bytes);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_VIEW_STORE_H_
