#include "protocol/strict_json.h"

#include <cmath>
#include <exception>
#include <stdexcept>
#include <vector>

#include "util/strings.h"

namespace octoscope::protocol::json_fields {
namespace {

// Thrown from the parser callback to stop parsing at the first limit broken.
class LimitError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string FormatNumber(double v) { return Json(v).dump(); }

}  // namespace

Result<Json> ParseObject(std::string_view text, std::string_view what, const ParseLimits& limits) {
  if (text.size() > limits.max_bytes) {
    return InvalidArgumentError(std::string(what) + ": " + std::to_string(text.size()) +
                                " bytes, at most " + std::to_string(limits.max_bytes));
  }
  // One set of keys per open object, to refuse duplicates ({"a":1,"a":2} would otherwise mean
  // whatever the last one says).
  std::vector<std::vector<std::string>> open_objects;
  const Json::parser_callback_t check = [&](int depth, Json::parse_event_t event, Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start:
      case Json::parse_event_t::array_start:
        // `depth` counts the containers already open around this one.
        if (depth + 1 > limits.max_depth) {
          throw LimitError("nested deeper than " + std::to_string(limits.max_depth) + " levels");
        }
        if (event == Json::parse_event_t::object_start) open_objects.emplace_back();
        break;
      case Json::parse_event_t::object_end:
        if (!open_objects.empty()) open_objects.pop_back();
        break;
      case Json::parse_event_t::key: {
        const std::string& key = parsed.get_ref<const std::string&>();
        if (key.size() > limits.max_string_bytes) {
          throw LimitError("a key is longer than " + std::to_string(limits.max_string_bytes) +
                           " bytes");
        }
        if (!open_objects.empty()) {
          std::vector<std::string>& keys = open_objects.back();
          for (const std::string& k : keys) {
            if (k == key) throw LimitError("duplicate key \"" + Printable(key, 60) + "\"");
          }
          keys.push_back(key);
        }
        break;
      }
      case Json::parse_event_t::value:
        if (parsed.is_string() &&
            parsed.get_ref<const std::string&>().size() > limits.max_string_bytes) {
          throw LimitError("a string is longer than " + std::to_string(limits.max_string_bytes) +
                           " bytes");
        }
        break;
      case Json::parse_event_t::array_end:
        break;
    }
    return true;
  };
  Json doc;
  try {
    doc = Json::parse(text.begin(), text.end(), check);
  } catch (const LimitError& e) {
    return InvalidArgumentError(std::string(what) + ": " + e.what());
  } catch (const std::exception& e) {
    // e.what() names the position; it may quote the input, so it is shortened and escaped.
    return InvalidArgumentError(std::string(what) + ": not valid JSON: " + Printable(e.what(), 160));
  }
  if (!doc.is_object()) {
    return InvalidArgumentError(std::string(what) + ": must be a JSON object, got " + TypeOf(doc));
  }
  return doc;
}

std::string TypeOf(const Json& j) {
  if (j.is_number()) return "number";
  return std::string(j.type_name());
}

std::string Join(std::string_view path, std::string_view key) {
  return path.empty() ? std::string(key) : std::string(path) + "." + std::string(key);
}

std::string Index(std::string_view path, size_t i) {
  return std::string(path) + "[" + std::to_string(i) + "]";
}

Status FieldError(std::string_view path, std::string_view problem) {
  return InvalidArgumentError(std::string(path) + ": " + std::string(problem));
}

Status CheckKeys(const Json& object, std::string_view path,
                 std::initializer_list<std::string_view> known) {
  for (const auto& item : object.items()) {
    bool found = false;
    for (std::string_view k : known) found = found || item.key() == k;
    if (!found) {
      std::string list;
      for (std::string_view k : known) list += (list.empty() ? "" : ", ") + std::string(k);
      return FieldError(Join(path, Printable(item.key(), 60)),
                        "unknown field (known: " + list + ")");
    }
  }
  return Status::Ok();
}

Status CheckObject(const Json& j, std::string_view path) {
  if (!j.is_object()) return FieldError(path, "must be an object, got " + TypeOf(j));
  return Status::Ok();
}

Result<const Json*> Require(const Json& object, std::string_view path, std::string_view key) {
  auto it = object.find(key);
  if (it == object.end()) return FieldError(Join(path, key), "missing");
  return &*it;
}

Result<int64_t> GetInteger(const Json& j, std::string_view path, int64_t lo, int64_t hi) {
  if (!j.is_number_integer()) {
    return FieldError(path, "must be an integer, got " +
                                (j.is_number() ? Printable(j.dump(), 40) : TypeOf(j)));
  }
  if (j.is_number_unsigned() && j.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX)) {
    return FieldError(path, "is " + j.dump() + ", must be in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "]");
  }
  const int64_t v = j.get<int64_t>();
  if (v < lo || v > hi) {
    return FieldError(path, "is " + std::to_string(v) + ", must be in [" + std::to_string(lo) +
                                ", " + std::to_string(hi) + "]");
  }
  return v;
}

Result<double> GetNumber(const Json& j, std::string_view path, double lo, double hi) {
  if (!j.is_number()) return FieldError(path, "must be a number, got " + TypeOf(j));
  const double v = j.get<double>();
  if (!std::isfinite(v)) return FieldError(path, "must be finite");
  if (v < lo || v > hi) {
    return FieldError(path, "is " + FormatNumber(v) + ", must be in [" + FormatNumber(lo) + ", " +
                                FormatNumber(hi) + "]");
  }
  return v;
}

Result<bool> GetBool(const Json& j, std::string_view path) {
  if (!j.is_boolean()) return FieldError(path, "must be true or false, got " + TypeOf(j));
  return j.get<bool>();
}

Result<std::string> GetString(const Json& j, std::string_view path, size_t max_bytes,
                              bool single_line) {
  if (!j.is_string()) return FieldError(path, "must be a string, got " + TypeOf(j));
  const std::string& s = j.get_ref<const std::string&>();
  if (s.size() > max_bytes) {
    return FieldError(path, "is " + std::to_string(s.size()) + " bytes long, at most " +
                                std::to_string(max_bytes));
  }
  if (single_line) {
    for (char c : s) {
      const unsigned char u = static_cast<unsigned char>(c);
      if (u < 0x20 || u == 0x7f) return FieldError(path, "must not contain control characters");
    }
  }
  return s;
}

Result<std::array<double, 3>> GetNumber3(const Json& j, std::string_view path, double lo,
                                         double hi) {
  if (!j.is_array()) return FieldError(path, "must be an array of 3 numbers, got " + TypeOf(j));
  if (j.size() != 3) {
    return FieldError(path, "must have 3 elements, has " + std::to_string(j.size()));
  }
  std::array<double, 3> out{};
  for (size_t i = 0; i < 3; ++i) {
    OCTO_ASSIGN_OR_RETURN(out[i], GetNumber(j[i], Index(path, i), lo, hi));
  }
  return out;
}

std::string OneLine(std::string_view text, size_t max_bytes) {
  std::string line(text.substr(0, max_bytes));
  for (char& c : line) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7f) c = ' ';
  }
  return line;
}

std::string Quote(std::string_view text) { return Dump(Json(std::string(text))); }

std::string Dump(const Json& j) { return j.dump(-1, ' ', false, Json::error_handler_t::replace); }

}  // namespace octoscope::protocol::json_fields
