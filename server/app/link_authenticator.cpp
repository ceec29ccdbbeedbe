#include "app/link_authenticator.h"

#include <utility>

#include "net/auth.h"

namespace octoscope::app {

LinkAuthenticator::LinkAuthenticator(std::shared_ptr<const net::Authenticator> users,
                                     const session::SessionRegistry* registry,
                                     const session::ViewStore* views)
    : users_(std::move(users)), registry_(registry), views_(views) {}

std::optional<net::Principal> LinkAuthenticator::Authenticate(std::string_view authorization,
                                                              std::string_view raw_query) const {
  // A user token wins: a user may open a link's URL while signed in.
  if (auto user = users_->Authenticate(authorization, raw_query)) {
    const net::RequestCredentials credentials = net::ReadCredentials(authorization, raw_query);
    // A signed-in user following a share link joins through it (the link's role applies).
    if (credentials.share) {
      if (registry_ == nullptr || !registry_->FindShare(*credentials.share)) return std::nullopt;
      return net::Principal{net::Principal::Kind::kShare, user->user, false, *credentials.share};
    }
    if (credentials.view) {
      if (views_ == nullptr || !views_->Exists(*credentials.view)) return std::nullopt;
      return net::Principal{net::Principal::Kind::kView, user->user, false, *credentials.view};
    }
    return user;
  }
  const net::RequestCredentials credentials = net::ReadCredentials(authorization, raw_query);
  if (credentials.share && registry_ != nullptr && registry_->FindShare(*credentials.share)) {
    return net::Principal{net::Principal::Kind::kShare, "", false, *credentials.share};
  }
  if (credentials.view && views_ != nullptr && views_->Exists(*credentials.view)) {
    return net::Principal{net::Principal::Kind::kView, "", false, *credentials.view};
  }
  return std::nullopt;
}

std::string LinkAuthenticator::RefusalMessage(std::string_view authorization,
                                              std::string_view raw_query) const {
  const net::RequestCredentials credentials = net::ReadCredentials(authorization, raw_query);
  if (credentials.share) return "this share link is not valid (revoked or expired)";
  if (credentials.view) return "no such view link";
  return users_->RefusalMessage(authorization, raw_query);
}

}  // namespace octoscope::app
