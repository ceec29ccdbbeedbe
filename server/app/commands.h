// The octoscope subcommands. Each takes the arguments after its name and returns the process
// exit status: 0 success, 2 bad input (unreadable, corrupt or unsupported data; one line on
// stderr names the file and the problem), 64 bad usage (help printed to stderr).
//
// Thread safety: each command runs on the main thread; they build and own their objects.
#ifndef OCTOSCOPE_APP_COMMANDS_H_
#define OCTOSCOPE_APP_COMMANDS_H_

#include <span>
#include <string>

namespace octoscope::app {

inline constexpr int kExitOk = 0;
inline constexpr int kExitBadInput = 2;
inline constexpr int kExitUsage = 64;

int RunInfo(std::span<const std::string> args);    // app/info_command.cpp
int RunDemo(std::span<const std::string> args);    // app/demo_command.cpp
int RunBuild(std::span<const std::string> args);   // app/build_command.cpp
int RunRender(std::span<const std::string> args);  // app/render_command.cpp
int RunBench(std::span<const std::string> args);   // app/bench_command.cpp
// `bench upload`, dispatched by RunBench.
int RunBenchUpload(std::span<const std::string> args);  // app/upload_bench_command.cpp
int RunServe(std::span<const std::string> args);        // app/serve_command.cpp

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_COMMANDS_H_
