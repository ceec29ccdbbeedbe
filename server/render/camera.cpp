#include "render/camera.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

namespace octoscope::render {
namespace {

Status CheckImageSize(int width, int height) {
  if (width < 1 || height < 1 || width > kMaxImageSize || height > kMaxImageSize) {
    return InvalidArgumentError("image size must lie in [1, " + std::to_string(kMaxImageSize) +
                                "] per axis, got " + std::to_string(width) + "x" +
                                std::to_string(height));
  }
  return Status::Ok();
}

// The view direction and preferred up vector of each standard view (see camera.h).
void StandardFrame(StandardView view, Vec3* forward, Vec3* up) {
  switch (view) {
    case StandardView::kZ:
      *forward = {0, 0, 1};
      *up = {0, -1, 0};
      return;
    case StandardView::kY:
      *forward = {0, -1, 0};
      *up = {0, 0, -1};
      return;
    case StandardView::kX:
      *forward = {1, 0, 0};
      *up = {0, 0, -1};
      return;
    case StandardView::kIso:
      *forward = Normalize({1, 1, 1});
      *up = {0, -1, 0};
      return;
  }
}

}  // namespace

std::string_view ProjectionName(Projection p) {
  return p == Projection::kOrthographic ? "ortho" : "perspective";
}

std::optional<Projection> ProjectionFromName(std::string_view name) {
  if (name == "ortho" || name == "orthographic") return Projection::kOrthographic;
  if (name == "perspective") return Projection::kPerspective;
  return std::nullopt;
}

std::string_view StandardViewName(StandardView v) {
  switch (v) {
    case StandardView::kX:
      return "x";
    case StandardView::kY:
      return "y";
    case StandardView::kZ:
      return "z";
    case StandardView::kIso:
      return "iso";
  }
  return "?";
}

std::optional<StandardView> StandardViewFromName(std::string_view name) {
  for (StandardView v :
       {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
    if (StandardViewName(v) == name) return v;
  }
  return std::nullopt;
}

Vec3 PhysicalSpacing(const volume::VolumeInfo& info) {
  Vec3 s;
  for (int i = 0; i < 3; ++i) s[i] = info.spacing_um[i].value_or(1.0);
  return s;
}

Box3 PhysicalBounds(const std::array<int64_t, 3>& size, const Vec3& spacing) {
  return {{0, 0, 0},
          {static_cast<double>(size[0]) * spacing.x, static_cast<double>(size[1]) * spacing.y,
           static_cast<double>(size[2]) * spacing.z}};
}

Box3 PhysicalBounds(const volume::VolumeInfo& info) {
  return PhysicalBounds(info.size, PhysicalSpacing(info));
}

Result<Camera> Camera::FromFrame(Projection projection, const Vec3& position, const Vec3& forward,
                                 const Vec3& up, int width, int height, double fov_y_degrees,
                                 double ortho_height) {
  OCTO_RETURN_IF_ERROR(CheckImageSize(width, height));
  if (!IsFinite(position) || !IsFinite(forward) || !IsFinite(up)) {
    return InvalidArgumentError("camera position, direction and up vector must be finite");
  }
  if (!std::isfinite(fov_y_degrees) || fov_y_degrees <= 0 || fov_y_degrees >= 180) {
    return InvalidArgumentError("field of view must lie in (0, 180) degrees, got " +
                                std::to_string(fov_y_degrees));
  }
  if (!std::isfinite(ortho_height) || ortho_height <= 0) {
    return InvalidArgumentError("orthographic view height must be finite and > 0, got " +
                                std::to_string(ortho_height));
  }
  const double fl = Length(forward);
  const double ul = Length(up);
  if (!(fl > 0) || !(ul > 0)) {
    return InvalidArgumentError("camera view direction and up vector must be non-zero");
  }
  Camera c;
  c.projection_ = projection;
  c.position_ = position;
  c.forward_ = forward / fl;
  const Vec3 side = Cross(c.forward_, up / ul);
  // Nearly parallel vectors would make the frame numerically meaningless.
  if (!(Length(side) > 1e-9)) {
    return InvalidArgumentError("camera up vector is parallel to the view direction");
  }
  c.right_ = Normalize(side);
  c.up_ = Cross(c.right_, c.forward_);
  c.width_ = width;
  c.height_ = height;
  c.fov_y_degrees_ = fov_y_degrees;
  c.ortho_height_ = ortho_height;
  c.tan_half_fov_ = std::tan(fov_y_degrees * std::numbers::pi / 360.0);
  return c;
}

Result<Camera> Camera::LookAt(Projection projection, const Vec3& position, const Vec3& target,
                              const Vec3& up, int width, int height, double fov_y_degrees,
                              double ortho_height) {
  if (!IsFinite(position) || !IsFinite(target)) {
    return InvalidArgumentError("camera position and target must be finite");
  }
  if (position == target) return InvalidArgumentError("camera position equals its target");
  return FromFrame(projection, position, target - position, up, width, height, fov_y_degrees,
                   ortho_height);
}

Result<Camera> Camera::FromViewMatrix(Projection projection, const Mat4& world_to_camera, int width,
                                      int height, double fov_y_degrees, double ortho_height) {
  const Mat4& m = world_to_camera;
  if (!m.IsAffine()) return InvalidArgumentError("view matrix is not a finite affine matrix");
  const Vec3 r0{m(0, 0), m(0, 1), m(0, 2)};
  const Vec3 r1{m(1, 0), m(1, 1), m(1, 2)};
  const Vec3 r2{m(2, 0), m(2, 1), m(2, 2)};
  constexpr double kTol = 1e-6;
  const bool orthonormal = std::fabs(Dot(r0, r0) - 1) < kTol && std::fabs(Dot(r1, r1) - 1) < kTol &&
                           std::fabs(Dot(r2, r2) - 1) < kTol && std::fabs(Dot(r0, r1)) < kTol &&
                           std::fabs(Dot(r0, r2)) < kTol && std::fabs(Dot(r1, r2)) < kTol;
  if (!orthonormal || Dot(Cross(r0, r1), r2) < 0) {
    return InvalidArgumentError("view matrix rotation part is not a proper rotation");
  }
  // Camera space p_c = R p + t, so the eye (p_c = 0) sits at -R^T t.
  const Vec3 t{m(0, 3), m(1, 3), m(2, 3)};
  const Vec3 position = -(r0 * t.x + r1 * t.y + r2 * t.z);
  return FromFrame(projection, position, -r2, r1, width, height, fov_y_degrees, ortho_height);
}

Result<Camera> Camera::Standard(StandardView view, Projection projection, const Box3& bounds,
                                int width, int height, double fov_y_degrees) {
  OCTO_RETURN_IF_ERROR(CheckImageSize(width, height));
  const Vec3 extent = bounds.Extent();
  if (!IsFinite(bounds.lo) || !IsFinite(bounds.hi) || !(extent.x > 0) || !(extent.y > 0) ||
      !(extent.z > 0)) {
    return InvalidArgumentError("bounding box must be finite with positive extent");
  }
  Vec3 forward, up;
  StandardFrame(view, &forward, &up);
  const Vec3 center = bounds.Center();
  const double radius = Length(extent) / 2;
  const double aspect = static_cast<double>(width) / height;
  if (projection == Projection::kOrthographic) {
    // Build the frame first to project the box onto the image axes.
    OCTO_ASSIGN_OR_RETURN(Camera probe, FromFrame(projection, center, forward, up, width, height,
                                                  fov_y_degrees, 1.0));
    double half_w = 0, half_h = 0;
    for (int i = 0; i < 3; ++i) {
      half_w += std::fabs(probe.right_[i]) * extent[i] / 2;
      half_h += std::fabs(probe.up_[i]) * extent[i] / 2;
    }
    const double ortho_height = std::max(2 * half_h, 2 * half_w / aspect);
    // Stand well outside the box: rays start on the camera plane.
    return FromFrame(projection, center - probe.forward_ * (2 * radius), forward, up, width, height,
                     fov_y_degrees, ortho_height);
  }
  if (!std::isfinite(fov_y_degrees) || fov_y_degrees <= 0 || fov_y_degrees >= 180) {
    return InvalidArgumentError("field of view must lie in (0, 180) degrees, got " +
                                std::to_string(fov_y_degrees));
  }
  const double half_v = fov_y_degrees * std::numbers::pi / 360.0;
  const double half_h = std::atan(std::tan(half_v) * aspect);
  const double distance = radius / std::sin(std::min(half_v, half_h));
  return FromFrame(projection, center - Normalize(forward) * distance, forward, up, width, height,
                   fov_y_degrees, 2 * radius);
}

Ray Camera::ImageRay(double x, double y) const {
  // Offsets from the image centre in pixels; right is +x, up is -y (row 0 at the top).
  const double dx = x - width_ / 2.0;
  const double dy = height_ / 2.0 - y;
  if (projection_ == Projection::kOrthographic) {
    const double pixel = ortho_height_ / height_;
    return {position_ + right_ * (dx * pixel) + up_ * (dy * pixel), forward_};
  }
  const double scale = 2 * tan_half_fov_ / height_;  // Image-plane units per pixel at distance 1.
  return {position_, Normalize(forward_ + right_ * (dx * scale) + up_ * (dy * scale))};
}

Mat4 Camera::ViewMatrix() const {
  Mat4 m;
  const Vec3 back = -forward_;
  const Vec3 rows[3] = {right_, up_, back};
  for (int i = 0; i < 3; ++i) {
    m(i, 0) = rows[i].x;
    m(i, 1) = rows[i].y;
    m(i, 2) = rows[i].z;
    m(i, 3) = -Dot(rows[i], position_);
  }
  return m;
}

}  // namespace octoscope::render
