// ServeConfig: the configuration file of `octoscope serve --config FILE` (docs/server.md,
// "Configuration"): a JSON object whose keys are the long flag names (every option is also a
// flag; a flag given on the command line wins). Strict: unknown keys, wrong types and values out
// of range are errors naming the key.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_
#define OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "util/result.h"

namespace octoscope::protocol {

inline constexpr uint64_t kMaxServeConfigBytes = 1 << 20;

struct ServeConfig {
  std::vector<std::string> data;   // "data": [folders].
  std::vector<std::string> watch;  // "watch": [folders].
  std::optional<bool> demo;
  std::optional<std::string> cache;
  std::optional<std::string> bind;
  std::optional<int64_t> port;  // [0, 65535].
  std::optional<std::string> token;
  std::optional<std::string> token_file;
  std::optional<int64_t> ram_mb;     // [64, 2^24].
  std::optional<int64_t> device_mb;  // [0, 2^24].
  std::optional<std::string> device;
  std::optional<std::string> web;
  std::optional<int64_t> io_threads;              // [1, 64].
  std::optional<int64_t> max_upload_mb;           // [1, 2^20].
  std::optional<std::vector<int64_t>> demo_size;  // [x, y, z], each [16, 4096].
  std::optional<double> demo_rate;                // Planes per second, (0, 1000].
};

// `what` names the file in errors.
Result<ServeConfig> ParseServeConfig(std::string_view text, std::string_view what);

}  // namespace octoscope::protocol

#endif  // OCTOSCOPE_PROTOCOL_SERVE_CONFIG_H_
