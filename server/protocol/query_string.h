// Query strings and percent-encoding of HTTP request targets (RFC 3986): the strict decoding the
// HTTP API's parameters and the static file paths go through.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_QUERY_STRING_H_
#define OCTOSCOPE_PROTOCOL_QUERY_STRING_H_

#include <cstddef>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "util/result.h"

namespace octoscope::protocol {

// More parameters than this are refused (a request has a handful).
inline constexpr size_t kMaxQueryParameters = 64;

// Decodes %XX escapes (and '+' as a space when `plus_is_space`, as in query strings). A '%' not
// followed by two hex digits is an error; decoded NUL bytes are refused.
Result<std::string> PercentDecode(std::string_view text, bool plus_is_space);

struct QueryParameter {
  std::string name;
  std::string value;  // "" for a bare "name".
};

// Splits "a=1&b=2" (without the '?') into decoded parameters, in order; empty pieces ("a=1&&b")
// are skipped.
Result<std::vector<QueryParameter>> ParseQueryString(std::string_view query);

// `query` without its parameters named `name` (the raw text of the others, in order).
std::string RemoveQueryParameter(std::string_view query, std::string_view name);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_QUERY_STRING_H_
