// Test helper: runs the real octoscope binary and captures its exit status and output.
#ifndef OCTOSCOPE_TESTS_APP_RUN_OCTOSCOPE_H_
#define OCTOSCOPE_TESTS_APP_RUN_OCTOSCOPE_H_

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace octoscope::app {

namespace fs = std::filesystem;

struct RunResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

// Runs the octoscope binary with `args` (shell-quoted by the caller), capturing both streams.
// `env` ("NAME=value ") is put before the command. Exit code -1 when killed by a signal.
inline RunResult RunOctoscope(const std::string& args, const std::string& env = "") {
  fs::path err_file =
      fs::temp_directory_path() / ("octoscope-test-stderr-" + std::to_string(getpid()));
  std::string command = env;
  command.append(OCTOSCOPE_BINARY).append(" ").append(args).append(" 2>").append(err_file.string());
  RunResult result;
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return result;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) result.out.append(buf.data(), n);
  int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream err(err_file);
  result.err.assign(std::istreambuf_iterator<char>(err), {});
  fs::remove(err_file);
  return result;
}

inline std::string Quote(const fs::path& p) {
  // Built with append(): GCC 12's -Wrestrict misfires on chained operator+ at -O3.
  std::string quoted = "'";
  quoted.append(p.string());
  quoted.append("'");
  return quoted;
}

}  // namespace octoscope::app

#endif  // OCTOSCOPE_TESTS_APP_RUN_OCTOSCOPE_H_
