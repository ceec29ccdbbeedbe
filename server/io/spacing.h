// Spacing rules shared by the readers: which physical voxel pitch a file's tags describe, and how
// the user's overrides replace it. One place, so that a TIFF stack, an ImageJ file, a slice
// folder, an OME-TIFF and a raw file opened with the same options agree.
//
// Rules for a TIFF page (TiffPageSpacing):
//  - an ImageJ description whose unit= is known: x/y = unit / X/YResolution, z = |spacing| * unit;
//  - otherwise a ResolutionUnit of centimetres: x/y = 1e4 µm / resolution (pixels per cm);
//  - an inch or unitless resolution gives nothing: TIFF writers put a meaningless 72 dpi there.
// Every spacing is finite and > 0, or absent.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_IO_SPACING_H_
#define OCTOSCOPE_IO_SPACING_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string_view>

#include "io/open_options.h"
#include "io/tiff_file.h"
#include "volume/volume_info.h"

namespace octoscope::io {

struct ImageJDescription;  // io/tiff_stack_volume.h

// `v` when it is finite and > 0, else nullopt (a spacing must be one or absent).
std::optional<double> PositiveOrNone(std::optional<double> v);

// Micrometres per `unit` ("micron", "um", "µm", "nm", "mm", "cm", "m", "inch" …); nullopt when the
// unit is unknown or "pixel".
std::optional<double> MicrometresPerUnit(std::string_view unit);

// The pitch (µm) of a resolution tag given in pixels per unit: micrometres_per_unit / resolution.
std::optional<double> SpacingFromResolution(std::optional<double> pixels_per_unit,
                                            double micrometres_per_unit);

// x/y pitch from a TIFF resolution tag when its ResolutionUnit is centimetres (3); else nullopt.
std::optional<double> SpacingFromCentimetreResolution(std::optional<double> pixels_per_unit,
                                                      uint16_t resolution_unit);

// The spacing (µm) of a TIFF page by the rules above. `imagej`: the page's parsed ImageJ
// description, or nullptr when it has none.
std::array<std::optional<double>, 3> TiffPageSpacing(const TiffIfd& ifd,
                                                     const ImageJDescription* imagej);

// Replaces info.spacing_um per axis where options.spacing_um is set.
void ApplySpacingOverrides(volume::VolumeInfo& info, const OpenOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_SPACING_H_
