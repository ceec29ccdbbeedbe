// AccessControl: who may do what on `octoscope serve` (docs/server.md, "Users and access" and
// "Threat model"). It is the server's Authenticator — user tokens from the users table, share
// tokens and view ids through lookup hooks the sharing layer fills — and the session layer's
// GrantChecker: every credential rests on a grant (protocol::GrantRef), and a grant holds only
// while the chain of grants it was made under, down to a user, still holds and covers the
// dataset:
//   - a user grant: the user is in the users table (by the stable id the user's name got) and
//     not expired; it covers every dataset for an admin, else the datasets whose source lies
//     under one of the user's folders (component-wise prefix of weakly_canonical paths), the
//     demo, and the streams the user created (the stream's Dataset::creator(), the creator's
//     grant as text, kept in its record across restarts);
//   - a share grant: the link is live (not revoked, not expired, its session not released); it
//     covers the one dataset it was made for, while the grant of its session's owner does;
//   - a view grant: the view link exists and has not expired; it covers its one dataset while
//     the grant it was made under does.
// A dataset a principal may not see is answered exactly like a dataset that does not exist.
//
// Tokens are compared in constant time against every user's token (no early exit on a match or on
// secret bytes). The users table can be replaced at run time (SIGHUP re-reads the users file);
// connections already open are checked again by their sessions (ViewSession::Revalidate).
//
// Thread safety: thread-safe. Authenticate, RefusalMessage, MayView and Check run on I/O and
// session threads: they take a short lock (never while calling a hook) and never touch the disk,
// except a user's first look at a dataset, which resolves its source path once (weakly_canonical:
// a few stat calls) and remembers it. Hooks must not call back into this object.
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
#include "protocol/grant_ref.h"
#include "protocol/serve_config.h"
#include "protocol/ws_messages.h"
#include "session/grant_checker.h"
#include "util/result.h"

namespace octoscope::app {

struct User {
  std::string name;
  std::string token;
  std::vector<std::filesystem::path> folders;  // weakly_canonical, absolute.
  bool admin = false;
  std::optional<std::chrono::system_clock::time_point> expires;
  // Stable while the name stays in the users table (app/user_ids.h); "" = the name itself.
  std::string id;
};

// The name of the --token's user.
inline constexpr char kAdminUserName[] = "admin";

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
// The rules a users table must follow beside an admin token (start-up and every reload alike):
// no user named "admin" when `admin_token` is set, and no user with the admin token.
Status CheckUsersBesideAdmin(const std::vector<User>& users, const std::string& admin_token);

// True when `path` equals `folder` or lies below it, compared component by component (so
// /srv/scans/alice2 is not under /srv/scans/alice). Both must be normalised already.
bool IsUnderFolder(const std::filesystem::path& path, const std::filesystem::path& folder);

// A live share link as the sharing layer reports it.
struct ShareGrantInfo {
  std::string id;             // Public id (the link's grant).
  protocol::GrantRef owner;   // The grant of the session it belongs to.
  std::string dataset;        // The dataset it admits to ("" until its session opened one).
};

// A stored view link as the view store reports it.
struct ViewGrantInfo {
  std::string dataset;
  std::optional<protocol::ViewLinkGrant> grant;  // nullopt: a document of version 1.
};

class AccessControl : public net::Authenticator, public session::GrantChecker {
 public:
  // Share links by their secret token and by their public id; nullopt when unknown, revoked or
  // expired. Fast, thread-safe, never block on disk, never call this object.
  using ShareLookup = std::function<std::optional<ShareGrantInfo>(std::string_view)>;
  // View links by id; nullopt when unknown.
  using ViewLookup = std::function<std::optional<ViewGrantInfo>(std::string_view id)>;
  using DatasetFinder = std::function<std::shared_ptr<dataset::Dataset>(std::string_view id)>;

  explicit AccessControl(std::vector<User> users);

  // Takes effect for the next request; connections already open end at their session's next
  // revalidation when their grant no longer holds.
  void ReplaceUsers(std::vector<User> users);
  size_t user_count() const;
  // The hooks of the sharing layer (default: no share links, no view links, no datasets).
  void SetShareLookups(ShareLookup by_token, ShareLookup by_id);
  void SetViewLookup(ViewLookup lookup);
  void SetDatasetFinder(DatasetFinder finder);

  std::optional<net::Principal> Authenticate(std::string_view authorization,
                                             std::string_view raw_query) const override;
  std::string RefusalMessage(std::string_view authorization,
                             std::string_view raw_query) const override;

  // session::GrantChecker.
  session::GrantVerdict Check(const protocol::GrantRef& grant,
                              std::string_view dataset) const override;

  // The grant a principal acts under (nullopt: none, e.g. GET /api/health without credentials).
  std::optional<protocol::GrantRef> GrantOf(const net::Principal& principal) const;
  // Whether `principal` may see (list, describe, open, upload to) `dataset`.
  bool MayView(const net::Principal& principal, const dataset::Dataset& dataset) const;
  // Only users create streams; only admins read /metrics.
  static bool MayCreateStreams(const net::Principal& principal);
  static bool MayReadMetrics(const net::Principal& principal);
  // The grant a stream was created under (its Dataset::creator()), if any.
  static std::optional<protocol::GrantRef> CreatorOf(const dataset::Dataset& dataset);
  // The name of the user whose id is `id`, nullopt when no user has it (any more).
  std::optional<std::string> UserName(std::string_view id) const;

 private:
  // The index of the user whose token the request carries, compared against every user.
  std::optional<size_t> MatchUser(const std::vector<User>& users, std::string_view authorization,
                                  std::string_view raw_query) const;
  session::GrantVerdict CheckAt(const protocol::GrantRef& grant, std::string_view dataset,
                                int depth) const;
  session::GrantVerdict CheckUser(const std::string& id, std::string_view dataset) const;
  // `dataset` null: whether the user holds at all.
  session::GrantVerdict CheckUserOn(const std::string& id, const dataset::Dataset* dataset) const;
  bool UserMayView(const User& user, const dataset::Dataset& dataset) const;
  std::filesystem::path CanonicalSource(const dataset::Dataset& dataset) const;

  mutable std::mutex mu_;
  std::shared_ptr<const std::vector<User>> users_;
  ShareLookup share_by_token_;
  ShareLookup share_by_id_;
  ViewLookup view_lookup_;
  DatasetFinder find_dataset_;
  mutable std::map<std::string, std::filesystem::path, std::less<>> sources_;  // Id -> canonical.
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_ACCESS_CONTROL_H_
