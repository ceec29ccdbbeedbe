#include "render/slice_overlay.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace octoscope::render {
namespace {

struct Point2 {
  double x = 0, y = 0;
};

// The smallest depth (along forward) a drawn point may have.
double MinDepth(const Camera& camera) {
  return camera.projection() == Projection::kOrthographic ? 0.0 : kOverlayNearUm;
}

// Projection without the in-front test. REQUIRES: perspective points have depth > 0.
Point2 Project(const Camera& camera, const Vec3& world) {
  const Vec3 d = world - camera.position();
  const double right = Dot(d, camera.right());
  const double up = Dot(d, camera.up());
  // Pixels per µm on the image plane (orthographic) or per unit of tangent (perspective).
  double scale;
  if (camera.projection() == Projection::kOrthographic) {
    scale = camera.height() / camera.ortho_height();
  } else {
    const double depth = Dot(d, camera.forward());
    const double tan_half = std::tan(camera.fov_y_degrees() * std::numbers::pi / 360.0);
    scale = camera.height() / (2 * tan_half * depth);
  }
  // Inverse of Camera::ImageRay: dx = x - width / 2 (right), dy = height / 2 - y (up).
  return {camera.width() / 2.0 + right * scale, camera.height() / 2.0 - up * scale};
}

// Distance from p to segment [a, b] (a point when a == b).
double DistanceToSegment(Point2 p, Point2 a, Point2 b) {
  const double ex = b.x - a.x, ey = b.y - a.y;
  const double len2 = ex * ex + ey * ey;
  double t = len2 > 0 ? ((p.x - a.x) * ex + (p.y - a.y) * ey) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  return std::hypot(p.x - (a.x + t * ex), p.y - (a.y + t * ey));
}

// Liang-Barsky: clips [a, b] to the rectangle [lo, hi]^2 per axis; false when nothing is left.
bool ClipSegment2D(Point2* a, Point2* b, Point2 lo, Point2 hi) {
  double t0 = 0, t1 = 1;
  const double dx = b->x - a->x, dy = b->y - a->y;
  const double p[4] = {-dx, dx, -dy, dy};
  const double q[4] = {a->x - lo.x, hi.x - a->x, a->y - lo.y, hi.y - a->y};
  for (int i = 0; i < 4; ++i) {
    if (p[i] == 0) {
      if (q[i] < 0) return false;  // Parallel to this edge and outside it.
      continue;
    }
    const double r = q[i] / p[i];
    if (p[i] < 0) {
      t0 = std::max(t0, r);
    } else {
      t1 = std::min(t1, r);
    }
    if (t0 > t1) return false;
  }
  const Point2 start = *a;
  *a = {start.x + t0 * dx, start.y + t0 * dy};
  *b = {start.x + t1 * dx, start.y + t1 * dy};
  return true;
}

// Rasterises segment [a, b] (pixel units) into `coverage` (max per pixel), recording newly
// touched pixels. Walks the major axis so the work is proportional to the segment's length.
void RasterizeSegment(Point2 a, Point2 b, int width, int height, std::vector<float>* coverage,
                      std::vector<size_t>* touched) {
  const double half = kOverlayLineWidthPx / 2;
  const double reach = half + 0.5;  // Beyond this distance the coverage is 0.
  // Keep the coordinates bounded (far-off perspective projections) without changing the line.
  const Point2 lo{-reach - 1, -reach - 1};
  const Point2 hi{width + reach + 1, height + reach + 1};
  if (!ClipSegment2D(&a, &b, lo, hi)) return;
  const bool x_major = std::abs(b.x - a.x) >= std::abs(b.y - a.y);
  // Work in (major, minor) coordinates; swap back when writing.
  const double a_major = x_major ? a.x : a.y, b_major = x_major ? b.x : b.y;
  const double a_minor = x_major ? a.y : a.x, b_minor = x_major ? b.y : b.x;
  const int major_size = x_major ? width : height;
  const int minor_size = x_major ? height : width;
  const double m_lo = std::min(a_major, b_major), m_hi = std::max(a_major, b_major);
  const double slope = m_hi > m_lo ? (b_minor - a_minor) / (b_major - a_major) : 0.0;
  // Minor-axis half extent that contains every pixel within `reach` of the line.
  const double minor_reach = reach * std::sqrt(1 + slope * slope);
  const int first = std::max(0, static_cast<int>(std::floor(m_lo - reach)));
  const int last = std::min(major_size - 1, static_cast<int>(std::floor(m_hi + reach)));
  for (int i = first; i <= last; ++i) {
    const double centre = i + 0.5;
    const double along = std::clamp(centre, m_lo, m_hi);
    const double minor = a_minor + (along - a_major) * slope;
    const int j0 = std::max(0, static_cast<int>(std::floor(minor - minor_reach)));
    const int j1 = std::min(minor_size - 1, static_cast<int>(std::floor(minor + minor_reach)));
    for (int j = j0; j <= j1; ++j) {
      const Point2 pixel = x_major ? Point2{centre, j + 0.5} : Point2{j + 0.5, centre};
      const double d = DistanceToSegment(pixel, a, b);
      const float c = static_cast<float>(std::clamp(half + 0.5 - d, 0.0, 1.0));
      if (c <= 0) continue;
      const int px = x_major ? i : j;
      const int py = x_major ? j : i;
      const size_t index = static_cast<size_t>(py) * static_cast<size_t>(width) + px;
      float& slot = (*coverage)[index];
      if (slot == 0) touched->push_back(index);
      slot = std::max(slot, c);
    }
  }
}

Status ValidatePlane(const SlicePlane& plane, size_t index) {
  const std::string where = "slice plane " + std::to_string(index) + ": ";
  if (plane.axis < 0 || plane.axis > 2) {
    return InvalidArgumentError(where + "axis must be 0, 1 or 2");
  }
  if (!std::isfinite(plane.position_um)) {
    return InvalidArgumentError(where + "position must be finite");
  }
  for (double v : plane.rgb) {
    if (!(v >= 0 && v <= 1)) return InvalidArgumentError(where + "colour must lie in [0, 1]");
  }
  return Status::Ok();
}

}  // namespace

std::optional<std::array<double, 2>> ProjectToImage(const Camera& camera, const Vec3& world) {
  const double depth = Dot(world - camera.position(), camera.forward());
  if (!(depth >= MinDepth(camera))) return std::nullopt;
  const Point2 p = Project(camera, world);
  return std::array<double, 2>{p.x, p.y};
}

std::optional<std::array<Vec3, 4>> SlicePlaneCorners(const Box3& bounds, const SlicePlane& plane) {
  const int a = plane.axis;
  if (!(plane.position_um >= bounds.lo[a] && plane.position_um <= bounds.hi[a])) {
    return std::nullopt;
  }
  // The two in-plane axes; corners go around (lo,lo) (hi,lo) (hi,hi) (lo,hi).
  const int u = a == 0 ? 1 : 0;
  const int v = a == 2 ? 1 : 2;
  std::array<Vec3, 4> corners;
  const double us[4] = {bounds.lo[u], bounds.hi[u], bounds.hi[u], bounds.lo[u]};
  const double vs[4] = {bounds.lo[v], bounds.lo[v], bounds.hi[v], bounds.hi[v]};
  for (int k = 0; k < 4; ++k) {
    corners[k][a] = plane.position_um;
    corners[k][u] = us[k];
    corners[k][v] = vs[k];
  }
  return corners;
}

Status DrawSlicePlanes(RenderImage* image, const Camera& camera, const Box3& bounds,
                       std::span<const SlicePlane> planes) {
  if (image->width != camera.width() || image->height != camera.height()) {
    return InvalidArgumentError(
        "overlay: image is " + std::to_string(image->width) + "x" + std::to_string(image->height) +
        ", camera " + std::to_string(camera.width()) + "x" + std::to_string(camera.height()));
  }
  const size_t pixels = static_cast<size_t>(image->width) * static_cast<size_t>(image->height);
  if (image->rgba.size() != pixels * 4) {
    return InvalidArgumentError("overlay: image buffer holds " +
                                std::to_string(image->rgba.size()) + " floats, expected " +
                                std::to_string(pixels * 4));
  }
  for (size_t i = 0; i < planes.size(); ++i) OCTO_RETURN_IF_ERROR(ValidatePlane(planes[i], i));

  std::vector<float> coverage(pixels, 0.0f);
  std::vector<size_t> touched;
  const double min_depth = MinDepth(camera);
  for (const SlicePlane& plane : planes) {
    const std::optional<std::array<Vec3, 4>> corners = SlicePlaneCorners(bounds, plane);
    if (!corners) continue;
    touched.clear();
    for (int k = 0; k < 4; ++k) {
      Vec3 a = (*corners)[k];
      Vec3 b = (*corners)[(k + 1) % 4];
      // Clip the edge to the region in front of the camera before projecting.
      const double da = Dot(a - camera.position(), camera.forward()) - min_depth;
      const double db = Dot(b - camera.position(), camera.forward()) - min_depth;
      if (da < 0 && db < 0) continue;
      if (da < 0) a = a + (b - a) * (da / (da - db));
      if (db < 0) b = b + (a - b) * (db / (db - da));
      RasterizeSegment(Project(camera, a), Project(camera, b), image->width, image->height,
                       &coverage, &touched);
    }
    // Composite the plane once per pixel (premultiplied "over").
    const float r = static_cast<float>(plane.rgb[0]);
    const float g = static_cast<float>(plane.rgb[1]);
    const float bl = static_cast<float>(plane.rgb[2]);
    for (size_t index : touched) {
      const float c = coverage[index];
      coverage[index] = 0;
      float* px = image->rgba.data() + index * 4;
      px[0] = r * c + px[0] * (1 - c);
      px[1] = g * c + px[1] * (1 - c);
      px[2] = bl * c + px[2] * (1 - c);
      px[3] = c + px[3] * (1 - c);
    }
  }
  return Status::Ok();
}

}  // namespace octoscope::render
