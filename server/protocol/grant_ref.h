// GrantRef: what a credential's access rests on (docs/server.md, "Threat model"). A user grant
// names the user by the stable id the server gives a user name while it stays in the users
// table (never reused: a name removed and added again gets a new id); a share grant names a share
// link by its public id (never by its secret token); a view grant names a view link by its id.
// Every session, share link, view link and stream records the grant it was made under, and a
// credential holds only while the whole chain of grants down to a user still holds and covers the
// dataset — so no link outlives, or reaches beyond, the access of whoever made it.
//
// Text form (view-link documents, stream records): "user:ID", "share:ID", "view:ID", ID being
// 1 to 64 of A-Z a-z 0-9 _ - . (user names are valid ids).
//
// Thread safety: a plain value type; pure functions.
#ifndef OCTOSCOPE_PROTOCOL_GRANT_REF_H_
#define OCTOSCOPE_PROTOCOL_GRANT_REF_H_

#include <string>
#include <string_view>

#include "util/result.h"

namespace octoscope::protocol {

struct GrantRef {
  enum class Kind { kUser, kShare, kView };
  Kind kind = Kind::kUser;
  std::string id;
  bool operator==(const GrantRef&) const = default;
};

inline constexpr size_t kMaxGrantIdBytes = 64;

// "user:ID", "share:ID" or "view:ID".
std::string GrantRefText(const GrantRef& grant);
// The inverse of GrantRefText; kInvalidArgument for anything else.
Result<GrantRef> ParseGrantRef(std::string_view text);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_GRANT_REF_H_
