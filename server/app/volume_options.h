// Shared command-line options for opening a volume (--series, --time, --level, --spacing), used
// by every subcommand that takes an INPUT, and the wiring of io::OpenOptions (JSON sidecars and
// Zarr metadata parsed by protocol/).
//
// Thread safety: not thread-safe; used at start-up.
#ifndef OCTOSCOPE_APP_VOLUME_OPTIONS_H_
#define OCTOSCOPE_APP_VOLUME_OPTIONS_H_

#include "app/flags.h"
#include "io/open_options.h"
#include "util/result.h"

namespace octoscope::app {

// Declares --series, --time, --level and --spacing on `flags`.
void AddVolumeFlags(Flags& flags);

// Builds the OpenOptions from parsed flags. Errors name the malformed flag.
Result<io::OpenOptions> VolumeOptionsFromFlags(const Flags& flags);

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_VOLUME_OPTIONS_H_
