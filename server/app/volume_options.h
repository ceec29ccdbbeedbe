// Shared command-line options for opening a volume (--series, --time, --level, --spacing,
// --decode-threads), used by every subcommand that takes an INPUT, and the wiring of
// io::OpenOptions (JSON sidecars and Zarr metadata parsed by protocol/).
//
// Thread safety: not thread-safe; used at start-up.
#ifndef OCTOSCOPE_APP_VOLUME_OPTIONS_H_
#define OCTOSCOPE_APP_VOLUME_OPTIONS_H_

#include "app/flags.h"
#include "io/open_options.h"
#include "util/result.h"

namespace octoscope::app {

// Declares --series, --time, --level, --spacing and --decode-threads on `flags`.
void AddVolumeFlags(Flags& flags);

// OpenOptions with the defaults and the parsers protocol/ provides (JSON raw sidecars, Zarr
// metadata): for commands that open a volume without the volume flags. No warning hook.
io::OpenOptions DefaultOpenOptions();

// Builds the OpenOptions from parsed flags. Errors name the malformed flag. The input's warnings
// (VolumeInfo::warnings) are printed to stderr as "<command>: warning: <text>" when it is opened.
Result<io::OpenOptions> VolumeOptionsFromFlags(const Flags& flags);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_VOLUME_OPTIONS_H_
