#include "protocol/query_string.h"

#include "util/strings.h"

namespace octoscope::protocol {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// The raw name of a "name=value" piece.
std::string_view RawName(std::string_view piece) { return piece.substr(0, piece.find('=')); }

}  // namespace

Result<std::string> PercentDecode(std::string_view text, bool plus_is_space) {
  std::string out;
  out.reserve(text.size());
  for (size_t i = 0; i < text.size(); ++i) {
    char c = text[i];
    if (c == '%') {
      const bool complete = i + 2 < text.size();
      const int hi = complete ? HexValue(text[i + 1]) : -1;
      const int lo = complete ? HexValue(text[i + 2]) : -1;
      if (hi < 0 || lo < 0) {
        return InvalidArgumentError("bad percent escape in \"" + Printable(text, 80) + "\"");
      }
      c = static_cast<char>(hi * 16 + lo);
      i += 2;
    } else if (c == '+' && plus_is_space) {
      c = ' ';
    }
    if (c == '\0') return InvalidArgumentError("encoded NUL byte in \"" + Printable(text, 80) + "\"");
    out += c;
  }
  return out;
}

Result<std::vector<QueryParameter>> ParseQueryString(std::string_view query) {
  std::vector<QueryParameter> out;
  for (std::string_view piece : Split(query, '&')) {
    if (piece.empty()) continue;
    if (out.size() == kMaxQueryParameters) {
      return InvalidArgumentError("more than " + std::to_string(kMaxQueryParameters) +
                                  " query parameters");
    }
    const size_t eq = piece.find('=');
    QueryParameter p;
    OCTO_ASSIGN_OR_RETURN(p.name, PercentDecode(piece.substr(0, eq), true));
    if (eq != std::string_view::npos) {
      OCTO_ASSIGN_OR_RETURN(p.value, PercentDecode(piece.substr(eq + 1), true));
    }
    out.push_back(std::move(p));
  }
  return out;
}

std::string RemoveQueryParameter(std::string_view query, std::string_view name) {
  std::string out;
  for (std::string_view piece : Split(query, '&')) {
    if (piece.empty()) continue;
    // Compare decoded names, so "%74oken" is removed as "token" is.
    Result<std::string> decoded = PercentDecode(RawName(piece), true);
    if (decoded.ok() && *decoded == name) continue;
    if (!out.empty()) out += '&';
    out += piece;
  }
  return out;
}

}  // namespace octoscope::protocol
