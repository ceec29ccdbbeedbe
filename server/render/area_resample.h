// Area-average resampling of rendered images: each output pixel is the mean of the input image
// over the output pixel's footprint (partial input pixels weighted by the overlapping area). Used
// to serve one render of a view to several participants with smaller viewports of the same aspect
// (docs/protocol.md, "Per-participant frames"): for an integer ratio it is the plain box average.
//
// Thread safety: a pure function.
#ifndef OCTOSCOPE_RENDER_AREA_RESAMPLE_H_
#define OCTOSCOPE_RENDER_AREA_RESAMPLE_H_

#include "render/render_image.h"

namespace octoscope::render {

// `image` resampled to width x height. REQUIRES: image valid (rgba.size() == w * h * 4, both
// >= 1); 1 <= width <= image.width and 1 <= height <= image.height (downsampling only).
RenderImage AreaResample(const RenderImage& image, int width, int height);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_AREA_RESAMPLE_H_
