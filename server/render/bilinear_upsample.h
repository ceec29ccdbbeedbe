// Bilinear upsampling of a rendered image: what a browser does when it draws a reduced-scale
// frame onto its full-size canvas (docs/protocol.md, interactive frames), for command-line
// renders at a reduced scale (`octoscope render --scale`). Pixel centres are aligned (output
// pixel x samples input coordinate (x + 0.5) * in / out - 0.5) and edges are clamped. The image
// is premultiplied, so interpolating all four components is exact compositing-wise.
//
// Thread safety: a pure function.
#ifndef OCTOSCOPE_RENDER_BILINEAR_UPSAMPLE_H_
#define OCTOSCOPE_RENDER_BILINEAR_UPSAMPLE_H_

#include "render/render_image.h"

namespace octoscope::render {

// `image` resampled to width x height. REQUIRES: image valid (rgba.size() == w * h * 4, both
// >= 1); width >= image.width and height >= image.height (upsampling only).
RenderImage BilinearUpsample(const RenderImage& image, int width, int height);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_BILINEAR_UPSAMPLE_H_
