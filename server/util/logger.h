// Logger: where long-running parts of the server (the net layer, sessions, datasets) report what
// happened, one line per event. There is no global logger: the composition root creates one and
// passes it down. StreamLogger writes "2024-05-01T12:00:00.123Z W message" lines to a FILE*.
//
// Thread safety: Log may be called from any thread concurrently; implementations must be
// thread-safe (StreamLogger serialises whole lines) and must not throw.
#ifndef OCTOSCOPE_UTIL_LOGGER_H_
#define OCTOSCOPE_UTIL_LOGGER_H_

#include <cstdio>
#include <mutex>
#include <string_view>

namespace octoscope {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

// "D", "I", "W", "E".
std::string_view LogLevelLetter(LogLevel level);

class Logger {
 public:
  virtual ~Logger() = default;
  // One event; `line` holds no newline (implementations replace control characters).
  virtual void Log(LogLevel level, std::string_view line) = 0;
};

// Writes lines at or above `min_level` to `out` (not owned; REQUIRES: outlives the logger),
// flushing each.
class StreamLogger : public Logger {
 public:
  StreamLogger(std::FILE* out, LogLevel min_level) : out_(out), min_level_(min_level) {}
  void Log(LogLevel level, std::string_view line) override;

 private:
  void Write(LogLevel level, std::string_view line);

  std::FILE* out_;
  LogLevel min_level_;
  std::mutex mu_;
};

// Discards everything.
class NullLogger : public Logger {
 public:
  void Log(LogLevel, std::string_view) override {}
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_LOGGER_H_
