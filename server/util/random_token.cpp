#include "util/random_token.h"

#include <sys/random.h>

#include <cerrno>
#include <cstring>
#include <vector>

namespace octoscope {

Result<std::string> RandomHex(int bytes) {
  std::vector<unsigned char> raw(static_cast<size_t>(bytes));
  size_t filled = 0;
  while (filled < raw.size()) {
    const ssize_t n = getrandom(raw.data() + filled, raw.size() - filled, 0);
    if (n < 0) {
      if (errno == EINTR) continue;
      return InternalError(std::string("getrandom: ") + std::strerror(errno));
    }
    filled += static_cast<size_t>(n);
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  out.reserve(raw.size() * 2);
  for (unsigned char b : raw) {
    out += kHex[b >> 4];
    out += kHex[b & 15];
  }
  return out;
}

}  // namespace octoscope
