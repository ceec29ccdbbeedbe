#include "dataset/display_defaults.h"

namespace octoscope::dataset {

bool AutoContrast(const Histogram& histogram, int c, render::ChannelParams& channel) {
  const auto lo = histogram.Percentile(c, kAutoContrastLow);
  const auto hi = histogram.Percentile(c, kAutoContrastHigh);
  if (!lo || !hi) return false;
  const volume::ValueMap& map = histogram.value_maps()[c];
  // Percentiles are in file units; the renderer's windows are in stored units.
  render::SetWindow(channel, map.ToStored(*lo), map.ToStored(*hi));
  return true;
}

render::RenderParams DefaultDisplayParams(const volume::VolumeInfo& info,
                                          volume::DataType stored_type, const Histogram* histogram,
                                          render::RenderMode mode) {
  render::RenderParams params =
      render::DefaultRenderParams(info.channel_count(), stored_type, mode);
  for (int c = 0; c < info.channel_count(); ++c) {
    params.channels[c].color = render::DefaultChannelColor(info, c);
    const auto& window = info.channels[c].window;
    if (window && histogram != nullptr && c < histogram->channels() &&
        window->end > window->start) {
      // The file's own display window (OME-Zarr omero, Imaris) is what its author chose.
      const volume::ValueMap& map = histogram->value_maps()[c];
      render::SetWindow(params.channels[c], map.ToStored(window->start), map.ToStored(window->end));
    } else if (histogram != nullptr && c < histogram->channels()) {
      AutoContrast(*histogram, c, params.channels[c]);
    }
  }
  return params;
}

}  // namespace octoscope::dataset
