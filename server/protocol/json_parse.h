// Parsing untrusted JSON text for the protocol documents: one checked entry point that refuses
// hostile nesting while parsing (deep trees also cost recursion when destroyed or dumped) and
// turns nlohmann's exceptions into a Status. Included only by protocol/ sources (the only layer
// with JSON).
//
// Thread safety: a pure function.
#ifndef OCTOSCOPE_PROTOCOL_JSON_PARSE_H_
#define OCTOSCOPE_PROTOCOL_JSON_PARSE_H_

#include <nlohmann/json.hpp>
#include <string_view>

#include "util/result.h"

namespace octoscope::protocol {

// The JSON value of `text`, or Corrupt "not valid JSON: <nlohmann's message, naming the
// position>" (also for nesting deeper than `max_depth`). Never throws.
Result<nlohmann::json> ParseJsonLimited(std::string_view text, int max_depth);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_JSON_PARSE_H_
