// Replays the seeds and every regression of the WebSocket-protocol fuzz harness (fuzz/ws/, input
// format in fuzz/ws_fuzz_input.h) through the harness's own code: no crash, no broken invariant.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "ws_fuzz_input.h"

namespace octoscope::fuzz {
namespace {

namespace fs = std::filesystem;

TEST(WsFuzzReplay, SeedsAndRegressions) {
  size_t files = 0, parsed = 0;
  const fs::path base = fs::path(OCTOSCOPE_SOURCE_DIR) / "fuzz" / "ws";
  for (const char* kind : {"seeds", "regressions"}) {
    const fs::path dir = base / kind;
    if (!fs::is_directory(dir)) continue;
    for (const auto& entry : fs::directory_iterator(dir)) {
      if (!entry.is_regular_file()) continue;
      std::ifstream in(entry.path(), std::ios::binary);
      const std::vector<uint8_t> input((std::istreambuf_iterator<char>(in)),
                                       std::istreambuf_iterator<char>());
      const Status s = WsMessageInput(input);
      EXPECT_NE(s.code(), StatusCode::kInternal) << entry.path() << ": " << s.ToString();
      ++files;
      if (kind == std::string("seeds")) {
        // Every seed is a valid input: it exercises the parsers' accepting paths.
        EXPECT_TRUE(s.ok()) << entry.path() << ": " << s.ToString();
      }
      parsed += s.ok();
    }
  }
  EXPECT_GE(files, 10u);
  EXPECT_GE(parsed, 10u);
}

}  // namespace
}  // namespace octoscope::fuzz
