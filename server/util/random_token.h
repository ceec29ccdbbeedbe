// Random tokens: secrets (the server's access token, share links) and ids that must not be
// guessable, drawn from the kernel's CSPRNG (getrandom(2)).
//
// Thread safety: thread-safe.
#ifndef OCTOSCOPE_UTIL_RANDOM_TOKEN_H_
#define OCTOSCOPE_UTIL_RANDOM_TOKEN_H_

#include <string>

#include "util/result.h"

namespace octoscope {

// `bytes` random bytes as 2 * bytes lowercase hex digits. REQUIRES: 1 <= bytes <= 256.
// kInternal when the kernel cannot provide randomness.
Result<std::string> RandomHex(int bytes);

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_RANDOM_TOKEN_H_
