// ServeSettings: the options of `octoscope serve`, from the flags and the --config file (a flag
// on the command line wins over the file; docs/server.md "Configuration"), with defaults
// resolved and checked: the cache folder, the web client's folder, the token (given, read from a
// file, or a fresh random 128-bit one), and the safety rule that a non-loopback bind needs an
// explicit token.
//
// Thread safety: functions of the main thread at start-up.
#ifndef OCTOSCOPE_APP_SERVE_SETTINGS_H_
#define OCTOSCOPE_APP_SERVE_SETTINGS_H_

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "app/flags.h"
#include "util/result.h"

namespace octoscope::app {

struct ServeSettings {
  std::vector<std::filesystem::path> data_dirs;
  std::vector<std::filesystem::path> watch_dirs;
  bool demo = false;
  std::array<int64_t, 3> demo_size{256, 256, 160};
  double demo_rate = 5;  // Planes (all channels) per second.
  std::filesystem::path cache_dir;
  std::filesystem::path web_root;
  std::string bind = "127.0.0.1";
  uint16_t port = 8080;
  std::string token;
  bool token_generated = false;
  uint64_t ram_mb = 0;
  uint64_t device_mb = 0;  // 0 = automatic.
  std::string device;      // OpenCL device preference ("" = best).
  int io_threads = 2;
  int encoder_threads = 2;
  uint64_t max_upload_mb = 1024;
  std::filesystem::path state_dir;  // View links live in state_dir/views.
  std::string public_url;           // "" = http://BIND:PORT/ (ends with "/").
  int max_sessions = 64;
  int max_participants = 16;
  int64_t idle_timeout_s = 900;
};

void AddServeFlags(Flags& flags);

// kInvalidArgument for contradictory or unsafe options (exit 64), other errors for files that
// cannot be read (exit 2).
Result<ServeSettings> ResolveServeSettings(const Flags& flags);

// The URL to open: http://HOST:PORT/?token=TOKEN[&dataset=ID].
std::string ServeUrl(const ServeSettings& settings, uint16_t port, const std::string& dataset);

// True for 127.0.0.0/8, ::1 and "localhost".
bool IsLoopback(const std::string& address);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_SERVE_SETTINGS_H_
