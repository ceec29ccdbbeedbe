// Small string helpers: strict number parsing (no locale, no silent truncation), natural ("human")
// ordering of file names, and case-insensitive comparison.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_UTIL_STRINGS_H_
#define OCTOSCOPE_UTIL_STRINGS_H_

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace octoscope {

// Whole-string parses; leading/trailing ASCII whitespace is allowed, anything else is not.
std::optional<int64_t> ParseInt64(std::string_view text);
std::optional<double> ParseDouble(std::string_view text);

// True when `a` sorts before `b` in natural order: runs of digits compare by value
// ("z2.tif" < "z10.tif"), other characters case-insensitively, ties broken byte-wise.
bool NaturalLess(std::string_view a, std::string_view b);

bool EqualsIgnoreCase(std::string_view a, std::string_view b);
bool EndsWithIgnoreCase(std::string_view text, std::string_view suffix);
std::string ToLower(std::string_view text);
std::string_view TrimWhitespace(std::string_view text);

// Splits on `separator`; keeps empty pieces.
std::vector<std::string_view> Split(std::string_view text, char separator);

// Shortens `text` for inclusion in an error message (untrusted input can be huge or binary).
std::string Printable(std::string_view text, size_t max_length = 64);

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_STRINGS_H_
