// AccessControl: who may do what on `octoscope serve` (docs/server.md, "Users and access"). It is
// the server's Authenticator — user tokens from the users table, share tokens and view ids through
// lookup hooks the sharing layer fills — and the rule of which datasets a principal sees:
//   - an admin user: every dataset;
//   - a user: the datasets whose source lies under one of the user's folders (component-wise
//     prefix of weakly_canonical paths), the demo, and the streams the user created;
//   - a share principal: the dataset of the share link's session; a view principal: the dataset
//     of the view link. Neither may create streams or read /metrics.
// A dataset a principal may not see is answered exactly like a dataset that does not exist.
//
// Tokens are compared in constant time against every user's token (no early exit on a match or on
// secret bytes). The users table can be replaced at run time (SIGHUP re-reads the users file).
//
// Thread safety: thread-safe. Authenticate, RefusalMessage and MayView run on I/O threads: they
// take a short lock and never touch the disk, except MayView's first look at a dataset, which
// resolves its source path once (weakly_canonical: a few stat calls) and remembers it.
#ifndef OCTOSCOPE_APP_ACCESS_CONTROL_H_
#define OCTOSCOPE_APP_ACCESS_CONTROL_H_

#include <chrono>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "dataset/dataset.h"
#include "net/principal.h"
#include "protocol/serve_config.h"
#include "util/result.h"

namespace octoscope::app {

struct User {
  std::string name;
  std::string token;
  std::vector<std::filesystem::path> folders;  // weakly_canonical, absolute.
  bool admin = false;
  std::optional<std::chrono::system_clock::time_point> expires;
};

// The token must not be guessable and fit in a URL and a header: 16 to 256 of A-Z a-z 0-9 - _ . ~
Status CheckToken(const std::string& token);
// The first line of `path`, trailing blanks removed.
Result<std::string> ReadTokenFile(const std::filesystem::path& path);

// Users from the config's entries: token files read, tokens checked and unique, folders made
// absolute and weakly_canonical. `what` names the source in errors ("--config cfg.json").
// kInvalidArgument for a bad entry, kNotFound for a token file that cannot be read.
Result<std::vector<User>> LoadUsers(const std::vector<protocol::UserConfig>& entries,
                                    std::string_view what);
// ParseUsersFile + LoadUsers of the file at `path`.
Result<std::vector<User>> LoadUsersFile(const std::filesystem::path& path);

// True when `path` equals `folder` or lies below it, compared component by component (so
// /srv/scans/alice2 is not under /srv/scans/alice). Both must be normalised already.
bool IsUnderFolder(const std::filesystem::path& path, const std::filesystem::path& folder);

class AccessControl : public net::Authenticator {
 public:
  // The dataset id a share token or view id is scoped to; nullopt when it is unknown (then the
  // request is refused with 401). Must be fast and thread-safe; never blocks on disk.
  using ScopeLookup = std::function<std::optional<std::string>(std::string_view credential)>;

  explicit AccessControl(std::vector<User> users);

  // Takes effect for the next request; connections already open keep their principal.
  void ReplaceUsers(std::vector<User> users);
  size_t user_count() const;
  // The hooks of the sharing layer (default: no share links, no view links).
  void SetShareLookup(ScopeLookup lookup);
  void SetViewLookup(ScopeLookup lookup);

  std::optional<net::Principal> Authenticate(std::string_view authorization,
                                             std::string_view raw_query) const override;
  std::string RefusalMessage(std::string_view authorization,
                             std::string_view raw_query) const override;

  // Whether `principal` may see (list, describe, open, upload to) `dataset`.
  bool MayView(const net::Principal& principal, const dataset::Dataset& dataset) const;
  // Only users create streams; only admins read /metrics.
  static bool MayCreateStreams(const net::Principal& principal);
  static bool MayReadMetrics(const net::Principal& principal);
  // The stream `dataset_id` was created by `user` (who then sees it).
  void RecordCreator(const std::string& dataset_id, const std::string& user);

 private:
  // The index of the user whose token the request carries, compared against every user.
  std::optional<size_t> MatchUser(const std::vector<User>& users, std::string_view authorization,
                                  std::string_view raw_query) const;
  std::optional<std::string> ScopeOf(const net::Principal& principal) const;
  std::filesystem::path CanonicalSource(const dataset::Dataset& dataset) const;

  mutable std::mutex mu_;
  std::shared_ptr<const std::vector<User>> users_;
  ScopeLookup share_lookup_;
  ScopeLookup view_lookup_;
  std::map<std::string, std::string, std::less<>> creators_;                   // Stream id -> user.
  mutable std::map<std::string, std::filesystem::path, std::less<>> sources_;  // Id -> canonical.
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_ACCESS_CONTROL_H_
