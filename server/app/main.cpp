// octoscope: one binary, several subcommands. The composition root: it builds the objects each
// command needs and passes them down; nothing below app/ reads arguments or the environment.
#include <cstdio>
#include <exception>
#include <span>
#include <string>
#include <vector>

#include "app/commands.h"

namespace {

struct Command {
  const char* name;
  const char* summary;
  int (*run)(std::span<const std::string>);
};

constexpr Command kCommands[] = {
    {"info", "print a volume's metadata (and with --stats, per-channel min/max/mean)",
     octoscope::app::RunInfo},
    {"build", "build (or reuse) the multi-resolution octree of a scan in a cache directory",
     octoscope::app::RunBuild},
    {"demo", "write the built-in demo specimen (a synthetic fluorescent embryo) as OME-TIFF",
     octoscope::app::RunDemo},
    {"render", "render one image of a scan or an octree cache (OpenCL ray casting) to PNG/JPEG",
     octoscope::app::RunRender},
    {"serve", "the viewer server: browser clients, datasets, live streaming (prints the URL)",
     octoscope::app::RunServe},
    {"bench", "benchmarks: 'bench render' measures speed against error of the renderer",
     octoscope::app::RunBench},
};

void PrintUsage(std::FILE* out) {
  std::fprintf(
      out,
      "usage: octoscope COMMAND [ARGS]\n\n"
      "Octoscope reads multi-channel 3-D microscopy scans (OME-TIFF, TIFF/BigTIFF, ImageJ\n"
      "hyperstacks, slice folders, raw) slab by slab.\n\ncommands:\n");
  for (const Command& c : kCommands) std::fprintf(out, "  %-8s %s\n", c.name, c.summary);
  std::fprintf(out, "\n'octoscope COMMAND --help' describes each command.\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty() || args[0] == "--help" || args[0] == "-h" || args[0] == "help") {
    PrintUsage(args.empty() ? stderr : stdout);
    return args.empty() ? octoscope::app::kExitUsage : octoscope::app::kExitOk;
  }
  for (const Command& c : kCommands) {
    if (args[0] != c.name) continue;
    // The one catch point: an exception is a bug, but it still ends in one clear line.
    try {
      return c.run(std::span<const std::string>(args).subspan(1));
    } catch (const std::exception& e) {
      std::fprintf(stderr, "octoscope %s: internal error: %s\n", c.name, e.what());
      return 70;
    }
  }
  std::fprintf(stderr, "octoscope: unknown command '%s'\n\n", args[0].c_str());
  PrintUsage(stderr);
  return octoscope::app::kExitUsage;
}
