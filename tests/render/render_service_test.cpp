// RenderService (server/render/render_service.h): frame jobs of several views on one render
// thread. Every image the service delivers is checked against a render of the same request made
// here WITHOUT the service (a VolumeRenderer / SliceRenderer on a fresh DeviceOctree, run on the
// test thread before the service exists) and, where the level of detail is 0, against the CPU
// reference renderer. No test asserts a time: waits use generous timeouts only to turn a hang
// into a failure.
#include "render/render_service.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <future>
#include <latch>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cl_test_env.h"
#include "render/slice_renderer.h"
#include "render/volume_renderer.h"
#include "render_fixture.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::CompareImages;
using ::octoscope::render::testing::MakeRenderScene;
using ::octoscope::render::testing::RenderScene;
using ::octoscope::render::testing::SceneSpec;
using ::octoscope::render::testing::SharedClTestEnv;
using namespace std::chrono_literals;

// Long enough for PoCL on a loaded 2-core machine; only a hang reaches it.
constexpr auto kTimeout = 300s;
// Float (GPU) vs double (reference) MIP of the same voxels: a few float ulps of a [0, 1] value,
// far below one 8-bit step.
constexpr double kReferenceTolerance = 1.0 / 255;

uint32_t Hash(int64_t x, int64_t y, int64_t z) {
  uint32_t h = static_cast<uint32_t>(x * 73856093 ^ y * 19349663 ^ z * 83492791);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

// Noise over the whole volume: no brick is homogeneous, every ray needs every brick it crosses.
SceneSpec NoiseSpec(std::array<int64_t, 3> size) {
  SceneSpec spec;
  spec.size = size;
  spec.brick = {16, 16, 16};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(Hash(x, y, z) & 0xffffu);
  };
  return spec;
}

std::unique_ptr<RenderScene> Scene(const SceneSpec& spec, bool insert = true) {
  auto scene = MakeRenderScene(spec, insert);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return scene.ok() ? std::move(*scene) : nullptr;
}

RenderParams Mip() { return DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kMip); }

FrameOptions Refine() {
  FrameOptions options;
  options.mode = FrameMode::kRefine;
  return options;
}

FrameOptions FullFrame() { return FrameOptions{}; }

// An orthographic view along +z of the square [x0, x0 + side] x [y0, y0 + side], one pixel per
// µm (so the level of detail is 0 with unit spacing).
Camera ZView(double x0, double y0, int side) {
  const double cx = x0 + side / 2.0, cy = y0 + side / 2.0;
  auto camera = Camera::LookAt(Projection::kOrthographic, {cx, cy, -1}, {cx, cy, 0}, {0, -1, 0},
                               side, side, 30, side);
  EXPECT_TRUE(camera.ok()) << camera.status().ToString();
  return *camera;
}

Camera Standard(const RenderScene& scene, StandardView view, int width, int height) {
  auto camera =
      Camera::Standard(view, Projection::kOrthographic,
                       PhysicalBounds(scene.spec.size, scene.spec.spacing), width, height);
  EXPECT_TRUE(camera.ok()) << camera.status().ToString();
  return *camera;
}

// A render of one request without the service (its own DeviceOctree on the shared context).
RenderImage DirectVolume(RenderScene& scene, const Camera& camera, const RenderParams& params,
                         const FrameOptions& options, const DeviceOctreeOptions& device = {}) {
  const auto& env = SharedClTestEnv();
  auto dev = DeviceOctree::Create(env.context, scene.tree.get(), device);
  EXPECT_TRUE(dev.ok()) << dev.status().ToString();
  if (!dev.ok()) return {};
  auto renderer = VolumeRenderer::Create(env.context, env.programs, dev->get(), scene.spec.spacing);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  if (!renderer.ok()) return {};
  FrameStats stats;
  auto image = (*renderer)->Render(camera, params, options, &stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  if (options.mode == FrameMode::kRefine) {
    EXPECT_TRUE(stats.final);
  }
  return image.ok() ? std::move(*image) : RenderImage{};
}

RenderImage DirectSlice(RenderScene& scene, const SliceView& view, const RenderParams& params) {
  const auto& env = SharedClTestEnv();
  auto dev = DeviceOctree::Create(env.context, scene.tree.get());
  EXPECT_TRUE(dev.ok()) << dev.status().ToString();
  if (!dev.ok()) return {};
  auto renderer = SliceRenderer::Create(env.context, env.programs, dev->get(), scene.spec.spacing);
  EXPECT_TRUE(renderer.ok()) << renderer.status().ToString();
  if (!renderer.ok()) return {};
  SliceOptions options;
  options.converge = true;
  options.max_frames = kDefaultSliceMaxPasses;
  SliceStats stats;
  auto image = (*renderer)->Render(view, params, options, &stats);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  EXPECT_TRUE(stats.converged);
  return image.ok() ? std::move(*image) : RenderImage{};
}

RenderImage Reference(const RenderScene& scene, const Camera& camera, const RenderParams& params) {
  auto volume = scene.Reference();
  EXPECT_TRUE(volume.ok()) << volume.status().ToString();
  auto image = RenderReference(*volume, camera, params);
  EXPECT_TRUE(image.ok()) << image.status().ToString();
  return image.ok() ? std::move(*image) : RenderImage{};
}

std::unique_ptr<RenderService> MakeService(RenderScene& scene,
                                           const RenderServiceOptions& options = {}) {
  const auto& env = SharedClTestEnv();
  auto service = RenderService::CreateShared(env.context, env.programs, scene.tree.get(),
                                             scene.spec.spacing, options);
  EXPECT_TRUE(service.ok()) << service.status().ToString();
  return service.ok() ? std::move(*service) : nullptr;
}

bool Identical(const RenderImage& a, const RenderImage& b) {
  return a.width == b.width && a.height == b.height && a.rgba == b.rgba;
}

// Collects one view's results (callbacks run on the render thread).
class FrameSink {
 public:
  FrameCallback Callback() {
    return [this](FrameResult result) { Add(std::move(result)); };
  }
  void Add(FrameResult result) {
    std::lock_guard lock(mu_);
    frames_.push_back(std::move(result));
    cv_.notify_all();
  }
  // The final result of `sequence`; nullopt after kTimeout (a hang).
  std::optional<FrameResult> WaitFinal(uint64_t sequence) {
    std::unique_lock lock(mu_);
    std::optional<FrameResult> found;
    cv_.wait_for(lock, kTimeout, [&] {
      for (const FrameResult& f : frames_) {
        if (f.final && f.sequence == sequence) {
          found = f;
          return true;
        }
      }
      return false;
    });
    return found;
  }
  std::vector<FrameResult> Frames() const {
    std::lock_guard lock(mu_);
    return frames_;
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<FrameResult> frames_;
};

FrameRequest VolumeRequest(const Camera& camera, const FrameOptions& options, uint64_t sequence,
                           const RenderParams& params = Mip()) {
  FrameRequest request;
  request.camera = camera;
  request.params = params;
  request.options = options;
  request.sequence = sequence;
  return request;
}

// Pixels whose colour is not the (black) background.
int LitPixels(const RenderImage& image) {
  int lit = 0;
  for (size_t i = 0; i + 3 < image.rgba.size(); i += 4) {
    if (image.rgba[i] > 1e-6f) ++lit;
  }
  return lit;
}

TEST(RenderServiceTest, OneViewRefinementEqualsDirectRenderAndReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), Refine());
  const RenderImage reference = Reference(*scene, camera, Mip());

  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  FrameSink sink;
  const ViewId view = service->OpenView(sink.Callback());
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera, Refine(), 7)).ok());
  std::optional<FrameResult> final = sink.WaitFinal(7);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_EQ(final->view, view);
  EXPECT_EQ(final->kind, FrameKind::kVolume);
  EXPECT_TRUE(final->stats.final);
  EXPECT_TRUE(Identical(final->image, direct));
  const auto diff = CompareImages(final->image, reference);
  EXPECT_LE(diff.max_abs, kReferenceTolerance) << "at " << diff.worst_x << "," << diff.worst_y;

  // Progress images (every pass) come before the final one, with growing finished fractions.
  const std::vector<FrameResult> frames = sink.Frames();
  ASSERT_FALSE(frames.empty());
  EXPECT_TRUE(frames.back().final);
  EXPECT_EQ(static_cast<int>(frames.size()), final->stats.passes);
  for (size_t i = 0; i + 1 < frames.size(); ++i) {
    EXPECT_FALSE(frames[i].final);
    EXPECT_EQ(frames[i].image.width, 32);
    EXPECT_LE(frames[i].stats.finished_fraction, frames[i + 1].stats.finished_fraction);
  }
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.requests, 1u);
  EXPECT_EQ(stats.frames_delivered, 1u);
  EXPECT_EQ(stats.progress_delivered + 1, frames.size());
}

TEST(RenderServiceTest, OwnsItsContextAndPrograms) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  // The first full frame (nothing resident yet) is deterministic: compare with a direct one.
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), FullFrame());
  auto context = ComputeContext::Create(SharedClTestEnv().context->device());
  ASSERT_TRUE(context.ok()) << context.status().ToString();
  auto service = RenderService::Create(std::move(*context), scene->tree.get(), scene->spec.spacing);
  ASSERT_TRUE(service.ok()) << service.status().ToString();
  EXPECT_EQ((*service)->device().name, SharedClTestEnv().context->device().name);
  FrameSink sink;
  const ViewId view = (*service)->OpenView(sink.Callback());
  ASSERT_TRUE((*service)->Submit(view, VolumeRequest(camera, FullFrame(), 1)).ok());
  std::optional<FrameResult> frame = sink.WaitFinal(1);
  ASSERT_TRUE(frame.has_value());
  ASSERT_TRUE(frame->status.ok()) << frame->status.ToString();
  EXPECT_TRUE(Identical(frame->image, direct));
  // A device octree that cannot be created is Create's error, and no thread is left behind.
  RenderServiceOptions impossible;
  impossible.device_octree.max_allocation_bytes = 1;  // Less than one brick.
  auto failed = RenderService::CreateShared(SharedClTestEnv().context, SharedClTestEnv().programs,
                                            scene->tree.get(), scene->spec.spacing, impossible);
  ASSERT_FALSE(failed.ok());
  EXPECT_EQ(failed.status().code(), StatusCode::kResourceExhausted);
}

TEST(RenderServiceTest, FullFrameAndFinalOnlyRefinement) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), Refine());

  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  FrameSink sink;
  const ViewId view = service->OpenView(sink.Callback());
  // A full frame is one pass, delivered as final (coarser where bricks were missing).
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera, FullFrame(), 1)).ok());
  std::optional<FrameResult> full = sink.WaitFinal(1);
  ASSERT_TRUE(full.has_value());
  ASSERT_TRUE(full->status.ok()) << full->status.ToString();
  EXPECT_EQ(full->stats.passes, 1);
  EXPECT_EQ(full->image.width, 32);
  for (float v : full->image.rgba) ASSERT_TRUE(std::isfinite(v));
  // A refinement asking for the final image only: exactly one more callback.
  FrameRequest refine = VolumeRequest(camera, Refine(), 2);
  refine.progress_images = false;
  ASSERT_TRUE(service->Submit(view, std::move(refine)).ok());
  std::optional<FrameResult> final = sink.WaitFinal(2);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_TRUE(Identical(final->image, direct));
  EXPECT_EQ(sink.Frames().size(), 2u);
  // Invalid parameters come back through the callback as the request's final error.
  FrameRequest bad = VolumeRequest(camera, FullFrame(), 3);
  bad.params.channels.clear();
  ASSERT_TRUE(service->Submit(view, std::move(bad)).ok());
  std::optional<FrameResult> error = sink.WaitFinal(3);
  ASSERT_TRUE(error.has_value());
  EXPECT_FALSE(error->status.ok());
  EXPECT_TRUE(error->image.rgba.empty());
  // A volume request without camera, a slice request without slice, an unknown view.
  FrameRequest no_camera;
  EXPECT_EQ(service->Submit(view, no_camera).code(), StatusCode::kInvalidArgument);
  FrameRequest no_slice;
  no_slice.kind = FrameKind::kSlice;
  EXPECT_EQ(service->Submit(view, no_slice).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(service->Submit(view + 100, VolumeRequest(camera, FullFrame(), 4)).code(),
            StatusCode::kNotFound);
}

TEST(RenderServiceTest, LatestStateWins) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({48, 32, 24}));
  ASSERT_NE(scene, nullptr);
  constexpr int kRequests = 20;
  // Request k pans the view by k/4 µm.
  const auto camera_of = [](int k) { return ZView(0.25 * k, 0, 32); };
  const RenderImage newest = DirectVolume(*scene, camera_of(kRequests), Mip(), Refine());
  const RenderImage oldest = DirectVolume(*scene, camera_of(1), Mip(), Refine());
  ASSERT_FALSE(Identical(newest, oldest));

  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  // The first callback (of request 1) holds the render thread until requests 2..20 are in, so
  // request 1 is in flight while they arrive, deterministically.
  FrameSink sink;
  std::promise<void> entered, release;
  std::shared_future<void> released = release.get_future().share();
  std::atomic<bool> first = true;
  const ViewId view = service->OpenView([&](FrameResult result) {
    if (first.exchange(false)) {
      entered.set_value();
      released.wait();
    }
    sink.Add(std::move(result));
  });
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera_of(1), Refine(), 1)).ok());
  ASSERT_EQ(entered.get_future().wait_for(kTimeout), std::future_status::ready);
  for (int k = 2; k <= kRequests; ++k) {
    ASSERT_TRUE(service->Submit(view, VolumeRequest(camera_of(k), Refine(), k)).ok());
  }
  release.set_value();
  std::optional<FrameResult> final = sink.WaitFinal(kRequests);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_TRUE(Identical(final->image, newest));

  // Request 1 delivered its first pass (unless that pass finished it), 2..19 nothing at all.
  const std::vector<FrameResult> frames = sink.Frames();
  ASSERT_FALSE(frames.empty());
  const bool first_was_final = frames.front().final;
  for (const FrameResult& f : frames) {
    EXPECT_TRUE(f.sequence == 1 || f.sequence == kRequests) << f.sequence;
    if (f.sequence == 1 && !first_was_final) {
      EXPECT_FALSE(f.final);
    }
  }
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.requests, static_cast<uint64_t>(kRequests));
  EXPECT_EQ(stats.replaced, static_cast<uint64_t>(kRequests - 2));  // 2..19.
  if (!first_was_final) {
    EXPECT_EQ(stats.cancelled, 1u);
  }
  EXPECT_EQ(stats.frames_delivered, first_was_final ? 2u : 1u);
}

TEST(RenderServiceTest, SeveralViewsFromSeveralThreads) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 32}));
  ASSERT_NE(scene, nullptr);
  // Three 3-D views and two slice views, each with its own final request.
  const std::vector<Camera> cameras = {Standard(*scene, StandardView::kZ, 32, 32),
                                       Standard(*scene, StandardView::kY, 32, 32),
                                       Standard(*scene, StandardView::kX, 32, 32)};
  std::vector<SliceView> slices(2);
  slices[0].axis = 2;
  slices[0].position_um = 10.3;
  slices[0].width = slices[0].height = 32;
  slices[1].axis = 0;
  slices[1].position_um = 21.6;
  slices[1].width = slices[1].height = 32;
  std::vector<RenderImage> expected;
  for (const Camera& camera : cameras)
    expected.push_back(DirectVolume(*scene, camera, Mip(), Refine()));
  for (const SliceView& slice : slices) expected.push_back(DirectSlice(*scene, slice, Mip()));
  // The MIP views at level 0 agree with the reference too.
  for (size_t i = 0; i < cameras.size(); ++i) {
    EXPECT_LE(CompareImages(expected[i], Reference(*scene, cameras[i], Mip())).max_abs,
              kReferenceTolerance);
  }

  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  const size_t view_count = cameras.size() + slices.size();
  std::vector<FrameSink> sinks(view_count);
  std::vector<ViewId> views;
  for (FrameSink& sink : sinks) views.push_back(service->OpenView(sink.Callback()));
  // One thread per view; each sends two full frames (interaction) then the final refinement.
  std::latch start(static_cast<ptrdiff_t>(view_count));
  std::vector<std::thread> threads;
  for (size_t v = 0; v < view_count; ++v) {
    threads.emplace_back([&, v] {
      start.arrive_and_wait();
      for (uint64_t seq = 1; seq <= 3; ++seq) {
        FrameRequest request;
        if (v < cameras.size()) {
          request.camera = cameras[v];
        } else {
          request.kind = FrameKind::kSlice;
          request.slice = slices[v - cameras.size()];
        }
        request.params = Mip();
        request.options = seq == 3 ? Refine() : FullFrame();
        request.sequence = seq;
        EXPECT_TRUE(service->Submit(views[v], std::move(request)).ok());
      }
    });
  }
  for (std::thread& t : threads) t.join();
  for (size_t v = 0; v < view_count; ++v) {
    SCOPED_TRACE("view " + std::to_string(v));
    std::optional<FrameResult> final = sinks[v].WaitFinal(3);
    ASSERT_TRUE(final.has_value());
    ASSERT_TRUE(final->status.ok()) << final->status.ToString();
    EXPECT_EQ(final->view, views[v]);
    EXPECT_EQ(final->kind, v < cameras.size() ? FrameKind::kVolume : FrameKind::kSlice);
    EXPECT_TRUE(final->stats.final);
    const auto diff = CompareImages(final->image, expected[v]);
    EXPECT_EQ(diff.max_abs, 0) << "at " << diff.worst_x << "," << diff.worst_y;
    // A view's results come in submission order; nothing arrives after its final one.
    const std::vector<FrameResult> frames = sinks[v].Frames();
    for (size_t i = 0; i + 1 < frames.size(); ++i) {
      EXPECT_LE(frames[i].sequence, frames[i + 1].sequence);
    }
    EXPECT_TRUE(frames.back().final);
    EXPECT_EQ(frames.back().sequence, 3u);
  }
}

TEST(RenderServiceTest, DisjointViewsShareATinyBrickBuffer) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // 64 x 32 x 32 voxels in 16^3 bricks; view A sees x < 32, view B x >= 32 (level 0, MIP reads
  // every brick along z). Each alone fits in kMinBrickSlots slots per pass; both together do not.
  auto scene = Scene(NoiseSpec({64, 32, 32}));
  ASSERT_NE(scene, nullptr);
  DeviceOctreeOptions tiny;
  tiny.brick_buffer_bytes = scene->tree->geometry().brick_bytes() * kMinBrickSlots;
  const Camera a = ZView(0, 0, 32), b = ZView(32, 0, 32);
  const RenderImage expected_a = DirectVolume(*scene, a, Mip(), Refine());
  const RenderImage expected_b = DirectVolume(*scene, b, Mip(), Refine());
  EXPECT_LE(CompareImages(expected_a, Reference(*scene, a, Mip())).max_abs, kReferenceTolerance);

  RenderServiceOptions options;
  options.device_octree = tiny;
  auto service = MakeService(*scene, options);
  ASSERT_NE(service, nullptr);
  FrameSink sink_a, sink_b;
  const ViewId view_a = service->OpenView(sink_a.Callback());
  const ViewId view_b = service->OpenView(sink_b.Callback());
  ASSERT_TRUE(service->Submit(view_a, VolumeRequest(a, Refine(), 1)).ok());
  ASSERT_TRUE(service->Submit(view_b, VolumeRequest(b, Refine(), 1)).ok());
  std::optional<FrameResult> final_a = sink_a.WaitFinal(1);
  std::optional<FrameResult> final_b = sink_b.WaitFinal(1);
  ASSERT_TRUE(final_a.has_value() && final_b.has_value());
  ASSERT_TRUE(final_a->status.ok()) << final_a->status.ToString();
  ASSERT_TRUE(final_b->status.ok()) << final_b->status.ToString();
  EXPECT_TRUE(Identical(final_a->image, expected_a));
  EXPECT_TRUE(Identical(final_b->image, expected_b));
  // The passes interleaved: each view had several, and the other view's frames came between.
  EXPECT_GT(final_a->stats.passes, 1);
  EXPECT_GT(final_b->stats.passes, 1);
  const RenderServiceStats stats = service->stats();
  std::printf("[ info     ] passes A %d, B %d, stall retries %llu\n", final_a->stats.passes,
              final_b->stats.passes, static_cast<unsigned long long>(stats.stall_retries));
}

TEST(RenderServiceTest, RendersWhileConstructionInserts) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // The 32 x 32 columns form four 16 x 16 blocks b = 2 (y / 16) + x / 16 (one brick column
  // each); block b is bright in plane z = 8 b + 4 only. After planes [0, k) are inserted a MIP
  // along z lights exactly the blocks with 8 b + 4 < k, and a brick's average (the fallback of a
  // missing brick) lights the same pixels as its voxels.
  SceneSpec spec;
  spec.size = {32, 32, 32};
  spec.brick = {16, 16, 16};
  spec.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    const int64_t block = 2 * (y / 16) + x / 16;
    return z == 8 * block + 4 ? static_cast<uint16_t>(30000 + 1000 * (x % 8)) : 0;
  };
  auto scene = Scene(spec, /*insert=*/false);
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  const int full_count = 32 * 32;

  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  FrameSink sink;
  const ViewId view = service->OpenView(sink.Callback());
  uint64_t sequence = 0;
  const auto frame = [&](const FrameOptions& options) -> std::optional<FrameResult> {
    ++sequence;
    EXPECT_TRUE(service->Submit(view, VolumeRequest(camera, options, sequence)).ok());
    return sink.WaitFinal(sequence);
  };
  // Nothing inserted yet: the frame is empty.
  std::optional<FrameResult> empty = frame(FullFrame());
  ASSERT_TRUE(empty.has_value() && empty->status.ok());
  EXPECT_EQ(LitPixels(empty->image), 0);
  std::vector<int> counts = {0};

  // The builder inserts two planes at a time and waits until a frame started after its insert
  // finished, so inserts overlap frames and every stage is seen.
  std::mutex mu;
  std::condition_variable cv;
  int frames_done = 0;
  std::atomic<bool> built = false;
  Status build_status;
  std::thread builder([&] {
    for (int64_t z = 0; z < spec.size[2]; z += 2) {
      int seen = 0;
      {
        std::lock_guard lock(mu);
        seen = frames_done;
      }
      build_status = scene->InsertPlanes(z, z + 2);
      if (!build_status.ok()) break;
      std::unique_lock lock(mu);
      cv.wait_for(lock, kTimeout, [&] { return frames_done >= seen + 2; });
    }
    built = true;
  });
  while (!built) {
    std::optional<FrameResult> f = frame(FullFrame());
    ASSERT_TRUE(f.has_value() && f->status.ok());
    counts.push_back(LitPixels(f->image));
    std::lock_guard lock(mu);
    ++frames_done;
    cv.notify_all();
  }
  builder.join();
  ASSERT_TRUE(build_status.ok()) << build_status.ToString();
  // Full frames after the build converge once the uploads caught up.
  for (int i = 0; i < 10; ++i) {
    std::optional<FrameResult> f = frame(FullFrame());
    ASSERT_TRUE(f.has_value() && f->status.ok());
    counts.push_back(LitPixels(f->image));
    if (f->stats.requests == 0) break;
  }
  std::string trace;
  for (int c : counts) trace += std::to_string(c) + " ";
  SCOPED_TRACE("lit pixels per frame: " + trace);
  std::printf("[ info     ] lit pixels per frame: %s\n", trace.c_str());
  ASSERT_GE(counts.size(), 16u);
  // Grows from nothing to the full count, never dropping much on the way (interpolation at a
  // coarser level may light a few pixels beside a lit block for a frame, until the finer bricks
  // arrive).
  EXPECT_EQ(counts.back(), full_count);
  EXPECT_GE(
      std::count_if(counts.begin(), counts.end(), [&](int c) { return c > 0 && c < full_count; }),
      3);
  int peak = 0;
  for (int c : counts) {
    EXPECT_GE(c, peak - full_count / 10);
    peak = std::max(peak, c);
  }
  // After the build, a refined frame equals the reference.
  std::optional<FrameResult> refined = frame(Refine());
  ASSERT_TRUE(refined.has_value());
  ASSERT_TRUE(refined->status.ok()) << refined->status.ToString();
  EXPECT_EQ(LitPixels(refined->image), full_count);
  EXPECT_LE(CompareImages(refined->image, Reference(*scene, camera, Mip())).max_abs,
            kReferenceTolerance);
}

TEST(RenderServiceTest, CloseViewStopsCallbacks) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 32}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);

  // Closed from another thread while its refinement is in flight: once CloseView returned, the
  // callback never runs again.
  std::atomic<bool> closed = false;
  std::atomic<int> after_close = 0;
  std::promise<void> entered;
  std::atomic<bool> first = true;
  const ViewId a = service->OpenView([&](FrameResult) {
    if (closed) ++after_close;
    if (first.exchange(false)) entered.set_value();
  });
  ASSERT_TRUE(service->Submit(a, VolumeRequest(camera, Refine(), 1)).ok());
  ASSERT_EQ(entered.get_future().wait_for(kTimeout), std::future_status::ready);
  service->CloseView(a);
  closed = true;
  EXPECT_EQ(service->Submit(a, VolumeRequest(camera, Refine(), 2)).code(), StatusCode::kNotFound);

  // Closed from inside its own callback (the render thread): no deadlock, no further callback.
  std::atomic<int> b_calls = 0;
  ViewId b = 0;
  std::promise<ViewId> b_id;
  std::shared_future<ViewId> b_known = b_id.get_future().share();
  b = service->OpenView([&](FrameResult) {
    ++b_calls;
    service->CloseView(b_known.get());
  });
  b_id.set_value(b);
  ASSERT_TRUE(service->Submit(b, VolumeRequest(camera, Refine(), 1)).ok());

  // A throwing callback is caught on the render thread; its view is closed.
  std::atomic<int> c_calls = 0;
  const ViewId c = service->OpenView([&](FrameResult) {
    ++c_calls;
    throw std::runtime_error("boom");
  });
  ASSERT_TRUE(service->Submit(c, VolumeRequest(camera, Refine(), 1)).ok());

  // A later view still renders: the render thread is alive and has passed b's and c's jobs.
  FrameSink sink;
  const ViewId d = service->OpenView(sink.Callback());
  ASSERT_TRUE(service->Submit(d, VolumeRequest(camera, Refine(), 5)).ok());
  std::optional<FrameResult> final = sink.WaitFinal(5);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok());
  EXPECT_EQ(after_close, 0);
  EXPECT_EQ(b_calls, 1);
  EXPECT_EQ(c_calls, 1);
  EXPECT_EQ(service->Submit(b, VolumeRequest(camera, Refine(), 2)).code(), StatusCode::kNotFound);
  EXPECT_EQ(service->Submit(c, VolumeRequest(camera, Refine(), 2)).code(), StatusCode::kNotFound);
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.callback_failures, 1u);
  EXPECT_NE(stats.last_callback_error.find("boom"), std::string::npos);
}

TEST(RenderServiceTest, ShutdownWithPendingJobsIsClean) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({48, 48, 32}));
  ASSERT_NE(scene, nullptr);
  auto service = MakeService(*scene);
  ASSERT_NE(service, nullptr);
  std::atomic<int> calls = 0;
  std::atomic<bool> destroyed = false;
  std::atomic<int> after_destroy = 0;
  std::vector<ViewId> views;
  for (int v = 0; v < 4; ++v) {
    views.push_back(service->OpenView([&](FrameResult) {
      ++calls;
      if (destroyed) ++after_destroy;
    }));
  }
  for (int v = 0; v < 4; ++v) {
    const Camera camera = ZView(4.0 * v, 8, 40);
    ASSERT_TRUE(service->Submit(views[v], VolumeRequest(camera, Refine(), 1)).ok());
  }
  // Destroy on another thread so that a hang fails the test instead of blocking it.
  std::future<void> done = std::async(std::launch::async, [&] { service.reset(); });
  ASSERT_EQ(done.wait_for(kTimeout), std::future_status::ready);
  destroyed = true;
  EXPECT_EQ(after_destroy, 0);
  std::printf("[ info     ] %d callbacks before shutdown\n", calls.load());
}

}  // namespace
}  // namespace octoscope::render
