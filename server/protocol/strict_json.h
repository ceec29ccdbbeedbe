// JSON fields: the strict reading of untrusted JSON that the protocol's message and API parsers
// share (internal to server/protocol; the only other code that includes nlohmann/json is the
// rest of this folder). Parsing is bounded before a tree is built: size, nesting depth, string
// and key lengths; duplicate keys are refused (two parsers must never disagree on a message).
// Field readers return kInvalidArgument errors of the form "<field path>: <problem>", the path
// written the way a client would ("state.camera.position[1]"); untrusted text in messages is
// shortened and escaped (Printable).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_STRICT_JSON_H_
#define OCTOSCOPE_PROTOCOL_STRICT_JSON_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "util/result.h"

namespace octoscope::protocol::json_fields {

using Json = nlohmann::json;

struct ParseLimits {
  size_t max_bytes = 0;         // Longer text is refused unparsed.
  int max_depth = 0;            // Objects/arrays nested deeper than this are refused.
  size_t max_string_bytes = 0;  // Longest string value or key.
};

// Parses `text` as one JSON object within `limits`. `what` names the document in errors
// ("message", "request body").
Result<Json> ParseObject(std::string_view text, std::string_view what, const ParseLimits& limits);

// The JSON type name ("string", "number", ...) for messages.
std::string TypeOf(const Json& j);

// "path.key" (or "key" at the top level) and "path[i]".
std::string Join(std::string_view path, std::string_view key);
std::string Index(std::string_view path, size_t i);

// kInvalidArgument "<path>: <problem>".
Status FieldError(std::string_view path, std::string_view problem);

// Refuses keys outside `known`, naming the first unknown one (typos are never ignored).
Status CheckKeys(const Json& object, std::string_view path,
                 std::initializer_list<std::string_view> known);

// Refuses a non-object.
Status CheckObject(const Json& j, std::string_view path);

// The member `key` of `object`, or an error naming the missing field.
Result<const Json*> Require(const Json& object, std::string_view path, std::string_view key);

// An integer in [lo, hi]; JSON numbers with a fraction or exponent form (3.0, 1e3) are refused.
Result<int64_t> GetInteger(const Json& j, std::string_view path, int64_t lo, int64_t hi);
// A finite number in [lo, hi].
Result<double> GetNumber(const Json& j, std::string_view path, double lo, double hi);
Result<bool> GetBool(const Json& j, std::string_view path);
// A string of at most `max_bytes` bytes (valid UTF-8: the parser checks); with `single_line`,
// control characters are refused too.
Result<std::string> GetString(const Json& j, std::string_view path, size_t max_bytes,
                              bool single_line);
// Exactly three finite numbers, each in [lo, hi].
Result<std::array<double, 3>> GetNumber3(const Json& j, std::string_view path, double lo,
                                         double hi);

// `text` cut to `max_bytes` with control characters replaced by spaces (one line for a message).
std::string OneLine(std::string_view text, size_t max_bytes);

// `text` as a JSON string literal (invalid UTF-8 replaced).
std::string Quote(std::string_view text);

// `j` as compact text; invalid UTF-8 (never produced by the parser) is replaced, never thrown.
std::string Dump(const Json& j);

}  // namespace octoscope::protocol::json_fields

#endif  // OCTOSCOPE_PROTOCOL_STRICT_JSON_H_
