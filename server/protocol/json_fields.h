// JsonFields: the strict field readers every JSON document of protocol/ is parsed with (render
// parameters, cameras, dataset requests, sidecars). PROTOCOL-INTERNAL: only protocol/ includes
// it (the only layer that touches JSON). Errors are kInvalidArgument and name the field by its
// path ("channels[2].window: must be > 0"); nothing throws out of these functions.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_
#define OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_

#include <cmath>
#include <cstdint>
#include <initializer_list>
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

// Parses the whole text as one JSON object ("what" names the document in errors). Texts over
// max_bytes, nesting deeper than max_depth (refused while parsing: deep trees cost recursion
// later) and anything but an object are errors.
Result<nlohmann::json> ParseJsonObject(std::string_view text, std::string_view what,
                                       uint64_t max_bytes, int max_depth);

// Refuses keys outside `known` (typos must not be silently ignored).
Status CheckKeys(const nlohmann::json& object, const std::string& path,
                 std::initializer_list<std::string_view> known);

Result<double> GetNumber(const nlohmann::json& j, const std::string& path);  // Finite.
Result<double> GetNumberIn(const nlohmann::json& j, const std::string& path, double lo, double hi);
// An integer in [lo, hi] (3.0 is refused: counts are integers).
Result<int64_t> GetInteger(const nlohmann::json& j, const std::string& path, int64_t lo,
                           int64_t hi);
Result<bool> GetBool(const nlohmann::json& j, const std::string& path);
Result<std::string> GetString(const nlohmann::json& j, const std::string& path);
// An array of exactly `length` elements.
Status CheckArray(const nlohmann::json& j, const std::string& path, size_t length);
// `n` finite numbers, each within [lo, hi].
Result<std::vector<double>> GetNumbers(const nlohmann::json& j, const std::string& path, size_t n,
                                       double lo = -HUGE_VAL, double hi = HUGE_VAL);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_JSON_FIELDS_H_
