// Slice-plane overlay: the outlines of the slice planes drawn into a rendered 3-D view (the
// paper's Fig. 1), so the user sees where the three slice views cut the volume.
//
// Each SlicePlane {axis, position_um, rgb} cuts the volume box in a rectangle (nothing when the
// position lies outside the box's extent along the axis). Its four edges are clipped to the
// region in front of the camera (orthographic: the camera plane and beyond, as camera.h's rays
// see it; perspective: depth >= kOverlayNearUm in front of the eye), projected exactly with the
// camera's frame (ProjectToImage) and drawn as anti-aliased lines kOverlayLineWidthPx wide:
// a pixel's coverage is clamp(width / 2 + 0.5 - d, 0, 1) where d is the distance of its centre
// from the projected segment (pixel units). The coverage of one plane is the maximum over its
// edges (corners are not drawn twice), and the plane is composited over the image:
//   rgb = colour * a + rgb * (1 - a),   alpha = a + alpha * (1 - a)
// (the RenderImage is premultiplied). Only pixels inside the image are written; pixels with zero
// coverage are untouched. Planes are drawn in the order given (later ones on top). Lines are not
// hidden by the volume (an overlay, like the paper's figure).
//
// Thread safety: pure functions of their arguments; DrawSlicePlanes mutates only `image`.
#ifndef OCTOSCOPE_RENDER_SLICE_OVERLAY_H_
#define OCTOSCOPE_RENDER_SLICE_OVERLAY_H_

#include <array>
#include <optional>
#include <span>

#include "render/camera.h"
#include "render/linear_algebra.h"
#include "render/render_image.h"
#include "util/status.h"

namespace octoscope::render {

inline constexpr double kOverlayLineWidthPx = 1.5;
// Perspective near distance (µm) to which lines through or behind the eye are clipped.
inline constexpr double kOverlayNearUm = 1e-3;

struct SlicePlane {
  int axis = 2;                        // 0 = x, 1 = y, 2 = z: the plane's normal.
  double position_um = 0;              // Physical position along the axis.
  std::array<double, 3> rgb{1, 1, 1};  // Line colour, components in [0, 1].
};

// The image-plane point (pixel units: x right from the left edge, y down from the top; pixel
// (px, py) has its centre at (px + 0.5, py + 0.5)) where `world` projects, the inverse of
// Camera::ImageRay. nullopt when the point is not in front of the camera (orthographic: behind
// the camera plane; perspective: depth < kOverlayNearUm).
std::optional<std::array<double, 2>> ProjectToImage(const Camera& camera, const Vec3& world);

// The rectangle's four corners where plane cuts `bounds`, in order around it; nullopt when the
// position is outside [bounds.lo, bounds.hi] along the axis.
std::optional<std::array<Vec3, 4>> SlicePlaneCorners(const Box3& bounds, const SlicePlane& plane);

// Draws every plane into `image` (see the file comment). kInvalidArgument when the image's size
// differs from the camera's, the image buffer has the wrong length, or a plane is invalid (axis
// outside 0..2, position not finite, colour outside [0, 1]); the image is then untouched.
Status DrawSlicePlanes(RenderImage* image, const Camera& camera, const Box3& bounds,
                       std::span<const SlicePlane> planes);

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_SLICE_OVERLAY_H_
