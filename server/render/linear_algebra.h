// Small double-precision vector and matrix types for cameras, clipping planes and per-channel
// sample transforms: Vec3 (a point or direction) and Mat4 (a row-major 4x4 matrix acting on column
// vectors, p' = M * (x, y, z, 1)). Header-only; deliberately minimal.
//
// Thread safety: plain value types; all functions are pure.
#ifndef OCTOSCOPE_RENDER_LINEAR_ALGEBRA_H_
#define OCTOSCOPE_RENDER_LINEAR_ALGEBRA_H_

#include <array>
#include <cmath>
#include <optional>

namespace octoscope::render {

struct Vec3 {
  double x = 0, y = 0, z = 0;

  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  double& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  bool operator==(const Vec3&) const = default;
};

inline Vec3 operator+(const Vec3& a, const Vec3& b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(const Vec3& a, const Vec3& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator-(const Vec3& a) { return {-a.x, -a.y, -a.z}; }
inline Vec3 operator*(const Vec3& a, double s) { return {a.x * s, a.y * s, a.z * s}; }
inline Vec3 operator*(double s, const Vec3& a) { return a * s; }
inline Vec3 operator/(const Vec3& a, double s) { return {a.x / s, a.y / s, a.z / s}; }
// Componentwise product and quotient.
inline Vec3 Mul(const Vec3& a, const Vec3& b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline Vec3 Div(const Vec3& a, const Vec3& b) { return {a.x / b.x, a.y / b.y, a.z / b.z}; }

inline double Dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double Length(const Vec3& a) { return std::sqrt(Dot(a, a)); }
// REQUIRES: Length(a) > 0.
inline Vec3 Normalize(const Vec3& a) { return a / Length(a); }
inline bool IsFinite(const Vec3& a) {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

// Row-major: m[row * 4 + col]. Default: the identity.
struct Mat4 {
  std::array<double, 16> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

  double operator()(int row, int col) const { return m[row * 4 + col]; }
  double& operator()(int row, int col) { return m[row * 4 + col]; }
  bool operator==(const Mat4&) const = default;

  static Mat4 Identity() { return Mat4{}; }
  static Mat4 Translation(const Vec3& t) {
    Mat4 r;
    r(0, 3) = t.x;
    r(1, 3) = t.y;
    r(2, 3) = t.z;
    return r;
  }
  static Mat4 Scale(const Vec3& s) {
    Mat4 r;
    r(0, 0) = s.x;
    r(1, 1) = s.y;
    r(2, 2) = s.z;
    return r;
  }

  bool IsIdentity() const { return *this == Mat4{}; }
  // True when the last row is exactly (0, 0, 0, 1) and every entry is finite.
  bool IsAffine() const {
    for (double v : m) {
      if (!std::isfinite(v)) return false;
    }
    return m[12] == 0 && m[13] == 0 && m[14] == 0 && m[15] == 1;
  }

  // M * (p, 1), dropping w. REQUIRES: IsAffine().
  Vec3 TransformPoint(const Vec3& p) const {
    return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3],
            m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
  }
  // M * (v, 0): the linear part only.
  Vec3 TransformVector(const Vec3& v) const {
    return {m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
            m[8] * v.x + m[9] * v.y + m[10] * v.z};
  }
};

inline Mat4 operator*(const Mat4& a, const Mat4& b) {
  Mat4 r;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      double s = 0;
      for (int k = 0; k < 4; ++k) s += a(i, k) * b(k, j);
      r(i, j) = s;
    }
  }
  return r;
}

// The inverse of an affine matrix, or nullopt when it is not affine or (nearly) singular.
inline std::optional<Mat4> InverseAffine(const Mat4& a) {
  if (!a.IsAffine()) return std::nullopt;
  // Invert the 3x3 linear part by cofactors, then the translation: x = L^-1 (y - t).
  const double c00 = a(1, 1) * a(2, 2) - a(1, 2) * a(2, 1);
  const double c01 = a(1, 2) * a(2, 0) - a(1, 0) * a(2, 2);
  const double c02 = a(1, 0) * a(2, 1) - a(1, 1) * a(2, 0);
  const double det = a(0, 0) * c00 + a(0, 1) * c01 + a(0, 2) * c02;
  double scale = 0;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) scale = std::fmax(scale, std::fabs(a(i, j)));
  }
  if (!(std::fabs(det) > 1e-12 * scale * scale * scale)) return std::nullopt;
  const double inv = 1.0 / det;
  Mat4 r;
  r(0, 0) = c00 * inv;
  r(0, 1) = (a(0, 2) * a(2, 1) - a(0, 1) * a(2, 2)) * inv;
  r(0, 2) = (a(0, 1) * a(1, 2) - a(0, 2) * a(1, 1)) * inv;
  r(1, 0) = c01 * inv;
  r(1, 1) = (a(0, 0) * a(2, 2) - a(0, 2) * a(2, 0)) * inv;
  r(1, 2) = (a(0, 2) * a(1, 0) - a(0, 0) * a(1, 2)) * inv;
  r(2, 0) = c02 * inv;
  r(2, 1) = (a(0, 1) * a(2, 0) - a(0, 0) * a(2, 1)) * inv;
  r(2, 2) = (a(0, 0) * a(1, 1) - a(0, 1) * a(1, 0)) * inv;
  const Vec3 t = r.TransformVector({a(0, 3), a(1, 3), a(2, 3)});
  r(0, 3) = -t.x;
  r(1, 3) = -t.y;
  r(2, 3) = -t.z;
  return r;
}

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_LINEAR_ALGEBRA_H_
