#include "app/access_control.h"

#include <fstream>
#include <sstream>
#include <utility>

#include "dataset/dataset_registry.h"
#include "net/auth.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

constexpr size_t kMinTokenChars = 16;
constexpr size_t kMaxTokenChars = 256;

}  // namespace

Status CheckToken(const std::string& token) {
  if (token.size() < kMinTokenChars || token.size() > kMaxTokenChars) {
    return InvalidArgumentError("the token must be " + std::to_string(kMinTokenChars) + " to " +
                                std::to_string(kMaxTokenChars) + " characters");
  }
  for (char c : token) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '-' || c == '_' || c == '.' || c == '~';
    if (!ok) return InvalidArgumentError("the token may hold only A-Z a-z 0-9 - _ . ~");
  }
  return Status::Ok();
}

Result<std::string> ReadTokenFile(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return NotFoundError(path.string() + ": cannot read the token file");
  std::string line;
  std::getline(in, line);
  while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t')) {
    line.pop_back();
  }
  return line;
}

Result<std::vector<User>> LoadUsers(const std::vector<protocol::UserConfig>& entries,
                                    std::string_view what) {
  std::vector<User> users;
  for (const protocol::UserConfig& e : entries) {
    const std::string where = std::string(what) + ": user \"" + e.name + "\"";
    User u;
    u.name = e.name;
    u.admin = e.admin;
    if (e.token) {
      u.token = *e.token;
    } else {
      auto read = ReadTokenFile(*e.token_file);
      if (!read.ok()) return NotFoundError(where + ": " + read.status().message());
      u.token = *read;
    }
    if (Status s = CheckToken(u.token); !s.ok()) {
      return InvalidArgumentError(where + ": " + s.message());
    }
    for (const User& other : users) {
      // Start-up only, not a secret comparison against a request.
      if (other.token == u.token) {
        return InvalidArgumentError(where + ": the same token as user \"" + other.name + "\"");
      }
    }
    for (const std::string& folder : e.folders) {
      std::error_code ec;
      fs::path canonical = fs::weakly_canonical(fs::absolute(folder, ec), ec);
      if (ec) return InvalidArgumentError(where + ": folder " + folder + ": " + ec.message());
      u.folders.push_back(std::move(canonical));
    }
    if (e.expires_unix_s) {
      u.expires = std::chrono::system_clock::time_point(std::chrono::seconds(*e.expires_unix_s));
    }
    users.push_back(std::move(u));
  }
  return users;
}

Result<std::vector<User>> LoadUsersFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return NotFoundError(path.string() + ": cannot read the users file");
  std::ostringstream text;
  text << in.rdbuf();
  auto parsed = protocol::ParseUsersFile(text.str(), path.string());
  if (!parsed.ok()) return parsed.status();
  return LoadUsers(*parsed, path.string());
}

Status CheckUsersBesideAdmin(const std::vector<User>& users, const std::string& admin_token) {
  if (admin_token.empty()) return Status::Ok();
  for (const User& u : users) {
    if (u.name == kAdminUserName) {
      return InvalidArgumentError(
          "a user is named \"admin\", the name of the --token's user: rename it");
    }
    // Start-up and reloads only, not a secret comparison against a request.
    if (u.token == admin_token) {
      return InvalidArgumentError("user \"" + u.name + "\" has the --token's token");
    }
  }
  return Status::Ok();
}

bool IsUnderFolder(const fs::path& path, const fs::path& folder) {
  auto p = path.begin();
  for (auto f = folder.begin(); f != folder.end(); ++f) {
    // A trailing separator gives an empty last component: it matches anything.
    if (f->empty() && std::next(f) == folder.end()) break;
    if (p == path.end() || *p != *f) return false;
    ++p;
  }
  return !path.empty() && !folder.empty();
}

namespace {

using protocol::GrantRef;
using session::GrantVerdict;

// How many links a chain of grants may hold (links are made under earlier ones, so chains do not
// loop; this bounds a corrupt state folder).
constexpr int kMaxGrantDepth = 16;

GrantVerdict Refused(std::string reason) {
  GrantVerdict v;
  v.reason = std::move(reason);
  return v;
}

const std::string& IdOf(const User& user) { return user.id.empty() ? user.name : user.id; }

bool Expired(const User& user) {
  return user.expires && std::chrono::system_clock::now() >= *user.expires;
}

}  // namespace

AccessControl::AccessControl(std::vector<User> users)
    : users_(std::make_shared<const std::vector<User>>(std::move(users))) {}

void AccessControl::ReplaceUsers(std::vector<User> users) {
  auto table = std::make_shared<const std::vector<User>>(std::move(users));
  std::lock_guard<std::mutex> lock(mu_);
  users_ = std::move(table);
}

size_t AccessControl::user_count() const {
  std::lock_guard<std::mutex> lock(mu_);
  return users_->size();
}

void AccessControl::SetShareLookups(ShareLookup by_token, ShareLookup by_id) {
  std::lock_guard<std::mutex> lock(mu_);
  share_by_token_ = std::move(by_token);
  share_by_id_ = std::move(by_id);
}

void AccessControl::SetViewLookup(ViewLookup lookup) {
  std::lock_guard<std::mutex> lock(mu_);
  view_lookup_ = std::move(lookup);
}

void AccessControl::SetDatasetFinder(DatasetFinder finder) {
  std::lock_guard<std::mutex> lock(mu_);
  find_dataset_ = std::move(finder);
}

std::optional<size_t> AccessControl::MatchUser(const std::vector<User>& users,
                                               std::string_view authorization,
                                               std::string_view raw_query) const {
  // Every candidate against every user, all the way: the time depends on the counts and lengths,
  // never on which bytes matched.
  std::optional<size_t> match;
  for (const std::string& candidate : net::ReadCredentials(authorization, raw_query).tokens) {
    for (size_t i = 0; i < users.size(); ++i) {
      const bool equal = net::ConstantTimeEquals(candidate, users[i].token);
      if (equal && !match) match = i;
    }
  }
  return match;
}

std::optional<net::Principal> AccessControl::Authenticate(std::string_view authorization,
                                                          std::string_view raw_query) const {
  std::shared_ptr<const std::vector<User>> users;
  ShareLookup share;
  {
    std::lock_guard<std::mutex> lock(mu_);
    users = users_;
    share = share_by_token_;
  }
  const net::RequestCredentials c = net::ReadCredentials(authorization, raw_query);
  std::string name;
  if (const std::optional<size_t> i = MatchUser(*users, authorization, raw_query)) {
    const User& u = (*users)[*i];
    if (Expired(u)) return std::nullopt;
    name = u.name;
    // A signed-in user following a share or view link uses the link (its role and scope).
    if (!c.share && !c.view) {
      net::Principal p;
      p.kind = net::Principal::Kind::kUser;
      p.user = u.name;
      p.user_id = IdOf(u);
      p.admin = u.admin;
      return p;
    }
  }
  // A link admits while the whole chain of grants it rests on holds.
  if (c.share) {
    const std::optional<ShareGrantInfo> info = share ? share(*c.share) : std::nullopt;
    if (!info || !Check(GrantRef{GrantRef::Kind::kShare, info->id}, "").holds) return std::nullopt;
    return net::Principal{net::Principal::Kind::kShare, name, false, *c.share, ""};
  }
  if (c.view) {
    if (!protocol::IsViewLinkId(*c.view)) return std::nullopt;
    if (!Check(GrantRef{GrantRef::Kind::kView, *c.view}, "").holds) return std::nullopt;
    return net::Principal{net::Principal::Kind::kView, name, false, *c.view, ""};
  }
  return std::nullopt;
}

std::string AccessControl::RefusalMessage(std::string_view authorization,
                                          std::string_view raw_query) const {
  std::shared_ptr<const std::vector<User>> users;
  {
    std::lock_guard<std::mutex> lock(mu_);
    users = users_;
  }
  const std::optional<size_t> i = MatchUser(*users, authorization, raw_query);
  if (i && Expired((*users)[*i])) return "token expired";
  const net::RequestCredentials c = net::ReadCredentials(authorization, raw_query);
  if (c.share) return "this share link is not valid (revoked or expired)";
  if (c.view) {
    const session::GrantVerdict v =
        protocol::IsViewLinkId(*c.view) ? Check(GrantRef{GrantRef::Kind::kView, *c.view}, "")
                                        : Refused("the view link was deleted");
    return "this view link does not open: " + v.reason;
  }
  return "missing or wrong token";
}

std::optional<GrantRef> AccessControl::GrantOf(const net::Principal& principal) const {
  switch (principal.kind) {
    case net::Principal::Kind::kUser:
      if (principal.user.empty()) return std::nullopt;
      return GrantRef{GrantRef::Kind::kUser,
                      principal.user_id.empty() ? principal.user : principal.user_id};
    case net::Principal::Kind::kView:
      return GrantRef{GrantRef::Kind::kView, principal.credential};
    case net::Principal::Kind::kShare: {
      ShareLookup share;
      {
        std::lock_guard<std::mutex> lock(mu_);
        share = share_by_token_;
      }
      const std::optional<ShareGrantInfo> info = share ? share(principal.credential) : std::nullopt;
      // A link gone since the request was authenticated: a grant that holds nothing.
      return GrantRef{GrantRef::Kind::kShare, info ? info->id : std::string("revoked")};
    }
  }
  return std::nullopt;
}

GrantVerdict AccessControl::Check(const GrantRef& grant, std::string_view dataset) const {
  return CheckAt(grant, dataset, 0);
}

GrantVerdict AccessControl::CheckAt(const GrantRef& grant, std::string_view dataset,
                                    int depth) const {
  if (depth > kMaxGrantDepth) return Refused("the chain of links is too long");
  switch (grant.kind) {
    case GrantRef::Kind::kUser:
      return CheckUser(grant.id, dataset);
    case GrantRef::Kind::kShare: {
      ShareLookup lookup;
      {
        std::lock_guard<std::mutex> lock(mu_);
        lookup = share_by_id_;
      }
      const std::optional<ShareGrantInfo> info = lookup ? lookup(grant.id) : std::nullopt;
      if (!info) return Refused("the share link was revoked or expired");
      // It admits to the dataset it was made for only (none before its session opened one).
      if (!dataset.empty() && info->dataset != dataset) {
        return Refused("not allowed for this dataset");
      }
      // It holds while its session's owner may still see that dataset.
      GrantVerdict v = CheckAt(info->owner, dataset.empty() ? info->dataset : dataset, depth + 1);
      v.via_share = true;
      if (!v.holds && info->owner.kind == GrantRef::Kind::kUser) {
        v.reason = "the access of the session's owner ended (" + v.reason + ")";
      }
      return v;
    }
    case GrantRef::Kind::kView: {
      ViewLookup lookup;
      {
        std::lock_guard<std::mutex> lock(mu_);
        lookup = view_lookup_;
      }
      const std::optional<ViewGrantInfo> info = lookup ? lookup(grant.id) : std::nullopt;
      if (!info) return Refused("the view link was deleted");
      if (info->dataset.empty()) {
        return Refused("view link " + grant.id + " is not a valid view document");
      }
      if (!info->grant) {
        return Refused("the view link was made before links recorded who made them; save it again");
      }
      if (info->grant->expires_unix_s &&
          std::chrono::system_clock::now() >=
              std::chrono::system_clock::time_point(std::chrono::seconds(*info->grant->expires_unix_s))) {
        return Refused("the view link expired");
      }
      if (!dataset.empty() && info->dataset != dataset) {
        return Refused("not allowed for this dataset");
      }
      // It covers its own dataset while the grant it was made under does.
      GrantVerdict v = CheckAt(info->grant->creator, info->dataset, depth + 1);
      if (!v.holds) v.reason = "the access of the view link's maker ended (" + v.reason + ")";
      return v;
    }
  }
  return Refused("unknown grant");
}

GrantVerdict AccessControl::CheckUser(const std::string& id, std::string_view dataset) const {
  DatasetFinder find;
  {
    std::lock_guard<std::mutex> lock(mu_);
    find = find_dataset_;
  }
  std::shared_ptr<dataset::Dataset> found;
  if (!dataset.empty()) {
    found = find ? find(dataset) : nullptr;
    if (found == nullptr) return Refused("not allowed for this dataset");
  }
  return CheckUserOn(id, found.get());
}

GrantVerdict AccessControl::CheckUserOn(const std::string& id,
                                        const dataset::Dataset* dataset) const {
  std::shared_ptr<const std::vector<User>> users;
  {
    std::lock_guard<std::mutex> lock(mu_);
    users = users_;
  }
  const User* user = nullptr;
  for (const User& u : *users) {
    if (IdOf(u) == id) user = &u;
  }
  // A user removed by a reload keeps nothing; a new user of the same name has another id.
  if (user == nullptr) return Refused("user removed");
  if (Expired(*user)) return Refused("token expired");
  GrantVerdict v;
  v.owner = GrantRef{GrantRef::Kind::kUser, id};
  v.holds = dataset == nullptr || UserMayView(*user, *dataset);
  if (!v.holds) v.reason = "not allowed for this dataset";
  return v;
}

fs::path AccessControl::CanonicalSource(const dataset::Dataset& dataset) const {
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = sources_.find(dataset.id());
    if (it != sources_.end()) return it->second;
  }
  // The folder holding it resolved, its own name not: whether a main file that is a link leads
  // somewhere (and where) must not change who sees it listed (the file gate refuses such a link
  // alike, whether its target exists or not).
  std::error_code ec;
  fs::path canonical;
  if (!dataset.source_path().empty()) {
    const fs::path absolute = fs::absolute(dataset.source_path(), ec).lexically_normal();
    if (!ec) canonical = fs::weakly_canonical(absolute.parent_path(), ec) / absolute.filename();
  }
  if (ec) canonical.clear();  // Unresolvable: under no folder.
  std::lock_guard<std::mutex> lock(mu_);
  sources_.emplace(dataset.id(), canonical);
  return canonical;
}

bool AccessControl::UserMayView(const User& user, const dataset::Dataset& dataset) const {
  if (user.admin) return true;
  if (dataset.id() == dataset::DemoDatasetId()) return true;
  if (const std::optional<GrantRef> creator = CreatorOf(dataset)) {
    if (*creator == GrantRef{GrantRef::Kind::kUser, IdOf(user)}) return true;
  }
  if (dataset.is_stream()) return false;
  const fs::path source = CanonicalSource(dataset);
  if (source.empty()) return false;
  for (const fs::path& folder : user.folders) {
    if (IsUnderFolder(source, folder)) return true;
  }
  return false;
}

bool AccessControl::MayView(const net::Principal& principal,
                            const dataset::Dataset& dataset) const {
  const std::optional<GrantRef> grant = GrantOf(principal);
  if (!grant) return false;
  if (grant->kind == GrantRef::Kind::kUser) return CheckUserOn(grant->id, &dataset).holds;
  return Check(*grant, dataset.id()).holds;
}

bool AccessControl::MayCreateStreams(const net::Principal& principal) {
  return principal.kind == net::Principal::Kind::kUser && !principal.user.empty();
}

bool AccessControl::MayReadMetrics(const net::Principal& principal) {
  return principal.kind == net::Principal::Kind::kUser && principal.admin;
}

std::optional<GrantRef> AccessControl::CreatorOf(const dataset::Dataset& dataset) {
  if (!dataset.is_stream() || dataset.creator().empty()) return std::nullopt;
  auto creator = protocol::ParseGrantRef(dataset.creator());
  if (!creator.ok()) return std::nullopt;  // Not a grant: nobody's.
  return *creator;
}

std::optional<std::string> AccessControl::UserName(std::string_view id) const {
  std::lock_guard<std::mutex> lock(mu_);
  for (const User& u : *users_) {
    if (IdOf(u) == id) return u.name;
  }
  return std::nullopt;
}

}  // namespace octoscope::app
