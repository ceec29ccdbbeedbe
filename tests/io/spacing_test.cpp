// Tests for the shared spacing rules (io/spacing.h): positivity, units, the TIFF page rules
// (ImageJ unit= and spacing=, centimetre resolutions, ignored inch/none) and user overrides.
#include "io/spacing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "io/tiff_stack_volume.h"

namespace octoscope::io {
namespace {

TEST(SpacingTest, PositiveOrNone) {
  EXPECT_EQ(PositiveOrNone(2.5), 2.5);
  EXPECT_EQ(PositiveOrNone(std::nullopt), std::nullopt);
  EXPECT_EQ(PositiveOrNone(0.0), std::nullopt);
  EXPECT_EQ(PositiveOrNone(-1.0), std::nullopt);
  EXPECT_EQ(PositiveOrNone(std::numeric_limits<double>::infinity()), std::nullopt);
  EXPECT_EQ(PositiveOrNone(std::nan("")), std::nullopt);
}

TEST(SpacingTest, MicrometresPerUnit) {
  EXPECT_EQ(MicrometresPerUnit("micron"), 1.0);
  EXPECT_EQ(MicrometresPerUnit(" UM "), 1.0);
  EXPECT_EQ(MicrometresPerUnit("\xCE\xBCm"), 1.0);  // Greek mu.
  EXPECT_EQ(MicrometresPerUnit("nm"), 1e-3);
  EXPECT_EQ(MicrometresPerUnit("inch"), 25400.0);
  EXPECT_EQ(MicrometresPerUnit("pixel"), std::nullopt);
}

TEST(SpacingTest, ResolutionRules) {
  EXPECT_DOUBLE_EQ(SpacingFromResolution(4.0, 1.0).value_or(0), 0.25);
  EXPECT_EQ(SpacingFromResolution(0.0, 1.0), std::nullopt);
  EXPECT_EQ(SpacingFromResolution(std::nullopt, 1.0), std::nullopt);
  EXPECT_EQ(SpacingFromResolution(1e-320, 1.0), std::nullopt);  // 1 / denormal is infinite.
  EXPECT_DOUBLE_EQ(SpacingFromCentimetreResolution(20000.0, 3).value_or(0), 0.5);
  EXPECT_EQ(SpacingFromCentimetreResolution(72.0, 2), std::nullopt);  // Inch: a 72 dpi default.
  EXPECT_EQ(SpacingFromCentimetreResolution(72.0, 1), std::nullopt);  // No unit.
}

TEST(SpacingTest, TiffPageSpacing) {
  TiffIfd ifd;
  ifd.x_resolution = 2.0;
  ifd.y_resolution = 4.0;
  ifd.resolution_unit = 1;
  // ImageJ with a known unit: resolutions are pixels per that unit, spacing= is the z step.
  ImageJDescription ij = *ParseImageJDescription("ImageJ=1.54f\nunit=nm\nspacing=-300\n");
  auto s = TiffPageSpacing(ifd, &ij);
  EXPECT_DOUBLE_EQ(s[0].value_or(0), 0.5e-3);
  EXPECT_DOUBLE_EQ(s[1].value_or(0), 0.25e-3);
  EXPECT_DOUBLE_EQ(s[2].value_or(0), 0.3);  // |spacing|: ImageJ may store a negative step.
  // Without ImageJ (or with an unknown unit), only a centimetre ResolutionUnit counts.
  s = TiffPageSpacing(ifd, nullptr);
  EXPECT_FALSE(s[0] || s[1] || s[2]);
  ij.unit = "pixel";
  ifd.resolution_unit = 3;
  ifd.x_resolution = 10000.0;
  s = TiffPageSpacing(ifd, &ij);
  EXPECT_DOUBLE_EQ(s[0].value_or(0), 1.0);
  EXPECT_DOUBLE_EQ(s[1].value_or(0), 2500.0);
  EXPECT_FALSE(s[2]);
  ifd.resolution_unit = 2;
  s = TiffPageSpacing(ifd, nullptr);
  EXPECT_FALSE(s[0] || s[1] || s[2]);
}

TEST(SpacingTest, OverridesReplaceOnlyTheAxesGiven) {
  volume::VolumeInfo info;
  info.spacing_um = {1.0, 2.0, std::nullopt};
  OpenOptions options;
  options.spacing_um = {std::nullopt, 5.0, 7.0};
  ApplySpacingOverrides(info, options);
  EXPECT_EQ(info.spacing_um[0], 1.0);
  EXPECT_EQ(info.spacing_um[1], 5.0);
  EXPECT_EQ(info.spacing_um[2], 7.0);
}

}  // namespace
}  // namespace octoscope::io
