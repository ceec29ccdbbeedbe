// GrantChecker: the session layer's question to whoever knows the users and links (the app's
// AccessControl): does a grant still hold, and does it cover a dataset (docs/server.md, "Threat
// model")? Sessions ask before a participant opens a dataset, before a share link or view link
// is made, and every second for their owner (Revalidate), so that access ends for everyone it
// was passed on to as soon as the grant it rests on ends.
//
// Thread safety: Check is called from any thread, never with a session's mutex held (it may
// look up share links, which asks their session).
#ifndef OCTOSCOPE_SESSION_GRANT_CHECKER_H_
#define OCTOSCOPE_SESSION_GRANT_CHECKER_H_

#include <string>
#include <string_view>

#include "protocol/grant_ref.h"

namespace octoscope::session {

struct GrantVerdict {
  bool holds = false;
  // When it does not hold: one line for the user ("token expired", "user removed", "share link
  // revoked", "not allowed for this dataset", ...).
  std::string reason;
  // A share link lies on the chain: what it admits may not be shared further.
  bool via_share = false;
  // The user at the chain's root (view links and sessions count against it).
  protocol::GrantRef owner;
};

class GrantChecker {
 public:
  virtual ~GrantChecker() = default;
  // Whether `grant` holds now and, when `dataset` is not empty, covers the dataset of that id.
  virtual GrantVerdict Check(const protocol::GrantRef& grant, std::string_view dataset) const = 0;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_GRANT_CHECKER_H_
