#include "io/hdf5_call.h"

#include <string>

#include "util/strings.h"

namespace octoscope::io {
namespace {

// Keeps the innermost (last walked downward) description of the error stack.
herr_t KeepInnermost(unsigned, const H5E_error2_t* error, void* client) {
  auto* message = static_cast<std::string*>(client);
  if (error != nullptr && error->desc != nullptr && error->desc[0] != '\0') {
    *message = error->desc;
  } else if (error != nullptr && error->func_name != nullptr) {
    *message = std::string("error in ") + error->func_name;
  }
  return 0;
}

}  // namespace

void Hdf5Quiet() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

Status Hdf5Error(std::string_view call_text) {
  std::string innermost;
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_DOWNWARD, KeepInnermost, &innermost);
  H5Eclear2(H5E_DEFAULT);
  // Collapse whitespace runs (call texts span lines) and keep the message on one line.
  std::string call;
  for (char c : call_text) {
    const bool space = c == ' ' || c == '\n' || c == '\t' || c == '\r';
    if (space && (call.empty() || call.back() == ' ')) continue;
    call += space ? ' ' : c;
  }
  for (char& c : innermost) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  return CorruptError(call + " failed" +
                      (innermost.empty() ? std::string() : ": " + Printable(innermost, 200)));
}

void Hdf5Id::Reset() {
  if (id_ >= 0) {
    // Closing never fails in a way the caller could act on; keep its error stack clean.
    if (H5Idec_ref(id_) < 0) H5Eclear2(H5E_DEFAULT);
    id_ = H5I_INVALID_HID;
  }
}

}  // namespace octoscope::io
