#include "protocol/json_fields.h"

#include <exception>
#include <limits>
#include <stdexcept>

#include "util/strings.h"

namespace octoscope::protocol {
namespace {

using nlohmann::json;

// Thrown from the parser callback to stop parsing at the first limit broken.
class LimitError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace

Status FieldError(const std::string& path, std::string_view problem) {
  return InvalidArgumentError(path + ": " + std::string(problem));
}

std::string TypeOf(const json& j) { return std::string(j.type_name()); }

std::string FormatDouble(double v) { return json(v).dump(); }

std::string Join(const std::string& path, std::string_view key) {
  return path.empty() ? std::string(key) : path + "." + std::string(key);
}

std::string Index(const std::string& path, size_t i) {
  return path + "[" + std::to_string(i) + "]";
}

namespace {

// Parses `text` with the limits (see ParseJsonObject); errors are kInvalidArgument "<problem>".
Result<json> ParseBounded(std::string_view text, int max_depth, size_t max_string_bytes) {
  // The keys of each open object, to refuse duplicates ({"a":1,"a":2} would otherwise mean
  // whatever the last one says). Objects are small (every schema's is), so a list is enough.
  std::vector<std::vector<std::string>> open_objects;
  const json::parser_callback_t check = [&](int depth, json::parse_event_t event, json& parsed) {
    switch (event) {
      case json::parse_event_t::object_start:
      case json::parse_event_t::array_start:
        // `depth` counts the containers already open around this one.
        if (depth + 1 > max_depth) {
          throw LimitError("nested too deeply (more than " + std::to_string(max_depth) +
                           " levels)");
        }
        if (event == json::parse_event_t::object_start) open_objects.emplace_back();
        break;
      case json::parse_event_t::object_end:
        if (!open_objects.empty()) open_objects.pop_back();
        break;
      case json::parse_event_t::key: {
        const std::string& key = parsed.get_ref<const std::string&>();
        if (key.size() > max_string_bytes) {
          throw LimitError("a key is longer than " + std::to_string(max_string_bytes) + " bytes");
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
      case json::parse_event_t::value:
        if (parsed.is_string() && parsed.get_ref<const std::string&>().size() > max_string_bytes) {
          throw LimitError("a string is longer than " + std::to_string(max_string_bytes) +
                           " bytes");
        }
        break;
      case json::parse_event_t::array_end:
        break;
    }
    return true;
  };
  try {
    return json::parse(text.begin(), text.end(), check);
  } catch (const LimitError& e) {
    return InvalidArgumentError(e.what());
  } catch (const std::exception& e) {
    // e.what() names the position; it may quote the input, so it is shortened and escaped.
    return InvalidArgumentError("not valid JSON: " + Printable(e.what(), 200));
  }
}

}  // namespace

Result<json> ParseJsonLimited(std::string_view text, int max_depth) {
  Result<json> doc = ParseBounded(text, max_depth, std::numeric_limits<size_t>::max());
  if (!doc.ok()) return CorruptError(doc.status().message());
  return doc;
}

Result<json> ParseJsonObject(std::string_view text, std::string_view what, uint64_t max_bytes,
                             int max_depth, size_t max_string_bytes) {
  if (text.size() > max_bytes) {
    return InvalidArgumentError(std::string(what) + ": " + std::to_string(text.size()) +
                                " bytes, larger than " + std::to_string(max_bytes));
  }
  Result<json> doc = ParseBounded(text, max_depth, max_string_bytes);
  if (!doc.ok()) return InvalidArgumentError(std::string(what) + ": " + doc.status().message());
  if (!doc->is_object()) {
    return InvalidArgumentError(std::string(what) + ": must be a JSON object, got " + TypeOf(*doc));
  }
  return doc;
}

Status CheckKeys(const json& object, const std::string& path,
                 std::initializer_list<std::string_view> known) {
  for (const auto& item : object.items()) {
    bool found = false;
    for (std::string_view k : known) found = found || item.key() == k;
    if (!found) {
      std::string list;
      for (std::string_view k : known) list += (list.empty() ? "" : ", ") + std::string(k);
      return InvalidArgumentError("unknown key \"" + Printable(item.key(), 60) + "\"" +
                                  (path.empty() ? "" : " in " + path) + " (known: " + list + ")");
    }
  }
  return Status::Ok();
}

Status CheckObject(const json& j, const std::string& path) {
  if (!j.is_object()) return FieldError(path, "must be an object, got " + TypeOf(j));
  return Status::Ok();
}

Result<const json*> Require(const json& object, const std::string& path, std::string_view key) {
  auto it = object.find(key);
  if (it == object.end()) return FieldError(Join(path, key), "missing");
  return &*it;
}

Result<double> GetNumber(const json& j, const std::string& path) {
  if (!j.is_number()) return FieldError(path, "must be a number, got " + TypeOf(j));
  const double v = j.get<double>();
  if (!std::isfinite(v)) return FieldError(path, "must be finite");
  return v;
}

Result<double> GetNumberIn(const json& j, const std::string& path, double lo, double hi) {
  OCTO_ASSIGN_OR_RETURN(double v, GetNumber(j, path));
  if (v < lo || v > hi) {
    return FieldError(path, "is " + FormatDouble(v) + ", must be in [" + FormatDouble(lo) + ", " +
                                FormatDouble(hi) + "]");
  }
  return v;
}

Result<int64_t> GetInteger(const json& j, const std::string& path, int64_t lo, int64_t hi) {
  if (!j.is_number_integer()) {
    return FieldError(path, "must be an integer, got " +
                                (j.is_number_float() ? Printable(j.dump(), 40) : TypeOf(j)));
  }
  if (j.is_number_unsigned() && j.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX)) {
    return FieldError(path, "is " + Printable(j.dump(), 40) + ", must be in " + std::to_string(lo) +
                                ".." + std::to_string(hi));
  }
  const int64_t v = j.get<int64_t>();
  if (v < lo || v > hi) {
    return FieldError(path, "is " + std::to_string(v) + ", must be in " + std::to_string(lo) +
                                ".." + std::to_string(hi));
  }
  return v;
}

Result<bool> GetBool(const json& j, const std::string& path) {
  if (!j.is_boolean()) return FieldError(path, "must be true or false, got " + TypeOf(j));
  return j.get<bool>();
}

Result<std::string> GetString(const json& j, const std::string& path) {
  if (!j.is_string()) return FieldError(path, "must be a string, got " + TypeOf(j));
  return j.get<std::string>();
}

Result<std::string> GetString(const json& j, const std::string& path, size_t max_bytes,
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

Status CheckArray(const json& j, const std::string& path, size_t length) {
  if (!j.is_array()) return FieldError(path, "must be an array, got " + TypeOf(j));
  if (j.size() != length) {
    return FieldError(
        path, "must have " + std::to_string(length) + " elements, has " + std::to_string(j.size()));
  }
  return Status::Ok();
}

Result<std::vector<double>> GetNumbers(const json& j, const std::string& path, size_t n, double lo,
                                       double hi) {
  OCTO_RETURN_IF_ERROR(CheckArray(j, path, n));
  std::vector<double> out(n);
  for (size_t i = 0; i < n; ++i) {
    OCTO_ASSIGN_OR_RETURN(out[i], GetNumberIn(j[i], Index(path, i), lo, hi));
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

std::string Quote(std::string_view text) { return Dump(json(std::string(text))); }

std::string Dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

}  // namespace octoscope::protocol
