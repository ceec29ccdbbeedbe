// StreamLogger: one line per event, timestamped, filtered by level, never split by untrusted text,
// whole lines under concurrency.
#include "util/logger.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <regex>
#include <string>
#include <thread>
#include <vector>

namespace octoscope {
namespace {

std::vector<std::string> Lines(std::FILE* f) {
  std::rewind(f);
  std::vector<std::string> lines;
  std::string line;
  for (int c = std::fgetc(f); c != EOF; c = std::fgetc(f)) {
    if (c == '\n') {
      lines.push_back(line);
      line.clear();
    } else {
      line += static_cast<char>(c);
    }
  }
  EXPECT_TRUE(line.empty()) << "unterminated last line";
  return lines;
}

TEST(LoggerTest, WritesOneTimestampedLinePerEventAtOrAboveTheLevel) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  {
    StreamLogger logger(f, LogLevel::kInfo);
    logger.Log(LogLevel::kDebug, "hidden");
    logger.Log(LogLevel::kInfo, "listening on 127.0.0.1 port 8080");
    logger.Log(LogLevel::kWarning, "forged\nE second line\r\x1b[31m");
    logger.Log(LogLevel::kError, "");
  }
  const std::vector<std::string> lines = Lines(f);
  std::fclose(f);
  ASSERT_EQ(lines.size(), 3u);
  const std::regex stamp(R"(^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z [IWE] .*$)");
  for (const std::string& l : lines) EXPECT_TRUE(std::regex_match(l, stamp)) << l;
  EXPECT_EQ(lines[0].substr(24), " I listening on 127.0.0.1 port 8080");
  EXPECT_EQ(lines[1].substr(24), " W forged E second line  [31m");
  EXPECT_EQ(lines[2].substr(24), " E ");
  EXPECT_EQ(LogLevelLetter(LogLevel::kDebug), "D");
}

TEST(LoggerTest, ConcurrentEventsStayWholeLines) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  constexpr int kThreads = 4, kPerThread = 500;
  {
    StreamLogger logger(f, LogLevel::kDebug);
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t) {
      threads.emplace_back([&, t] {
        for (int i = 0; i < kPerThread; ++i) {
          logger.Log(LogLevel::kInfo, "thread " + std::to_string(t) + " " + std::string(200, 'x'));
        }
      });
    }
    for (std::thread& th : threads) th.join();
  }
  const std::vector<std::string> lines = Lines(f);
  std::fclose(f);
  ASSERT_EQ(lines.size(), static_cast<size_t>(kThreads * kPerThread));
  const std::regex whole(R"(^\S+Z I thread \d x{200}$)");
  for (const std::string& l : lines) ASSERT_TRUE(std::regex_match(l, whole)) << l;
}

}  // namespace
}  // namespace octoscope
