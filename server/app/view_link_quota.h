// ViewLinkQuota: the view links one user may own and save (docs/server.md, "Threat model"). Each
// view link is a file in the state folder and a durable write: a user owns at most
// `max_per_owner` and saves at most `per_minute` a minute (bursts of that many), counted against
// the user at the root of the grant a link is made under (guests' links count against the
// session owner who shared).
//
// Thread safety: thread-safe.
#ifndef OCTOSCOPE_APP_VIEW_LINK_QUOTA_H_
#define OCTOSCOPE_APP_VIEW_LINK_QUOTA_H_

#include <map>
#include <mutex>
#include <string>

#include "protocol/grant_ref.h"
#include "session/view_store.h"
#include "util/status.h"
#include "util/token_bucket.h"

namespace octoscope::app {

class ViewLinkQuota {
 public:
  // REQUIRES: views outlives the quota; max_per_owner >= 1, per_minute >= 1.
  ViewLinkQuota(const session::ViewStore* views, int max_per_owner, int per_minute)
      : views_(views), max_per_owner_(max_per_owner), per_minute_(per_minute) {}

  // Ok and one save counted, or kResourceExhausted saying which limit was reached.
  Status Admit(const protocol::GrantRef& owner);

 private:
  const session::ViewStore* views_;
  const int max_per_owner_;
  const int per_minute_;
  std::mutex mu_;
  std::map<std::string, TokenBucket> rates_;  // By owner (GrantRefText).
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_VIEW_LINK_QUOTA_H_
