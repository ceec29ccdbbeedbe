// Camera: where an image is seen from and how its pixels turn into rays, in physical coordinates
// (micrometres, volume corner at the origin; see render/render_params.h).
//
// The camera has a position, an orthonormal frame (forward, right, up; right = forward x up) and
// an image of width x height pixels. Pixel (px, py) has its centre at image-plane coordinates
// (px + 0.5, py + 0.5); row 0 is the top of the image (the +up side), column 0 the left (-right).
//  - Orthographic: every ray has direction `forward` and starts on the plane through `position`
//    perpendicular to it; the image covers ortho_height µm vertically, ortho_height * width /
//    height horizontally, centred on `position`.
//  - Perspective: every ray starts at `position`; fov_y_degrees is the full vertical field of
//    view and pixels are square.
// Rays are half-lines (t >= 0): nothing behind the camera plane or eye is seen, so a perspective
// camera inside the volume sees what is in front of it.
//
// Standard views (fitted to a physical bounding box, image axes along increasing voxel indices):
//   z: looks along +z, image x = +x, image rows = +y (the usual microscope view of a plane)
//   y: looks along -y, image x = +x, image rows = +z
//   x: looks along +x, image x = +y, image rows = +z
//   iso: looks along (1, 1, 1) / sqrt 3 with up as close to -y as possible
// An orthographic standard view of an axis whose image size equals the volume's voxel counts
// (e.g. z at nx x ny, isotropic x/y spacing) puts each pixel centre on a voxel column's centre.
//
// Invariants: width, height in [1, kMaxImageSize]; frame orthonormal; fov in (0, 180);
// ortho_height > 0; everything finite.
// Thread safety: an immutable value; GenerateRay may be called from any thread.
#ifndef OCTOSCOPE_RENDER_CAMERA_H_
#define OCTOSCOPE_RENDER_CAMERA_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string_view>

#include "render/linear_algebra.h"
#include "util/result.h"
#include "volume/volume_info.h"

namespace octoscope::render {

inline constexpr int kMaxImageSize = 16384;

enum class Projection { kOrthographic, kPerspective };
enum class StandardView { kX, kY, kZ, kIso };

std::string_view ProjectionName(Projection p);  // "ortho", "perspective".
std::optional<Projection> ProjectionFromName(std::string_view name);
std::string_view StandardViewName(StandardView v);  // "x", "y", "z", "iso".
std::optional<StandardView> StandardViewFromName(std::string_view name);

// An axis-aligned box. Invariant: lo <= hi componentwise.
struct Box3 {
  Vec3 lo;
  Vec3 hi;
  Vec3 Center() const { return (lo + hi) * 0.5; }
  Vec3 Extent() const { return hi - lo; }
};

// The voxel pitch of `info` in µm per axis; an unknown spacing counts as 1 µm.
Vec3 PhysicalSpacing(const volume::VolumeInfo& info);
// [0, size * spacing] per axis.
Box3 PhysicalBounds(const std::array<int64_t, 3>& size, const Vec3& spacing);
Box3 PhysicalBounds(const volume::VolumeInfo& info);

// A half-line origin + t * direction, t >= 0. Invariant: |direction| == 1.
struct Ray {
  Vec3 origin;
  Vec3 direction;
  Vec3 At(double t) const { return origin + direction * t; }
};

class Camera {
 public:
  // A camera at `position` looking at `target`; `up` need not be perpendicular to the view
  // direction but must not be parallel to it. `fov_y_degrees` is used by perspective cameras,
  // `ortho_height` (µm) by orthographic ones; both are validated either way.
  static Result<Camera> LookAt(Projection projection, const Vec3& position, const Vec3& target,
                               const Vec3& up, int width, int height, double fov_y_degrees,
                               double ortho_height);

  // A camera from a world-to-camera matrix in the OpenGL convention: the camera looks along its
  // -Z axis, +Y is up, +X right. Errors unless the linear part is a rotation (orthonormal,
  // determinant +1, within 1e-6).
  static Result<Camera> FromViewMatrix(Projection projection, const Mat4& world_to_camera,
                                       int width, int height, double fov_y_degrees,
                                       double ortho_height);

  // A standard view fitted so that `bounds` fills the image as far as the aspect ratio allows:
  // orthographic: the box's projection just fits; perspective: its bounding sphere just fits.
  static Result<Camera> Standard(StandardView view, Projection projection, const Box3& bounds,
                                 int width, int height, double fov_y_degrees = 30);

  // The ray through the centre of pixel (px, py). REQUIRES: 0 <= px < width, 0 <= py < height.
  Ray PixelRay(int px, int py) const { return ImageRay(px + 0.5, py + 0.5); }
  // The ray through image-plane point (x, y), in pixel units (0 .. width, 0 .. height).
  Ray ImageRay(double x, double y) const;

  // World-to-camera matrix (OpenGL convention, as FromViewMatrix takes it).
  Mat4 ViewMatrix() const;

  Projection projection() const { return projection_; }
  const Vec3& position() const { return position_; }
  const Vec3& forward() const { return forward_; }
  const Vec3& right() const { return right_; }
  const Vec3& up() const { return up_; }
  int width() const { return width_; }
  int height() const { return height_; }
  double fov_y_degrees() const { return fov_y_degrees_; }
  double ortho_height() const { return ortho_height_; }

 private:
  Camera() = default;
  static Result<Camera> FromFrame(Projection projection, const Vec3& position, const Vec3& forward,
                                  const Vec3& up, int width, int height, double fov_y_degrees,
                                  double ortho_height);

  Projection projection_ = Projection::kOrthographic;
  Vec3 position_;
  Vec3 forward_{0, 0, 1};
  Vec3 right_{1, 0, 0};
  Vec3 up_{0, -1, 0};
  int width_ = 1;
  int height_ = 1;
  double fov_y_degrees_ = 30;
  double ortho_height_ = 1;
  double tan_half_fov_ = 0;  // Derived: tan(fov_y / 2).
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_CAMERA_H_
