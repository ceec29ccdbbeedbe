#include "util/logger.h"

#include <chrono>
#include <ctime>
#include <string>

namespace octoscope {

std::string_view LogLevelLetter(LogLevel level) {
  switch (level) {
    case LogLevel::kDebug:
      return "D";
    case LogLevel::kInfo:
      return "I";
    case LogLevel::kWarning:
      return "W";
    case LogLevel::kError:
      return "E";
  }
  return "?";
}

void StreamLogger::Log(LogLevel level, std::string_view line) {
  if (level < min_level_) return;
  try {
    Write(level, line);
  } catch (...) {
    // Logging never fails the caller (an allocation failure loses the line).
  }
}

void StreamLogger::Write(LogLevel level, std::string_view line) {
  // UTC timestamp with milliseconds.
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()) %
                  1000;
  std::tm utc{};
  gmtime_r(&seconds, &utc);
  char stamp[40];
  std::strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &utc);
  std::string text = std::string(stamp) + "." + std::to_string(1000 + ms.count()).substr(1) +
                     "Z " + std::string(LogLevelLetter(level)) + " ";
  // One event, one line: control characters of untrusted text never split or forge lines.
  for (char c : line) text += (static_cast<unsigned char>(c) < 0x20) ? ' ' : c;
  text += '\n';
  std::lock_guard<std::mutex> lock(mu_);
  std::fputs(text.c_str(), out_);
  std::fflush(out_);
}

}  // namespace octoscope
