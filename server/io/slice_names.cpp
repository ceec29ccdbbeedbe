#include "io/slice_names.h"

#include "util/checked_math.h"
#include "util/strings.h"

namespace octoscope::io {
namespace {

bool IsDigit(char c) { return c >= '0' && c <= '9'; }
bool IsLetter(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); }

// The marker of `markers` that `token` ends with, when it starts the token or follows a
// non-letter; "" otherwise.
std::string MarkerOf(std::string_view token, std::initializer_list<std::string_view> markers) {
  for (std::string_view marker : markers) {
    if (!EndsWithIgnoreCase(token, marker)) continue;
    const size_t start = token.size() - marker.size();
    if (start > 0 && IsLetter(token[start - 1])) continue;
    return std::string(token.substr(start));
  }
  return "";
}

// kInvalidArgument "\"<stem>\": <problem>" (built with append(): GCC 12's -Wrestrict misfires on
// chained operator+ at -O3).
Status NameError(std::string_view stem, std::string_view problem) {
  std::string message = "\"";
  message.append(Printable(stem)).append("\": ").append(problem);
  return InvalidArgumentError(std::move(message));
}

}  // namespace

bool IsTiffName(std::string_view name) {
  return EndsWithIgnoreCase(name, ".tif") || EndsWithIgnoreCase(name, ".tiff");
}

std::vector<NameToken> TokenizeName(std::string_view stem) {
  std::vector<NameToken> tokens;
  for (char c : stem) {
    if (tokens.empty() || tokens.back().digits != IsDigit(c)) tokens.push_back({"", IsDigit(c)});
    tokens.back().text += c;
  }
  return tokens;
}

std::string ChannelMarker(std::string_view token) {
  return MarkerOf(token, {"channel", "ch", "c", "w"});
}

uint64_t DigitValue(std::string_view digits) {
  uint64_t v = 0;
  for (char c : digits) {
    v = CheckedAdd(CheckedMul(v, 10).value_or(UINT64_MAX), static_cast<uint64_t>(c - '0'))
            .value_or(UINT64_MAX);
  }
  return v;
}

Result<PlaneName> ParsePlaneName(std::string_view stem) {
  const std::vector<NameToken> tokens = TokenizeName(stem);
  std::optional<size_t> channel, z, last;
  for (size_t p = 0; p < tokens.size(); ++p) {
    if (!tokens[p].digits) continue;
    const bool channel_marked = p > 0 && !ChannelMarker(tokens[p - 1].text).empty();
    const bool z_marked = p > 0 && !MarkerOf(tokens[p - 1].text, {"z"}).empty();
    if (channel_marked) {
      if (channel) {
        std::string problem = "two channel tokens in the name (\"";
        problem.append(tokens[*channel - 1].text).append(tokens[*channel].text).append("\" and \"");
        problem.append(tokens[p - 1].text).append(tokens[p].text).append("\")");
        return NameError(stem, problem);
      }
      channel = p;
      continue;
    }
    if (z_marked) {
      if (z) {
        return NameError(stem, "two z tokens in the name");
      }
      z = p;
      continue;
    }
    last = p;
  }
  if (!z) z = last;
  if (!z) {
    return NameError(stem, "no plane number in the name (expected e.g. \"z0012\")");
  }
  PlaneName name;
  name.z = DigitValue(tokens[*z].text);
  if (channel) name.channel = DigitValue(tokens[*channel].text);
  return name;
}

std::optional<uint64_t> ChannelFolderNumber(std::string_view folder_name) {
  const std::vector<NameToken> tokens = TokenizeName(folder_name);
  if (tokens.size() == 1 && tokens[0].digits) return DigitValue(tokens[0].text);
  std::optional<uint64_t> found;
  for (size_t p = 1; p < tokens.size(); ++p) {
    if (!tokens[p].digits || ChannelMarker(tokens[p - 1].text).empty()) continue;
    if (found) return std::nullopt;  // Ambiguous.
    found = DigitValue(tokens[p].text);
  }
  return found;
}

}  // namespace octoscope::io
