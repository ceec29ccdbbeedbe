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

void AccessControl::SetShareLookup(ScopeLookup lookup) {
  std::lock_guard<std::mutex> lock(mu_);
  share_lookup_ = std::move(lookup);
}

void AccessControl::SetViewLookup(ScopeLookup lookup) {
  std::lock_guard<std::mutex> lock(mu_);
  view_lookup_ = std::move(lookup);
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
  ScopeLookup share, view;
  {
    std::lock_guard<std::mutex> lock(mu_);
    users = users_;
    share = share_lookup_;
    view = view_lookup_;
  }
  const net::RequestCredentials c = net::ReadCredentials(authorization, raw_query);
  if (const std::optional<size_t> i = MatchUser(*users, authorization, raw_query)) {
    const User& u = (*users)[*i];
    if (u.expires && std::chrono::system_clock::now() >= *u.expires) return std::nullopt;
    // A signed-in user following a share or view link uses the link (its role and scope).
    if (c.share) {
      if (!share || !share(*c.share)) return std::nullopt;
      return net::Principal{net::Principal::Kind::kShare, u.name, false, *c.share};
    }
    if (c.view) {
      if (!view || !view(*c.view)) return std::nullopt;
      return net::Principal{net::Principal::Kind::kView, u.name, false, *c.view};
    }
    net::Principal p;
    p.kind = net::Principal::Kind::kUser;
    p.user = u.name;
    p.admin = u.admin;
    return p;
  }
  if (c.share && share && share(*c.share)) {
    return net::Principal{net::Principal::Kind::kShare, "", false, *c.share};
  }
  if (c.view && view && view(*c.view)) {
    return net::Principal{net::Principal::Kind::kView, "", false, *c.view};
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
  if (i && (*users)[*i].expires && std::chrono::system_clock::now() >= *(*users)[*i].expires) {
    return "token expired";
  }
  const net::RequestCredentials c = net::ReadCredentials(authorization, raw_query);
  if (c.share) return "this share link is not valid (revoked or expired)";
  if (c.view) return "no such view link";
  return "missing or wrong token";
}

std::optional<std::string> AccessControl::ScopeOf(const net::Principal& principal) const {
  ScopeLookup lookup;
  {
    std::lock_guard<std::mutex> lock(mu_);
    lookup = principal.kind == net::Principal::Kind::kShare ? share_lookup_ : view_lookup_;
  }
  if (!lookup) return std::nullopt;
  return lookup(principal.credential);
}

fs::path AccessControl::CanonicalSource(const dataset::Dataset& dataset) const {
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = sources_.find(dataset.id());
    if (it != sources_.end()) return it->second;
  }
  std::error_code ec;
  fs::path canonical = dataset.source_path().empty()
                           ? fs::path()
                           : fs::weakly_canonical(fs::absolute(dataset.source_path(), ec), ec);
  if (ec) canonical.clear();  // Unresolvable: under no folder.
  std::lock_guard<std::mutex> lock(mu_);
  sources_.emplace(dataset.id(), canonical);
  return canonical;
}

bool AccessControl::MayView(const net::Principal& principal,
                            const dataset::Dataset& dataset) const {
  if (principal.kind != net::Principal::Kind::kUser) {
    const std::optional<std::string> scope = ScopeOf(principal);
    return scope && *scope == dataset.id();
  }
  if (principal.admin) return true;
  if (principal.user.empty()) return false;  // No credentials (GET /api/health).
  if (dataset.id() == dataset::DemoDatasetId()) return true;
  std::shared_ptr<const std::vector<User>> users;
  {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = creators_.find(dataset.id());
    if (it != creators_.end() && it->second == principal.user) return true;
    users = users_;
  }
  const User* user = nullptr;
  for (const User& u : *users) {
    if (u.name == principal.user) user = &u;
  }
  // A user removed by a reload keeps nothing, even on a connection opened before.
  if (user == nullptr) return false;
  if (dataset.is_stream()) return false;
  const fs::path source = CanonicalSource(dataset);
  if (source.empty()) return false;
  for (const fs::path& folder : user->folders) {
    if (IsUnderFolder(source, folder)) return true;
  }
  return false;
}

bool AccessControl::MayCreateStreams(const net::Principal& principal) {
  return principal.kind == net::Principal::Kind::kUser && !principal.user.empty();
}

bool AccessControl::MayReadMetrics(const net::Principal& principal) {
  return principal.kind == net::Principal::Kind::kUser && principal.admin;
}

void AccessControl::RecordCreator(const std::string& dataset_id, const std::string& user) {
  std::lock_guard<std::mutex> lock(mu_);
  creators_[dataset_id] = user;
}

}  // namespace octoscope::app
