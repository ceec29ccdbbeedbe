// Display defaults: how a dataset looks when it is first opened — in the browser and in
// `octoscope render` without --params. Each channel gets the file's colour, or distinct defaults
// as Fiji and napari assign them (render::DefaultChannelColor), and a window from its histogram's
// 0.1 % and 99.9 % percentiles (auto-contrast), so a 12-bit camera's data does not open black in
// a 16-bit window nor 16-bit data white in an 8-bit one. A channel with no voxels counted yet
// keeps the stored type's full range.
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_DATASET_DISPLAY_DEFAULTS_H_
#define OCTOSCOPE_DATASET_DISPLAY_DEFAULTS_H_

#include "dataset/histogram.h"
#include "render/render_params.h"
#include "volume/volume_info.h"

namespace octoscope::dataset {

inline constexpr double kAutoContrastLow = 0.001;
inline constexpr double kAutoContrastHigh = 0.999;

// Sets channel c's window from the histogram's percentiles (stored units). False (window kept)
// when the channel has no voxels counted. REQUIRES: 0 <= c < histogram.channels().
bool AutoContrast(const Histogram& histogram, int c, render::ChannelParams& channel);

// Parameters of `mode` for `info`: one channel per volume channel with its default colour and
// window: the file's own display window where it gives one, else auto-contrast where `histogram`
// counts voxels (it may be null or have no channels; its value maps turn file units into stored
// ones), else the stored type's full range.
render::RenderParams DefaultDisplayParams(const volume::VolumeInfo& info,
                                          volume::DataType stored_type, const Histogram* histogram,
                                          render::RenderMode mode);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DISPLAY_DEFAULTS_H_
