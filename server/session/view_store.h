// ViewStore: the server's view links (docs/protocol.md, "View links"): each is a JSON document
// (protocol::ViewLinkJson: dataset id + full state) in STATE_DIR/views/ID.json, ID being 22
// characters of base64url (128 random bits). Written atomically (temporary file, fsync, rename,
// directory fsync) with mode 0600; never changed afterwards. Read back strictly: a file that is
// unreadable or not a valid view document is a kCorrupt error naming the view and the problem.
//
// Thread safety: thread-safe. Exists() answers from memory (the ids found at Open and saved
// since), so it may run on I/O threads; Save and Load touch the disk.
#ifndef OCTOSCOPE_SESSION_VIEW_STORE_H_
#define OCTOSCOPE_SESSION_VIEW_STORE_H_

#include <filesystem>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>

#include "protocol/ws_messages.h"
#include "util/result.h"

namespace octoscope::session {

// Largest view document read back (a state document is a few KiB).
inline constexpr uint64_t kMaxViewDocumentBytes = 64 << 10;

class ViewStore {
 public:
  // Creates STATE_DIR/views (mode 0700) when missing and indexes the ids there.
  static Result<std::unique_ptr<ViewStore>> Open(const std::filesystem::path& state_dir);

  // Stores `state` of dataset `dataset` under a new id; returns the id.
  Result<std::string> Save(std::string_view dataset, const protocol::ViewState& state);
  // The stored document as written (kNotFound for an unknown or malformed id; kCorrupt when the
  // file does not hold a valid view document).
  Result<std::string> LoadText(std::string_view id) const;
  // The stored view, parsed strictly.
  Result<protocol::ViewLink> Load(std::string_view id) const;
  // Whether a view of this id exists (from memory: no disk access).
  bool Exists(std::string_view id) const;

  const std::filesystem::path& dir() const { return dir_; }

 private:
  explicit ViewStore(std::filesystem::path dir) : dir_(std::move(dir)) {}
  std::filesystem::path PathOf(std::string_view id) const;

  const std::filesystem::path dir_;
  mutable std::mutex mu_;
  std::set<std::string, std::less<>> ids_;
};

// `bytes` random bytes as unpadded base64url (RFC 4648 §5). REQUIRES: 1 <= bytes <= 64.
Result<std::string> RandomBase64Url(int bytes);

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_VIEW_STORE_H_
