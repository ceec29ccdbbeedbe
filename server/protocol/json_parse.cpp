#include "protocol/json_parse.h"

#include <exception>
#include <stdexcept>
#include <string>

#include "util/strings.h"

namespace octoscope::protocol {

Result<nlohmann::json> ParseJsonLimited(std::string_view text, int max_depth) {
  try {
    const nlohmann::json::parser_callback_t limit_depth =
        [max_depth](int depth, nlohmann::json::parse_event_t, nlohmann::json&) {
          if (depth > max_depth) throw std::length_error("nested too deeply");
          return true;
        };
    return nlohmann::json::parse(text.begin(), text.end(), limit_depth);
  } catch (const std::exception& e) {
    // e.what() names the position; it may quote the input, so it is shortened.
    return CorruptError("not valid JSON: " + Printable(e.what(), 200));
  }
}

}  // namespace octoscope::protocol
