#include "protocol/grant_ref.h"

#include <algorithm>

namespace octoscope::protocol {
namespace {

constexpr std::pair<GrantRef::Kind, std::string_view> kKinds[] = {
    {GrantRef::Kind::kUser, "user:"},
    {GrantRef::Kind::kShare, "share:"},
    {GrantRef::Kind::kView, "view:"}};

bool IsGrantIdChar(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
         c == '-' || c == '.';
}

}  // namespace

std::string GrantRefText(const GrantRef& grant) {
  for (const auto& [kind, prefix] : kKinds) {
    if (kind == grant.kind) return std::string(prefix) + grant.id;
  }
  return grant.id;
}

Result<GrantRef> ParseGrantRef(std::string_view text) {
  for (const auto& [kind, prefix] : kKinds) {
    if (!text.starts_with(prefix)) continue;
    const std::string_view id = text.substr(prefix.size());
    if (id.empty() || id.size() > kMaxGrantIdBytes ||
        !std::all_of(id.begin(), id.end(), IsGrantIdChar)) {
      break;
    }
    return GrantRef{kind, std::string(id)};
  }
  return InvalidArgumentError("not a grant (expected user:ID, share:ID or view:ID)");
}

}  // namespace octoscope::protocol
