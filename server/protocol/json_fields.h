// JsonFields: the strict readers every JSON document of protocol/ is parsed with (WebSocket
// messages, REST bodies, render parameters, cameras, dataset requests, sidecars, Zarr metadata).
// PROTOCOL-INTERNAL: only protocol/ includes it (the only layer that touches JSON). Parsing is
// bounded before a tree is built: size, nesting depth, string and key lengths; duplicate keys are
// refused (two readers must never disagree on what a document says). Errors are kInvalidArgument
// and name the field by its path, written the way a client would ("channels[2].window: must be >
// 0"); untrusted text quoted in messages is shortened and escaped. Nothing throws out of these
// functions.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_
#define OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"
#include "util/status.h"

namespace octoscope::protocol {

// kInvalidArgument "<path>: <problem>".
Status FieldError(const std::string& path, std::string_view problem);
// The JSON type's name ("object", "number", ...), for messages.
std::string TypeOf(const nlohmann::json& j);
// Shortest round-tripping text of a number, for messages.
std::string FormatDouble(double v);
// "path.key" ("key" for the root) and "path[i]".
std::string Join(const std::string& path, std::string_view key);
std::string Index(const std::string& path, size_t i);

// Parses the whole text as one JSON object ("what" names the document in errors). Refused while
// parsing, before anything is built from them: texts over max_bytes, containers nested more than
// max_depth levels (the outer object is level 1; deep trees cost recursion later), strings or
// keys over max_string_bytes, and a key repeated within one object. Anything but an object is an
// error too.
Result<nlohmann::json> ParseJsonObject(
    std::string_view text, std::string_view what, uint64_t max_bytes, int max_depth,
    size_t max_string_bytes = std::numeric_limits<size_t>::max());

// The JSON value of `text` (any type), or kCorrupt "not valid JSON: <the parser's message, naming
// the position>" / "nested too deeply ..." / "duplicate key ...": for files (Zarr metadata) rather
// than requests. Containers nested more than `max_depth` levels and repeated keys are refused.
Result<nlohmann::json> ParseJsonLimited(std::string_view text, int max_depth);

// Refuses keys outside `known` (typos must not be silently ignored): `unknown key "K" in PATH
// (known: ...)` for the first unknown key K.
Status CheckKeys(const nlohmann::json& object, const std::string& path,
                 std::initializer_list<std::string_view> known);
// Refuses a non-object.
Status CheckObject(const nlohmann::json& j, const std::string& path);
// The member `key` of `object`, or an error naming the missing field (path.key).
Result<const nlohmann::json*> Require(const nlohmann::json& object, const std::string& path,
                                      std::string_view key);

Result<double> GetNumber(const nlohmann::json& j, const std::string& path);  // Finite.
Result<double> GetNumberIn(const nlohmann::json& j, const std::string& path, double lo, double hi);
// An integer in [lo, hi] (3.0 and 1e3 are refused: counts are integers).
Result<int64_t> GetInteger(const nlohmann::json& j, const std::string& path, int64_t lo,
                           int64_t hi);
Result<bool> GetBool(const nlohmann::json& j, const std::string& path);
Result<std::string> GetString(const nlohmann::json& j, const std::string& path);
// A string of at most `max_bytes` bytes (valid UTF-8: the parser checks); with `single_line`,
// control characters are refused too.
Result<std::string> GetString(const nlohmann::json& j, const std::string& path, size_t max_bytes,
                              bool single_line);
// An array of exactly `length` elements.
Status CheckArray(const nlohmann::json& j, const std::string& path, size_t length);
// `n` finite numbers, each within [lo, hi].
Result<std::vector<double>> GetNumbers(const nlohmann::json& j, const std::string& path, size_t n,
                                       double lo = -HUGE_VAL, double hi = HUGE_VAL);

// `text` cut to `max_bytes` with control characters replaced by spaces (one line for a message).
std::string OneLine(std::string_view text, size_t max_bytes);
// `text` as a JSON string literal (invalid UTF-8 replaced, never thrown).
std::string Quote(std::string_view text);
// `j` as compact text; invalid UTF-8 (never produced by the parser) is replaced, never thrown.
std::string Dump(const nlohmann::json& j);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_
