#include "render/reference_renderer.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>

#include "io/memory_volume.h"
#include "volume/value_map.h"

namespace octoscope::render {
namespace {

using volume::DataType;

constexpr double kU16 = 65535;

// A volume whose voxel (x, y, z) of channel c holds f(c, x, y, z).
ReferenceVolume MakeVolume(std::array<int64_t, 3> size, Vec3 spacing, DataType type, int channels,
                           const std::function<uint16_t(int, int64_t, int64_t, int64_t)>& f) {
  std::vector<std::vector<uint16_t>> data(channels);
  for (int c = 0; c < channels; ++c) {
    for (int64_t z = 0; z < size[2]; ++z) {
      for (int64_t y = 0; y < size[1]; ++y) {
        for (int64_t x = 0; x < size[0]; ++x) data[c].push_back(f(c, x, y, z));
      }
    }
  }
  auto v = ReferenceVolume::FromStored(size, spacing, type, std::move(data));
  EXPECT_TRUE(v.ok()) << v.status().ToString();
  return std::move(v).value();
}

// Deterministic pseudo-random values covering the whole uint16 range, 0 and max included.
uint16_t Hash(int c, int64_t x, int64_t y, int64_t z) {
  uint32_t h = static_cast<uint32_t>(c * 7919 + x * 104729 + y * 1299709 + z * 15485863);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  const uint16_t v = static_cast<uint16_t>(h);
  if (v % 11 == 0) return 0;
  if (v % 13 == 0) return 65535;
  return v;
}

// Renders and checks the output invariants every image must satisfy.
RenderImage Render(const ReferenceVolume& vol, const Camera& cam, const RenderParams& params,
                   RenderStats* stats = nullptr) {
  auto img = RenderReference(vol, cam, params, stats);
  EXPECT_TRUE(img.ok()) << img.status().ToString();
  if (!img.ok()) return {};
  EXPECT_EQ(img->width, cam.width());
  EXPECT_EQ(img->height, cam.height());
  EXPECT_EQ(img->rgba.size(), static_cast<size_t>(cam.width()) * cam.height() * 4);
  for (float v : img->rgba) {
    EXPECT_TRUE(std::isfinite(v));
    EXPECT_GE(v, 0.0f);
    EXPECT_LE(v, 1.0f);
  }
  return std::move(img).value();
}

Camera StandardCamera(StandardView view, const ReferenceVolume& vol, int w, int h,
                      Projection p = Projection::kOrthographic) {
  auto cam = Camera::Standard(view, p, vol.bounds(), w, h);
  EXPECT_TRUE(cam.ok()) << cam.status().ToString();
  return std::move(cam).value();
}

// Path length of a ray through a box [0, hi], written independently of the renderer: the
// distance between the last entry and first exit over the three slabs.
double PathLength(const Ray& r, const Vec3& hi) {
  double t0 = 0, t1 = 1e300;
  for (int a = 0; a < 3; ++a) {
    if (r.direction[a] == 0) {
      if (r.origin[a] < 0 || r.origin[a] > hi[a]) return 0;
      continue;
    }
    const double ta = (0 - r.origin[a]) / r.direction[a];
    const double tb = (hi[a] - r.origin[a]) / r.direction[a];
    t0 = std::max(t0, std::min(ta, tb));
    t1 = std::min(t1, std::max(ta, tb));
  }
  return std::max(0.0, t1 - t0);
}

TEST(ReferenceRendererTest, MipOrthoZEqualsColumnMax) {
  for (DataType type : {DataType::kUint16, DataType::kUint8}) {
    for (Vec3 spacing : {Vec3{1, 1, 1}, Vec3{0.5, 0.5, 3}}) {
      const int64_t nx = 7, ny = 5, nz = 6;
      const double max = volume::TypeMax(type);
      auto f = [&](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
        return static_cast<uint16_t>(Hash(c, x, y, z) % (static_cast<int>(max) + 1));
      };
      const ReferenceVolume vol = MakeVolume({nx, ny, nz}, spacing, type, 1, f);
      const Camera cam = StandardCamera(StandardView::kZ, vol, nx, ny);
      const RenderImage img = Render(vol, cam, DefaultRenderParams(1, type, RenderMode::kMip));
      for (int y = 0; y < ny; ++y) {
        for (int x = 0; x < nx; ++x) {
          uint16_t m = 0;
          for (int z = 0; z < nz; ++z) m = std::max(m, f(0, x, y, z));
          const auto px = img.Pixel(x, y);
          for (int k = 0; k < 3; ++k) EXPECT_NEAR(px[k], m / max, 1e-6) << x << "," << y;
          EXPECT_EQ(px[3], 1.0f);
        }
      }
    }
  }
}

TEST(ReferenceRendererTest, MinIpOrthoZEqualsColumnMin) {
  const ReferenceVolume vol = MakeVolume({6, 4, 5}, {1, 1, 1}, DataType::kUint16, 1, Hash);
  const RenderImage img = Render(vol, StandardCamera(StandardView::kZ, vol, 6, 4),
                                 DefaultRenderParams(1, DataType::kUint16, RenderMode::kMinIp));
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 6; ++x) {
      uint16_t m = 65535;
      for (int z = 0; z < 5; ++z) m = std::min(m, Hash(0, x, y, z));
      EXPECT_NEAR(img.Pixel(x, y)[0], m / kU16, 1e-6);
    }
  }
}

TEST(ReferenceRendererTest, SingleBrightVoxelVisibleInMipFromEveryAxis) {
  const int64_t nx = 5, ny = 6, nz = 4;
  const int64_t bx = 2, by = 3, bz = 1;
  const ReferenceVolume vol = MakeVolume({nx, ny, nz}, {1, 1, 1}, DataType::kUint16, 1,
                                         [&](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
                                           return (x == bx && y == by && z == bz) ? 65535 : 0;
                                         });
  const RenderParams params = DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip);
  const Vec3 c = vol.bounds().Center();
  struct Case {
    Vec3 forward, up;
    int w, h;
    int expect_x, expect_y;  // Pixel of the bright voxel.
  };
  // Image x runs along forward x up; rows run along -up.
  const Case cases[] = {
      {{0, 0, 1}, {0, -1, 0}, nx, ny, bx, by},            // +z: x right, y down.
      {{0, 0, -1}, {0, -1, 0}, nx, ny, nx - 1 - bx, by},  // -z: mirrored x.
      {{1, 0, 0}, {0, 0, -1}, ny, nz, by, bz},            // +x: y right, z down.
      {{-1, 0, 0}, {0, 0, -1}, ny, nz, ny - 1 - by, bz},  // -x
      {{0, -1, 0}, {0, 0, -1}, nx, nz, bx, bz},           // -y: x right, z down.
      {{0, 1, 0}, {0, 0, -1}, nx, nz, nx - 1 - bx, bz},   // +y
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(::testing::Message() << k.forward.x << k.forward.y << k.forward.z);
    auto cam =
        Camera::LookAt(Projection::kOrthographic, c - k.forward * 20, c, k.up, k.w, k.h, 30, k.h);
    ASSERT_TRUE(cam.ok());
    const RenderImage img = Render(vol, *cam, params);
    for (int y = 0; y < k.h; ++y) {
      for (int x = 0; x < k.w; ++x) {
        const float expected = (x == k.expect_x && y == k.expect_y) ? 1.0f : 0.0f;
        EXPECT_NEAR(img.Pixel(x, y)[0], expected, 1e-6) << x << "," << y;
      }
    }
  }
  // Oblique and perspective views see it too (interpolated, so dimmer than the voxel).
  for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
    const RenderImage img = Render(vol, StandardCamera(StandardView::kIso, vol, 32, 32, p), params);
    float brightest = 0;
    for (int y = 0; y < 32; ++y) {
      for (int x = 0; x < 32; ++x) brightest = std::max(brightest, img.Pixel(x, y)[0]);
    }
    EXPECT_GT(brightest, 0.2f);
  }
}

// DVR of a constant volume: every sample has the same colour and opacity, so a ray of physical
// path length L through the box ends with alpha 1 - exp(-sigma L) = 1 - (1 - a)^(L / ref) and
// premultiplied colour color * t * alpha, whatever the step.
TEST(ReferenceRendererTest, ConstantVolumeDvrMatchesClosedForm) {
  const uint16_t value = 40000;
  const double t = value / kU16;
  const double a = 0.1;  // Opacity per reference length (the smallest spacing).
  const double sigma = -std::log(1 - a);
  for (Vec3 spacing : {Vec3{1, 1, 1}, Vec3{1, 1, 2}, Vec3{0.5, 0.75, 0.6}}) {
    const double ref = std::min({spacing.x, spacing.y, spacing.z});
    const ReferenceVolume vol = MakeVolume({8, 7, 6}, spacing, DataType::kUint16, 1,
                                           [&](int, int64_t, int64_t, int64_t) { return value; });
    RenderParams params = DefaultRenderParams(1, DataType::kUint16, RenderMode::kDvr);
    params.channels[0].color = {1, 0.5, 0.25};
    params.channels[0].opacity_scale = a / t;
    const Box3 box = vol.bounds();
    std::vector<Camera> cams = {
        StandardCamera(StandardView::kZ, vol, 8, 7),
        StandardCamera(StandardView::kIso, vol, 12, 10),
        StandardCamera(StandardView::kIso, vol, 12, 10, Projection::kPerspective)};
    for (const Camera& cam : cams) {
      for (double step : {1.0, 0.3, 2.7, 1.0 / 64}) {
        SCOPED_TRACE(::testing::Message() << "spacing " << spacing.z << " step " << step);
        params.step_voxels = step;
        const RenderImage img = Render(vol, cam, params);
        for (int y = 0; y < cam.height(); ++y) {
          for (int x = 0; x < cam.width(); ++x) {
            const double length = PathLength(cam.PixelRay(x, y), box.hi);
            const double alpha = 1 - std::exp(-sigma * length / ref);
            const auto px = img.Pixel(x, y);
            ASSERT_NEAR(px[3], alpha, 2e-6) << x << "," << y;
            ASSERT_NEAR(px[0], 1.0 * t * alpha, 2e-6);
            ASSERT_NEAR(px[1], 0.5 * t * alpha, 2e-6);
            ASSERT_NEAR(px[2], 0.25 * t * alpha, 2e-6);
          }
        }
      }
    }
  }
}

TEST(ReferenceRendererTest, DvrOverOpaqueBackground) {
  const ReferenceVolume vol = MakeVolume({4, 4, 4}, {1, 1, 1}, DataType::kUint8, 1,
                                         [](int, int64_t, int64_t, int64_t) { return 255; });
  RenderParams params = DefaultRenderParams(1, DataType::kUint8, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.2;  // a = 0.2 per voxel, 4 voxels deep.
  params.background = {0, 0, 1, 1};
  const RenderImage img = Render(vol, StandardCamera(StandardView::kZ, vol, 4, 4), params);
  const double alpha = 1 - std::pow(0.8, 4);
  const auto px = img.Pixel(1, 2);
  EXPECT_NEAR(px[0], alpha, 1e-6);
  EXPECT_NEAR(px[2], alpha + (1 - alpha), 1e-6);
  EXPECT_NEAR(px[3], 1, 1e-6);
}

TEST(ReferenceRendererTest, TwoChannelIntermixingMatchesClosedForm) {
  const ReferenceVolume vol = MakeVolume(
      {3, 3, 10}, {1, 1, 1}, DataType::kUint16, 2,
      [](int c, int64_t, int64_t, int64_t) -> uint16_t { return c == 0 ? 65535 : 32768; });
  RenderParams params = DefaultRenderParams(2, DataType::kUint16, RenderMode::kDvr);
  params.channels[0].color = {1, 0, 0};
  params.channels[0].opacity_scale = 0.1;
  params.channels[1].color = {0, 1, 0};
  params.channels[1].opacity_scale = 0.3;
  const double t0 = 1, t1 = 32768 / kU16;
  const double a0 = 0.1 * t0, a1 = 0.3 * t1;
  const double mixed = 1 - (1 - a0) * (1 - a1);
  const int n = 10;
  // Sum over samples i of (1 - mixed)^i * premultiplied colour.
  const double series = (1 - std::pow(1 - mixed, n)) / mixed;
  const RenderImage img = Render(vol, StandardCamera(StandardView::kZ, vol, 3, 3), params);
  const auto px = img.Pixel(1, 1);
  EXPECT_NEAR(px[0], t0 * a0 * series, 1e-6);
  EXPECT_NEAR(px[1], t1 * a1 * series, 1e-6);
  EXPECT_NEAR(px[2], 0, 1e-6);
  EXPECT_NEAR(px[3], 1 - std::pow(1 - mixed, n), 1e-6);
}

TEST(ReferenceRendererTest, EarlyRayTermination) {
  const ReferenceVolume vol = MakeVolume({2, 2, 64}, {1, 1, 1}, DataType::kUint8, 1,
                                         [](int, int64_t, int64_t, int64_t) { return 255; });
  RenderParams params = DefaultRenderParams(1, DataType::kUint8, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.5;
  RenderStats stats;
  const RenderImage img = Render(vol, StandardCamera(StandardView::kZ, vol, 2, 2), params, &stats);
  // 1 - 0.5^n >= 0.999 first at n = 10.
  EXPECT_EQ(stats.rays, 4u);
  EXPECT_EQ(stats.rays_hit, 4u);
  EXPECT_EQ(stats.early_terminated, 4u);
  EXPECT_EQ(stats.steps, 4u * 10);
  EXPECT_NEAR(img.Pixel(0, 0)[3], 1 - std::pow(0.5, 10), 1e-6);
}

TEST(ReferenceRendererTest, ClipPlanesCutExactly) {
  const ReferenceVolume vol = MakeVolume({8, 8, 8}, {1, 1, 1}, DataType::kUint16, 1,
                                         [](int, int64_t, int64_t, int64_t) { return 65535; });
  const Camera cam = StandardCamera(StandardView::kZ, vol, 8, 8);
  RenderParams params = DefaultRenderParams(1, DataType::kUint16, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.1;
  // Keep z <= 3.3: every ray crosses exactly 3.3 µm.
  params.clip_planes = {{{0, 0, 1}, 3.3}};
  for (double step : {1.0, 0.7}) {
    params.step_voxels = step;
    const RenderImage img = Render(vol, cam, params);
    EXPECT_NEAR(img.Pixel(3, 3)[3], 1 - std::pow(0.9, 3.3), 1e-6);
  }
  params.step_voxels = 1;
  // Keep x <= 4 and x >= 2 (normal -x, distance -2) and y <= 5.5 (pixel row 5's centre lies on
  // the plane: kept, since the test is <=).
  params.clip_planes = {{{1, 0, 0}, 4}, {{-1, 0, 0}, -2}, {{0, 2, 0}, 11}};
  RenderStats stats;
  const RenderImage img = Render(vol, cam, params, &stats);
  int kept = 0;
  for (int y = 0; y < 8; ++y) {
    for (int x = 0; x < 8; ++x) {
      const bool inside = x >= 2 && x < 4 && y <= 5;
      EXPECT_NEAR(img.Pixel(x, y)[3], inside ? 1 - std::pow(0.9, 8) : 0.0, 1e-6) << x << "," << y;
      kept += inside;
    }
  }
  EXPECT_EQ(stats.rays_hit, static_cast<uint64_t>(kept));
  EXPECT_EQ(stats.steps, static_cast<uint64_t>(kept) * 8);

  // MIP: the bright half z >= 5 is cut away; samples stop at the plane.
  const ReferenceVolume slab = MakeVolume(
      {4, 4, 8}, {1, 1, 1}, DataType::kUint16, 1,
      [](int, int64_t, int64_t, int64_t z) -> uint16_t { return z >= 5 ? 65535 : 1000 * z; });
  RenderParams mip = DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip);
  mip.clip_planes = {{{0, 0, 1}, 4}};
  const RenderImage cut = Render(slab, StandardCamera(StandardView::kZ, slab, 4, 4), mip);
  EXPECT_NEAR(cut.Pixel(2, 1)[0], 3000 / kU16, 1e-6);
  // A plane that removes everything leaves the background.
  mip.clip_planes = {{{0, 0, 1}, -0.5}};
  mip.background = {0.25, 0.5, 0.75, 1};
  const RenderImage none = Render(slab, StandardCamera(StandardView::kZ, slab, 4, 4), mip);
  EXPECT_EQ(none.Pixel(0, 0), (std::array<float, 4>{0.25f, 0.5f, 0.75f, 1.0f}));
}

TEST(ReferenceRendererTest, ClipRayToVolumeHandlesParallelRays) {
  const Box3 box{{0, 0, 0}, {4, 4, 4}};
  // Along the x = 0 face: inside (faces inclusive).
  auto on_face = ClipRayToVolume({{0, 1, -1}, {0, 0, 1}}, box, {});
  ASSERT_TRUE(on_face.has_value());
  EXPECT_DOUBLE_EQ(on_face->first, 1);
  EXPECT_DOUBLE_EQ(on_face->second, 5);
  EXPECT_FALSE(ClipRayToVolume({{-1e-12, 1, -1}, {0, 0, 1}}, box, {}).has_value());
  // Behind the camera nothing counts; a camera inside starts at t = 0.
  EXPECT_FALSE(ClipRayToVolume({{1, 1, 5}, {0, 0, 1}}, box, {}).has_value());
  auto inside = ClipRayToVolume({{1, 1, 1}, {0, 0, 1}}, box, {});
  ASSERT_TRUE(inside.has_value());
  EXPECT_DOUBLE_EQ(inside->first, 0);
  EXPECT_DOUBLE_EQ(inside->second, 3);
  // A plane parallel to the ray keeps it or drops it whole.
  EXPECT_TRUE(ClipRayToVolume({{1, 1, -1}, {0, 0, 1}}, box, {{{1, 0, 0}, 1}}).has_value());
  EXPECT_FALSE(ClipRayToVolume({{1, 1, -1}, {0, 0, 1}}, box, {{{1, 0, 0}, 0.99}}).has_value());
  // Grazing an edge (a single point) is empty.
  EXPECT_FALSE(ClipRayToVolume({{5, 3, 2}, Normalize({-1, 1, 0})}, box, {}).has_value());
}

TEST(ReferenceRendererTest, DisabledChannelContributesNothingAndIsNeverSampled) {
  auto f = [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return c == 0 ? Hash(0, x, y, z) : 65535;
  };
  const ReferenceVolume two = MakeVolume({5, 4, 3}, {1, 1, 1}, DataType::kUint16, 2, f);
  const ReferenceVolume one = MakeVolume({5, 4, 3}, {1, 1, 1}, DataType::kUint16, 1, f);
  const Camera cam = StandardCamera(StandardView::kIso, two, 16, 16, Projection::kPerspective);
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    SCOPED_TRACE(std::string(RenderModeName(mode)));
    RenderParams p2 = DefaultRenderParams(2, DataType::kUint16, mode);
    p2.channels[0].color = {0, 1, 0.5};
    p2.channels[1].enabled = false;
    RenderParams p1 = DefaultRenderParams(1, DataType::kUint16, mode);
    p1.channels[0] = p2.channels[0];
    RenderStats s2, s1;
    const RenderImage i2 = Render(two, cam, p2, &s2);
    const RenderImage i1 = Render(one, cam, p1, &s1);
    EXPECT_EQ(i2.rgba, i1.rgba);
    EXPECT_GT(s2.channel_samples[0], 0u);
    EXPECT_EQ(s2.channel_samples[0], s1.channel_samples[0]);
    EXPECT_EQ(s2.channel_samples[1], 0u);
    // Nothing enabled: background only, no samples at all.
    p2.channels[0].enabled = false;
    RenderStats s0;
    const RenderImage i0 = Render(two, cam, p2, &s0);
    EXPECT_TRUE(std::all_of(i0.rgba.begin(), i0.rgba.end(), [](float v) { return v == 0; }));
    EXPECT_EQ(s0.steps, 0u);
    EXPECT_EQ(s0.channel_samples, (std::vector<uint64_t>{0, 0}));
  }
}

TEST(ReferenceRendererTest, ChromaticTranslationShiftsMip) {
  const int64_t nx = 9, ny = 4, nz = 3;
  for (double s : {1.0, 0.5}) {
    const ReferenceVolume vol =
        MakeVolume({nx, ny, nz}, {s, s, 2}, DataType::kUint16, 2,
                   [](int, int64_t x, int64_t y, int64_t z) { return Hash(0, x, y, z); });
    RenderParams params = DefaultRenderParams(2, DataType::kUint16, RenderMode::kMip);
    params.channels[0].color = {1, 0, 0};
    params.channels[1].color = {0, 1, 0};
    const int dx = 2;
    params.channels[1].transform = Mat4::Translation({dx * s, 0, 0});
    const RenderImage img = Render(vol, StandardCamera(StandardView::kZ, vol, nx, ny), params);
    for (int y = 0; y < ny; ++y) {
      for (int x = 0; x < nx; ++x) {
        auto column_max = [&](int64_t cx) {
          uint16_t m = 0;
          for (int z = 0; z < nz; ++z) m = std::max(m, Hash(0, cx, y, z));
          return m / kU16;
        };
        const auto px = img.Pixel(x, y);
        EXPECT_NEAR(px[0], column_max(x), 1e-6);
        // Channel 1 reads x + dx: its image moves dx pixels left; past the edge it is absent.
        EXPECT_NEAR(px[1], x + dx < nx ? column_max(x + dx) : 0.0, 1e-6) << x << "," << y;
      }
    }
  }
}

TEST(ReferenceRendererTest, PerspectiveCameraInsideTheVolume) {
  const ReferenceVolume vol = MakeVolume({10, 10, 10}, {1, 1, 1}, DataType::kUint16, 1,
                                         [](int, int64_t, int64_t, int64_t) { return 65535; });
  RenderParams params = DefaultRenderParams(1, DataType::kUint16, RenderMode::kDvr);
  params.channels[0].opacity_scale = 0.05;
  params.step_voxels = 0.5;
  auto cam =
      Camera::LookAt(Projection::kPerspective, {5, 5, 5}, {5, 5, 10}, {0, -1, 0}, 9, 9, 90, 1);
  ASSERT_TRUE(cam.ok());
  const RenderImage img = Render(vol, *cam, params);
  for (int y = 0; y < 9; ++y) {
    for (int x = 0; x < 9; ++x) {
      // The ray starts inside: its path is the distance to the exit face.
      const Ray r = cam->PixelRay(x, y);
      double exit = 1e300;
      for (int a = 0; a < 3; ++a) {
        if (r.direction[a] > 0) exit = std::min(exit, (10 - r.origin[a]) / r.direction[a]);
        if (r.direction[a] < 0) exit = std::min(exit, -r.origin[a] / r.direction[a]);
      }
      EXPECT_NEAR(img.Pixel(x, y)[3], 1 - std::pow(0.95, exit), 1e-6);
    }
  }
  // MIP from inside sees what is in front, not what is behind.
  const ReferenceVolume two_voxels =
      MakeVolume({10, 10, 10}, {1, 1, 1}, DataType::kUint16, 1,
                 [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
                   if (x == 5 && y == 5 && z == 8) return 30000;
                   if (x == 5 && y == 5 && z == 1) return 65535;
                   return 0;
                 });
  // Samples at z = 5.5, 6.5, ...: the voxel centres.
  auto eye = Camera::LookAt(Projection::kPerspective, {5.5, 5.5, 5}, {5.5, 5.5, 10}, {0, -1, 0}, 1,
                            1, 10, 1);
  ASSERT_TRUE(eye.ok());
  const RenderImage mip =
      Render(two_voxels, *eye, DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip));
  EXPECT_NEAR(mip.Pixel(0, 0)[0], 30000 / kU16, 1e-6);
}

TEST(ReferenceRendererTest, RaysAlongVoxelFacesInterpolate) {
  // Columns constant along y and z; rays at x = 0, 1, 2, 3, 4 run along voxel faces (0 and 4 are
  // the box faces, as a brick face would be for a brick boundary).
  const uint16_t column[4] = {0, 1000, 3000, 65535};
  const ReferenceVolume vol =
      MakeVolume({4, 3, 5}, {1, 1, 1}, DataType::kUint16, 1,
                 [&](int, int64_t x, int64_t, int64_t) -> uint16_t { return column[x]; });
  // 5 pixels of 1 µm centred on the box: centres at x = 0 .. 4.
  auto cam = Camera::LookAt(Projection::kOrthographic, {2, 1.5, -10}, {2, 1.5, 0}, {0, -1, 0}, 5, 3,
                            30, 3);
  ASSERT_TRUE(cam.ok());
  EXPECT_DOUBLE_EQ(cam->PixelRay(0, 0).origin.x, 0);
  EXPECT_DOUBLE_EQ(cam->PixelRay(4, 0).origin.x, 4);
  const RenderImage img =
      Render(vol, *cam, DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip));
  const double expected[5] = {0, 500, 2000, (3000 + 65535) / 2.0, 65535};
  for (int x = 0; x < 5; ++x) {
    for (int y = 0; y < 3; ++y) EXPECT_NEAR(img.Pixel(x, y)[0], expected[x] / kU16, 1e-6) << x;
  }
  // A ray along the box edge x = 0, y = 0 hits (faces inclusive).
  EXPECT_DOUBLE_EQ(vol.Sample(0, {0, 0, 2.5}), 0);
  EXPECT_DOUBLE_EQ(vol.Sample(0, {4, 3, 5}), 65535);
  EXPECT_DOUBLE_EQ(vol.Sample(0, {1.75, 0, 0}), 1000 + 0.25 * 2000);
}

TEST(ReferenceRendererTest, DegenerateVolumes) {
  const RenderParams mip1 = DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip);
  // 1x1xN: one pixel from z, a line from x.
  const ReferenceVolume line = MakeVolume({1, 1, 6}, {1, 1, 1}, DataType::kUint16, 1, Hash);
  uint16_t m = 0;
  for (int z = 0; z < 6; ++z) m = std::max(m, Hash(0, 0, 0, z));
  EXPECT_NEAR(Render(line, StandardCamera(StandardView::kZ, line, 1, 1), mip1).Pixel(0, 0)[0],
              m / kU16, 1e-6);
  const RenderImage side = Render(line, StandardCamera(StandardView::kX, line, 1, 6), mip1);
  for (int z = 0; z < 6; ++z) EXPECT_NEAR(side.Pixel(0, z)[0], Hash(0, 0, 0, z) / kU16, 1e-6);
  // NxNx1: the z view shows the plane, DVR crosses one voxel.
  const ReferenceVolume plane = MakeVolume({5, 5, 1}, {1, 1, 1}, DataType::kUint16, 1, Hash);
  const RenderImage top = Render(plane, StandardCamera(StandardView::kZ, plane, 5, 5), mip1);
  for (int y = 0; y < 5; ++y) {
    for (int x = 0; x < 5; ++x) EXPECT_NEAR(top.Pixel(x, y)[0], Hash(0, x, y, 0) / kU16, 1e-6);
  }
  RenderParams dvr = DefaultRenderParams(1, DataType::kUint16, RenderMode::kDvr);
  const RenderImage thin = Render(plane, StandardCamera(StandardView::kZ, plane, 5, 5), dvr);
  const double t = Hash(0, 2, 3, 0) / kU16;
  EXPECT_NEAR(thin.Pixel(2, 3)[3], t, 1e-6);  // a = t over one reference length.
  EXPECT_NEAR(thin.Pixel(2, 3)[0], t * t, 1e-6);
  // 1x1x1 from every standard view and projection: wherever the ray hits, the voxel's value.
  const ReferenceVolume dot = MakeVolume({1, 1, 1}, {2, 3, 4}, DataType::kUint8, 1,
                                         [](int, int64_t, int64_t, int64_t) { return 200; });
  for (StandardView v :
       {StandardView::kX, StandardView::kY, StandardView::kZ, StandardView::kIso}) {
    for (Projection p : {Projection::kOrthographic, Projection::kPerspective}) {
      RenderStats stats;
      const RenderImage img =
          Render(dot, StandardCamera(v, dot, 7, 5, p),
                 DefaultRenderParams(1, DataType::kUint8, RenderMode::kMip), &stats);
      EXPECT_GT(stats.rays_hit, 0u);
      for (int y = 0; y < 5; ++y) {
        for (int x = 0; x < 7; ++x) {
          const auto px = img.Pixel(x, y);
          EXPECT_TRUE(px[3] == 0 || std::fabs(px[0] - 200 / 255.0) < 1e-6);
        }
      }
    }
  }
}

TEST(ReferenceRendererTest, ExtremeValuesAndParametersStayFinite) {
  const ReferenceVolume vol = MakeVolume(
      {6, 6, 6}, {0.1, 7, 1}, DataType::kUint16, 2,
      [](int c, int64_t x, int64_t, int64_t) -> uint16_t { return (x + c) % 2 ? 65535 : 0; });
  std::array<volume::Rgba, kLutEntries> lut;
  for (int i = 0; i < kLutEntries; ++i) {
    lut[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(255 - i), 0, static_cast<uint8_t>(i)};
  }
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip, RenderMode::kMinIp}) {
    for (int variant = 0; variant < 4; ++variant) {
      RenderParams p = DefaultRenderParams(2, DataType::kUint16, mode);
      p.step_voxels = variant == 0 ? kMinStepVoxels : (variant == 1 ? kMaxStepVoxels : 0.9);
      p.channels[0].gamma = variant == 2 ? 1e-3 : 50;
      p.channels[0].opacity_scale = 1e6;
      p.channels[0].window = 1e-9;
      p.channels[1].lut = lut;
      p.channels[1].level = variant == 3 ? -1e12 : 65535;
      p.channels[1].transform = Mat4::Scale({1e-3, 50, 1});
      p.background = {1, 1, 1, variant == 3 ? 0.0 : 1.0};
      for (StandardView v : {StandardView::kIso, StandardView::kZ}) {
        Render(vol, StandardCamera(v, vol, 9, 7, Projection::kPerspective), p);
      }
    }
  }
}

TEST(ReferenceRendererTest, LutAndGammaAndWindow) {
  const ReferenceVolume vol = MakeVolume({3, 1, 1}, {1, 1, 1}, DataType::kUint16, 1,
                                         [](int, int64_t x, int64_t, int64_t) -> uint16_t {
                                           return x == 0 ? 0 : (x == 1 ? 1500 : 65535);
                                         });
  RenderParams p = DefaultRenderParams(1, DataType::kUint16, RenderMode::kMip);
  p.channels[0].window = 2000;
  p.channels[0].level = 1000;  // [0, 2000]
  p.channels[0].gamma = 2;
  p.channels[0].color = {0.5, 1, 0};
  const Camera cam = StandardCamera(StandardView::kZ, vol, 3, 1);
  RenderImage img = Render(vol, cam, p);
  EXPECT_NEAR(img.Pixel(0, 0)[1], 0, 1e-6);
  EXPECT_NEAR(img.Pixel(1, 0)[1], 0.75 * 0.75, 1e-6);
  EXPECT_NEAR(img.Pixel(1, 0)[0], 0.5 * 0.75 * 0.75, 1e-6);
  EXPECT_NEAR(img.Pixel(2, 0)[1], 1, 1e-6);  // Above the window: clamped.
  std::array<volume::Rgba, kLutEntries> lut;
  for (int i = 0; i < kLutEntries; ++i) {
    lut[i] = {static_cast<uint8_t>(i), static_cast<uint8_t>(255 - i), 7, 255};
  }
  p.channels[0].lut = lut;
  p.channels[0].gamma = 1;
  img = Render(vol, cam, p);
  // t = 0.75 sits at LUT position 191.25: between entries 191 and 192.
  EXPECT_NEAR(img.Pixel(1, 0)[0], 191.25 / 255, 1e-6);
  EXPECT_NEAR(img.Pixel(1, 0)[1], (255 - 191.25) / 255, 1e-6);
  EXPECT_NEAR(img.Pixel(1, 0)[2], 7 / 255.0, 1e-6);
  EXPECT_NEAR(img.Pixel(2, 0)[0], 1, 1e-6);
  EXPECT_NEAR(img.Pixel(0, 0)[1], 1, 1e-6);
}

TEST(ReferenceRendererTest, RepeatedRunsAreIdentical) {
  const ReferenceVolume vol = MakeVolume({7, 6, 5}, {0.3, 0.4, 1.1}, DataType::kUint16, 2, Hash);
  RenderParams p = DefaultRenderParams(2, DataType::kUint16, RenderMode::kDvr);
  p.channels[0].color = {1, 0, 1};
  p.channels[1].transform = Mat4::Translation({0.1, -0.2, 0.3});
  p.clip_planes = {{Normalize({1, 1, 1}), 2}};
  p.step_voxels = 0.37;
  const Camera cam = StandardCamera(StandardView::kIso, vol, 20, 14, Projection::kPerspective);
  const RenderImage a = Render(vol, cam, p);
  const RenderImage b = Render(vol, cam, p);
  ASSERT_EQ(a.rgba.size(), b.rgba.size());
  EXPECT_EQ(std::memcmp(a.rgba.data(), b.rgba.data(), a.rgba.size() * sizeof(float)), 0);
}

TEST(ReferenceRendererTest, LoadsFromVolumeSourceThroughValueMaps) {
  volume::VolumeInfo info;
  info.format = "raw";
  info.size = {4, 3, 2};
  info.channels = {{"a", {}}, {"b", {}}};
  info.dtype = DataType::kInt16;
  info.spacing_um = {0.5, std::nullopt, 2.0};
  auto mem = io::MemoryVolume::Create(info);
  ASSERT_TRUE(mem.ok());
  for (int c = 0; c < 2; ++c) {
    for (int z = 0; z < 2; ++z) {
      for (int y = 0; y < 3; ++y) {
        for (int x = 0; x < 4; ++x) {
          (*mem)->Set<int16_t>(
              c, x, y, z, static_cast<int16_t>(-32768 + c * 1000 + x * 7 + y * 300 + z * 5000));
        }
      }
    }
  }
  const std::vector<volume::ValueMap> maps(2, volume::FixedValueMap(DataType::kInt16));
  auto vol = ReferenceVolume::Load(**mem, maps);
  ASSERT_TRUE(vol.ok()) << vol.status().ToString();
  EXPECT_EQ(vol->stored_type(), DataType::kUint16);
  EXPECT_EQ(vol->spacing(), (Vec3{0.5, 1, 2.0}));
  EXPECT_EQ(vol->Value(1, 3, 2, 1), 1000 + 21 + 600 + 5000);
  EXPECT_EQ(vol->Value(0, 0, 0, 0), 0);
  const Camera cam = StandardCamera(StandardView::kZ, *vol, 4, 3);
  const RenderParams p = DefaultRenderParams(2, DataType::kUint16, RenderMode::kMip);
  auto direct = RenderReference(**mem, maps, cam, p);
  ASSERT_TRUE(direct.ok());
  EXPECT_EQ(direct->rgba, Render(*vol, cam, p).rgba);
  // Mismatched maps are refused.
  EXPECT_FALSE(ReferenceVolume::Load(**mem, {maps[0]}).ok());
  EXPECT_FALSE(
      ReferenceVolume::Load(**mem, std::vector(2, volume::FixedValueMap(DataType::kUint16))).ok());
  EXPECT_FALSE(ReferenceVolume::Load(**mem, maps, 10).ok());
}

TEST(ReferenceRendererTest, RejectsInvalidParametersAndVolumes) {
  const ReferenceVolume vol = MakeVolume(
      {2, 2, 2}, {1, 1, 1}, DataType::kUint8, 1,
      [](int c, int64_t x, int64_t y, int64_t z) -> uint16_t { return Hash(c, x, y, z) % 256; });
  const Camera cam = StandardCamera(StandardView::kZ, vol, 2, 2);
  const RenderParams good = DefaultRenderParams(1, DataType::kUint8, RenderMode::kDvr);
  EXPECT_TRUE(RenderReference(vol, cam, good).ok());
  std::vector<std::function<void(RenderParams&)>> breakers = {
      [](RenderParams& p) { p.channels.push_back(p.channels[0]); },
      [](RenderParams& p) { p.clip_planes.assign(4, ClipPlane{}); },
      [](RenderParams& p) {
        p.clip_planes = {{{0, 0, 0}, 1}};
      },
      [](RenderParams& p) { p.step_voxels = 0; },
      [](RenderParams& p) { p.step_voxels = std::numeric_limits<double>::quiet_NaN(); },
      [](RenderParams& p) { p.channels[0].window = 0; },
      [](RenderParams& p) { p.channels[0].gamma = -1; },
      [](RenderParams& p) { p.channels[0].opacity_scale = -1; },
      [](RenderParams& p) {
        p.channels[0].color = {2, 0, 0};
      },
      [](RenderParams& p) { p.channels[0].transform(3, 0) = 1; },
      [](RenderParams& p) {
        p.background = {0, 0, 0, 2};
      },
  };
  for (size_t i = 0; i < breakers.size(); ++i) {
    RenderParams p = good;
    breakers[i](p);
    auto r = RenderReference(vol, cam, p);
    EXPECT_FALSE(r.ok()) << "breaker " << i;
    EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  }
  EXPECT_FALSE(ReferenceVolume::FromStored({2, 2, 2}, {1, 1, 1}, DataType::kUint8,
                                           {std::vector<uint16_t>(8, 256)})
                   .ok());
  EXPECT_FALSE(ReferenceVolume::FromStored({2, 2, 2}, {1, 1, 1}, DataType::kUint8,
                                           {std::vector<uint16_t>(7, 0)})
                   .ok());
  EXPECT_FALSE(ReferenceVolume::FromStored({0, 2, 2}, {1, 1, 1}, DataType::kUint8, {{}}).ok());
  EXPECT_FALSE(ReferenceVolume::FromStored({1, 1, 1}, {1, 0, 1}, DataType::kUint8, {{0}}).ok());
  EXPECT_FALSE(ReferenceVolume::FromStored({1, 1, 1}, {1, 1, 1}, DataType::kInt16, {{0}}).ok());
}

}  // namespace
}  // namespace octoscope::render
