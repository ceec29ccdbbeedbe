#include "io/spacing.h"

#include <cmath>
#include <string>

#include "io/tiff_stack_volume.h"
#include "util/strings.h"

namespace octoscope::io {

std::optional<double> PositiveOrNone(std::optional<double> v) {
  if (v && std::isfinite(*v) && *v > 0) return v;
  return std::nullopt;
}

std::optional<double> MicrometresPerUnit(std::string_view unit) {
  const std::string u = ToLower(TrimWhitespace(unit));
  if (u == "micron" || u == "microns" || u == "um" || u == "\xC2\xB5m" || u == "\xCE\xBCm" ||
      u == "micrometer" || u == "micrometre" || u == "micrometers" || u == "micrometres") {
    return 1.0;
  }
  if (u == "nm" || u == "nanometer" || u == "nanometre" || u == "nanometers") return 1e-3;
  if (u == "mm" || u == "millimeter" || u == "millimetre" || u == "millimeters") return 1e3;
  if (u == "cm" || u == "centimeter" || u == "centimetre" || u == "centimeters") return 1e4;
  if (u == "m" || u == "meter" || u == "metre" || u == "meters") return 1e6;
  if (u == "inch" || u == "inches" || u == "in") return 25400.0;
  if (u == "angstrom" || u == "\xC3\x85") return 1e-4;
  return std::nullopt;
}

std::optional<double> SpacingFromResolution(std::optional<double> pixels_per_unit,
                                            double micrometres_per_unit) {
  if (!PositiveOrNone(pixels_per_unit)) return std::nullopt;
  return PositiveOrNone(micrometres_per_unit / *pixels_per_unit);
}

std::optional<double> SpacingFromCentimetreResolution(std::optional<double> pixels_per_unit,
                                                      uint16_t resolution_unit) {
  constexpr uint16_t kCentimetre = 3;  // TIFF RESUNIT_CENTIMETER.
  if (resolution_unit != kCentimetre) return std::nullopt;
  return SpacingFromResolution(pixels_per_unit, 1e4);
}

std::array<std::optional<double>, 3> TiffPageSpacing(const TiffIfd& ifd,
                                                     const ImageJDescription* imagej) {
  std::array<std::optional<double>, 3> spacing;
  if (imagej != nullptr) {
    if (std::optional<double> um = MicrometresPerUnit(imagej->unit)) {
      spacing[0] = SpacingFromResolution(ifd.x_resolution, *um);
      spacing[1] = SpacingFromResolution(ifd.y_resolution, *um);
      if (imagej->spacing) spacing[2] = PositiveOrNone(*um * std::fabs(*imagej->spacing));
      return spacing;
    }
  }
  spacing[0] = SpacingFromCentimetreResolution(ifd.x_resolution, ifd.resolution_unit);
  spacing[1] = SpacingFromCentimetreResolution(ifd.y_resolution, ifd.resolution_unit);
  return spacing;
}

void ApplySpacingOverrides(volume::VolumeInfo& info, const OpenOptions& options) {
  for (int axis = 0; axis < 3; ++axis) {
    if (options.spacing_um[axis]) info.spacing_um[axis] = options.spacing_um[axis];
  }
}

}  // namespace octoscope::io
