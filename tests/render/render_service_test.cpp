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
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "cl_test_env.h"
#include "octree/octree.h"
#include "paging/fault_injecting_page_store.h"
#include "paging/page_cache.h"
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

// A render of one request without the service (its own DeviceOctree on the shared context,
// with the coarse levels preloaded as the service's mirrors have them).
RenderImage DirectVolume(RenderScene& scene, const Camera& camera, const RenderParams& params,
                         const FrameOptions& options, const DeviceOctreeOptions& device = {}) {
  const auto& env = SharedClTestEnv();
  auto dev = DeviceOctree::Create(env.context, scene.tree.get(), device);
  EXPECT_TRUE(dev.ok()) << dev.status().ToString();
  if (!dev.ok()) return {};
  EXPECT_TRUE((*dev)->UploadCoarseLevels(kCoarseLevelBytes).ok());
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

std::unique_ptr<RenderService> MakeBareService(const RenderServiceOptions& options = {}) {
  const auto& env = SharedClTestEnv();
  auto service = RenderService::CreateShared(env.context, env.programs, options);
  EXPECT_TRUE(service.ok()) << service.status().ToString();
  return service.ok() ? std::move(*service) : nullptr;
}

ViewId OpenView(RenderService& service, DatasetKey dataset, FrameCallback callback) {
  Result<ViewId> view = service.OpenView(dataset, std::move(callback));
  EXPECT_TRUE(view.ok()) << view.status().ToString();
  return view.ok() ? *view : 0;
}

// A service with one dataset, the scene's octree.
struct Served {
  std::unique_ptr<RenderService> service;
  DatasetKey dataset = 0;

  RenderService* operator->() const { return service.get(); }
  ViewId Open(FrameCallback callback) { return OpenView(*service, dataset, std::move(callback)); }
};

Served MakeService(RenderScene& scene, const RenderServiceOptions& options = {}) {
  Served served;
  served.service = MakeBareService(options);
  if (served.service != nullptr) {
    served.dataset = served.service->AddDataset(scene.tree.get(), scene.spec.spacing);
  }
  return served;
}

// Closes views when it goes out of scope. Declare it after the locals the views' callbacks use:
// a view that keeps submitting from its callback (or has a frame in flight when an ASSERT
// returns) must not be delivered to once those locals are gone.
class ViewsClosedAtExit {
 public:
  ViewsClosedAtExit(RenderService& service, std::vector<ViewId> views)
      : service_(service), views_(std::move(views)) {}
  ViewsClosedAtExit(const ViewsClosedAtExit&) = delete;
  ViewsClosedAtExit& operator=(const ViewsClosedAtExit&) = delete;
  ~ViewsClosedAtExit() {
    for (ViewId view : views_) service_.CloseView(view);
  }

 private:
  RenderService& service_;
  std::vector<ViewId> views_;
};

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
  // Whether the final result of `sequence` arrives within `timeout`.
  bool WaitFinalFor(uint64_t sequence, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, timeout, [&] {
      return std::any_of(frames_.begin(), frames_.end(),
                         [&](const FrameResult& f) { return f.final && f.sequence == sequence; });
    });
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

  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
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
  // The first full frame (only the coarse levels resident) is deterministic: compare with a
  // direct one.
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), FullFrame());
  auto context = ComputeContext::Create(SharedClTestEnv().context->device());
  ASSERT_TRUE(context.ok()) << context.status().ToString();
  auto service = RenderService::Create(std::move(*context));
  ASSERT_TRUE(service.ok()) << service.status().ToString();
  EXPECT_EQ((*service)->device().name, SharedClTestEnv().context->device().name);
  const DatasetKey dataset = (*service)->AddDataset(scene->tree.get(), scene->spec.spacing);
  FrameSink sink;
  const ViewId view = OpenView(**service, dataset, sink.Callback());
  ASSERT_TRUE((*service)->Submit(view, VolumeRequest(camera, FullFrame(), 1)).ok());
  std::optional<FrameResult> frame = sink.WaitFinal(1);
  ASSERT_TRUE(frame.has_value());
  ASSERT_TRUE(frame->status.ok()) << frame->status.ToString();
  EXPECT_TRUE(Identical(frame->image, direct));
  // Automatic budgets: something, and a 4096^2 request fits.
  EXPECT_GT((*service)->device_memory_bytes(), 0u);
  EXPECT_GE((*service)->frame_memory_bytes(), kDefaultMaxRequestBytes);
  // Options that make no sense are Create's error.
  RenderServiceOptions bad;
  bad.refine_share = 1;
  EXPECT_EQ(RenderService::CreateShared(SharedClTestEnv().context, SharedClTestEnv().programs, bad)
                .status()
                .code(),
            StatusCode::kInvalidArgument);
  bad = {};
  bad.frame_memory_bytes = 1000;
  bad.max_request_bytes = 2000;
  EXPECT_EQ(RenderService::CreateShared(SharedClTestEnv().context, SharedClTestEnv().programs, bad)
                .status()
                .code(),
            StatusCode::kInvalidArgument);
}

TEST(RenderServiceTest, AMirrorThatCannotBeCreatedFailsItsRequestsNotTheService) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  RenderServiceOptions impossible;
  impossible.device_octree.max_allocation_bytes = 1;  // Less than one brick.
  Served service = MakeService(*scene, impossible);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
  for (uint64_t seq : {1, 2}) {
    ASSERT_TRUE(
        service->Submit(view, VolumeRequest(camera, seq == 1 ? FullFrame() : Refine(), seq)).ok());
    std::optional<FrameResult> failed = sink.WaitFinal(seq);
    ASSERT_TRUE(failed.has_value());
    EXPECT_EQ(failed->status.code(), StatusCode::kResourceExhausted) << failed->status.ToString();
    EXPECT_NE(failed->status.message().find("device mirror"), std::string::npos);
    EXPECT_TRUE(failed->image.rgba.empty());
  }
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.mirror_failures, 2u);  // Each request tried again.
  EXPECT_EQ(stats.mirrors, 0u);
  EXPECT_EQ(service->OpenView(service.dataset + 1, sink.Callback()).status().code(),
            StatusCode::kNotFound);
}

TEST(RenderServiceTest, FullFrameAndFinalOnlyRefinement) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const Camera camera = Standard(*scene, StandardView::kZ, 32, 32);
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), Refine());

  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
  // A full frame is one pass, delivered as final (coarser where bricks were missing), with the
  // request's identifying fields.
  FrameRequest first = VolumeRequest(camera, FullFrame(), 1);
  first.version = 41;
  ASSERT_TRUE(service->Submit(view, std::move(first)).ok());
  std::optional<FrameResult> full = sink.WaitFinal(1);
  ASSERT_TRUE(full.has_value());
  ASSERT_TRUE(full->status.ok()) << full->status.ToString();
  EXPECT_EQ(full->view, view);
  EXPECT_EQ(full->dataset, service.dataset);
  EXPECT_EQ(full->version, 41u);
  EXPECT_EQ(full->kind, FrameKind::kVolume);
  EXPECT_EQ(full->mode, FrameMode::kFullFrame);
  EXPECT_EQ(full->stats.passes, 1);
  EXPECT_EQ(full->image.width, 32);
  for (float v : full->image.rgba) ASSERT_TRUE(std::isfinite(v));
  // A refinement asking for the final image only: exactly one more callback.
  FrameRequest refine = VolumeRequest(camera, Refine(), 2);
  refine.progress_images = false;
  refine.version = 42;
  ASSERT_TRUE(service->Submit(view, std::move(refine)).ok());
  std::optional<FrameResult> final = sink.WaitFinal(2);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_EQ(final->version, 42u);
  EXPECT_EQ(final->mode, FrameMode::kRefine);
  EXPECT_EQ(final->stats.finished_fraction, 1.0);
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
  EXPECT_EQ(service->OpenView(service.dataset, FrameCallback()).status().code(),
            StatusCode::kInvalidArgument);
}

TEST(RenderServiceTest, AViewsFirstFrameShowsTheCoarseLevelsAtOnce) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({64, 64, 64}));  // 16^3 bricks: levels 0..2 (64, 8, 1 bricks).
  ASSERT_NE(scene, nullptr);
  ASSERT_EQ(scene->tree->geometry().root_level(), 2);
  const Camera camera = ZView(0, 0, 64);
  FrameOptions coarse = FullFrame();
  coarse.lod_bias = 1;  // Level 1: preloaded with the root when the mirror was made.
  FrameOptions refine = Refine();
  refine.lod_bias = 1;
  const RenderImage direct = DirectVolume(*scene, camera, Mip(), refine);
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera, coarse, 1)).ok());
  std::optional<FrameResult> first = sink.WaitFinal(1);
  ASSERT_TRUE(first.has_value());
  ASSERT_TRUE(first->status.ok()) << first->status.ToString();
  // The very first frame needs nothing more: it is the refined image at that level.
  EXPECT_EQ(first->stats.requests, 0u);
  EXPECT_EQ(first->stats.bricks_uploaded, 0u);
  EXPECT_LE(CompareImages(first->image, direct).max_abs, 1e-6);
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

  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  // The first callback (of request 1) holds the render thread until requests 2..20 are in, so
  // request 1 is in flight while they arrive, deterministically.
  FrameSink sink;
  std::promise<void> entered, release;
  std::shared_future<void> released = release.get_future().share();
  std::atomic<bool> first = true;
  const ViewId view = service.Open([&](FrameResult result) {
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

  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  const size_t view_count = cameras.size() + slices.size();
  std::vector<FrameSink> sinks(view_count);
  std::vector<ViewId> views;
  for (FrameSink& sink : sinks) views.push_back(service.Open(sink.Callback()));
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
  const RenderImage expected_a = DirectVolume(*scene, a, Mip(), Refine(), tiny);
  const RenderImage expected_b = DirectVolume(*scene, b, Mip(), Refine(), tiny);
  EXPECT_LE(CompareImages(expected_a, Reference(*scene, a, Mip())).max_abs, kReferenceTolerance);
  EXPECT_LE(CompareImages(expected_b, Reference(*scene, b, Mip())).max_abs, kReferenceTolerance);

  RenderServiceOptions options;
  options.device_memory_bytes = tiny.brick_buffer_bytes;  // The whole device: 8 bricks.
  // A tiny quantum: the views alternate pass by pass (with the default one, a view may finish
  // within its first quantum before the other even starts).
  options.quantum_ms = 1e-3;
  // Whole-image passes: the claim below is about them (a band's first pass may sample nothing
  // before its bricks came; bands are checked in VolumeRendererTest.RefinementInRowBands...).
  options.refine_pass_ms = 0;
  Served service = MakeService(*scene, options);
  ASSERT_NE(service.service, nullptr);
  // One event log for both views (callbacks run on the render thread, in order).
  std::mutex mu;
  std::vector<char> order;
  FrameSink sink_a, sink_b;
  const auto logged = [&](FrameSink& sink, char name) {
    return [&, name](FrameResult result) {
      {
        std::lock_guard lock(mu);
        order.push_back(name);
      }
      sink.Add(std::move(result));
    };
  };
  const ViewId view_a = service.Open(logged(sink_a, 'A'));
  const ViewId view_b = service.Open(logged(sink_b, 'B'));
  // Both requests wait until both are in (the render thread holds in a third view's callback),
  // so they compete from their first pass however this thread is scheduled.
  std::promise<void> entered, gate;
  std::shared_future<void> gate_open = gate.get_future().share();
  const ViewId holder = service.Open([&entered, gate_open](FrameResult) {
    entered.set_value();
    gate_open.wait();
  });
  ASSERT_TRUE(service->Submit(holder, VolumeRequest(ZView(0, 0, 4), FullFrame(), 1)).ok());
  entered.get_future().wait();
  ASSERT_TRUE(service->Submit(view_a, VolumeRequest(a, Refine(), 1)).ok());
  ASSERT_TRUE(service->Submit(view_b, VolumeRequest(b, Refine(), 1)).ok());
  gate.set_value();
  std::optional<FrameResult> final_a = sink_a.WaitFinal(1);
  std::optional<FrameResult> final_b = sink_b.WaitFinal(1);
  ASSERT_TRUE(final_a.has_value() && final_b.has_value());
  ASSERT_TRUE(final_a->status.ok()) << final_a->status.ToString();
  ASSERT_TRUE(final_b->status.ok()) << final_b->status.ToString();
  EXPECT_TRUE(Identical(final_a->image, expected_a));
  EXPECT_TRUE(Identical(final_b->image, expected_b));
  // The passes interleaved (each view had several, and the other's came between), and EVERY pass
  // of each view advanced its rays although the other view's uploads needed the slots too: what
  // a pass uploads is reserved for that view's next pass.
  EXPECT_GT(final_a->stats.passes, 1);
  EXPECT_GT(final_b->stats.passes, 1);
  for (const FrameSink* sink : {&sink_a, &sink_b}) {
    const std::vector<FrameResult> frames = sink->Frames();
    for (size_t i = 1; i < frames.size(); ++i) {
      EXPECT_GT(frames[i].stats.samples, frames[i - 1].stats.samples) << "pass " << i + 1;
    }
  }
  std::string sequence(order.begin(), order.end());
  EXPECT_NE(sequence.find("AB"), std::string::npos) << sequence;
  EXPECT_NE(sequence.find("BA"), std::string::npos) << sequence;
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.brick_memory_bytes, tiny.brick_buffer_bytes);
  EXPECT_EQ(stats.io_waits, 0u);
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

  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
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
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);

  // Closed from another thread while its refinement is in flight: once CloseView returned, the
  // callback never runs again.
  std::atomic<bool> closed = false;
  std::atomic<int> after_close = 0;
  std::promise<void> entered;
  std::atomic<bool> first = true;
  const ViewId a = service.Open([&](FrameResult) {
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
  b = service.Open([&](FrameResult) {
    ++b_calls;
    service->CloseView(b_known.get());
  });
  b_id.set_value(b);
  ASSERT_TRUE(service->Submit(b, VolumeRequest(camera, Refine(), 1)).ok());

  // A throwing callback is caught on the render thread; its view is closed.
  std::atomic<int> c_calls = 0;
  const ViewId c = service.Open([&](FrameResult) {
    ++c_calls;
    throw std::runtime_error("boom");
  });
  ASSERT_TRUE(service->Submit(c, VolumeRequest(camera, Refine(), 1)).ok());

  // A later view still renders: the render thread is alive and has passed b's and c's jobs.
  FrameSink sink;
  const ViewId d = service.Open(sink.Callback());
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
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  std::atomic<int> calls = 0;
  std::atomic<bool> destroyed = false;
  std::atomic<int> after_destroy = 0;
  std::vector<ViewId> views;
  for (int v = 0; v < 4; ++v) {
    views.push_back(service.Open([&](FrameResult) {
      ++calls;
      if (destroyed) ++after_destroy;
    }));
  }
  for (int v = 0; v < 4; ++v) {
    const Camera camera = ZView(4.0 * v, 8, 40);
    ASSERT_TRUE(service->Submit(views[v], VolumeRequest(camera, Refine(), 1)).ok());
  }
  // Destroy on another thread so that a hang fails the test instead of blocking it.
  std::future<void> done = std::async(std::launch::async, [&] { service.service.reset(); });
  ASSERT_EQ(done.wait_for(kTimeout), std::future_status::ready);
  destroyed = true;
  EXPECT_EQ(after_destroy, 0);
  std::printf("[ info     ] %d callbacks before shutdown\n", calls.load());
}

// Polls `condition` until it holds (true) or kTimeout passed (false).
template <typename Condition>
bool Eventually(Condition condition) {
  const auto deadline = std::chrono::steady_clock::now() + kTimeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

TEST(RenderServiceTest, DatasetsShareTheDeviceAndItsBrickBudget) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // A: 64 x 32 x 32 in 16^3 bricks, at most 16 + 2 + 1 = 19 bricks; B: 32 x 32 x 24, at most
  // 8 + 1 = 9 bricks. The device holds 20 bricks: alone A gets all it can use (19); with B, B
  // keeps its 9 and A gets the remaining 11.
  auto scene_a = Scene(NoiseSpec({64, 32, 32}));
  SceneSpec spec_b = NoiseSpec({32, 32, 24});
  spec_b.value = [](int, int64_t x, int64_t y, int64_t z) -> uint16_t {
    return static_cast<uint16_t>(Hash(z, x, y) & 0xffffu);  // Other data than A's.
  };
  auto scene_b = Scene(spec_b);
  ASSERT_TRUE(scene_a != nullptr && scene_b != nullptr);
  const uint64_t brick = scene_a->tree->geometry().brick_bytes();
  const Camera camera_a = Standard(*scene_a, StandardView::kZ, 64, 32);
  const Camera camera_b = Standard(*scene_b, StandardView::kX, 24, 32);
  const RenderImage expected_a = DirectVolume(*scene_a, camera_a, Mip(), Refine());
  const RenderImage expected_b = DirectVolume(*scene_b, camera_b, Mip(), Refine());
  EXPECT_LE(CompareImages(expected_b, Reference(*scene_b, camera_b, Mip())).max_abs,
            kReferenceTolerance);

  RenderServiceOptions options;
  options.device_memory_bytes = 20 * brick;
  options.mirror_idle_timeout = 0ms;  // Dropped as soon as the last view closes.
  auto service = MakeBareService(options);
  ASSERT_NE(service, nullptr);
  const DatasetKey a = service->AddDataset(scene_a->tree.get(), scene_a->spec.spacing);
  const DatasetKey b = service->AddDataset(scene_b->tree.get(), scene_b->spec.spacing);
  EXPECT_NE(a, b);
  FrameSink sink_a, sink_b;
  const ViewId view_a = OpenView(*service, a, sink_a.Callback());
  uint64_t seq_a = 0;
  const auto refine_a = [&] {
    ++seq_a;
    EXPECT_TRUE(service->Submit(view_a, VolumeRequest(camera_a, Refine(), seq_a)).ok());
    std::optional<FrameResult> final = sink_a.WaitFinal(seq_a);
    EXPECT_TRUE(final.has_value() && final->status.ok());
    if (final.has_value()) {
      EXPECT_TRUE(Identical(final->image, expected_a)) << "request " << seq_a;
    }
  };
  refine_a();
  EXPECT_TRUE(Eventually([&] { return service->stats().brick_memory_bytes == 19 * brick; }));
  // B opens: A shrinks to its share before B's mirror exists.
  const ViewId view_b = OpenView(*service, b, sink_b.Callback());
  ASSERT_TRUE(service->Submit(view_b, VolumeRequest(camera_b, Refine(), 1)).ok());
  std::optional<FrameResult> final_b = sink_b.WaitFinal(1);
  ASSERT_TRUE(final_b.has_value());
  ASSERT_TRUE(final_b->status.ok()) << final_b->status.ToString();
  EXPECT_TRUE(Identical(final_b->image, expected_b));
  EXPECT_TRUE(Eventually([&] {
    const RenderServiceStats stats = service->stats();
    return stats.mirrors == 2 && stats.brick_memory_bytes == 20 * brick;
  }));
  refine_a();  // Still right with 11 slots (after the re-upload).
  // B's last view closes: its mirror goes and A grows back.
  service->CloseView(view_b);
  EXPECT_TRUE(Eventually([&] {
    const RenderServiceStats stats = service->stats();
    return stats.mirrors == 1 && stats.brick_memory_bytes == 19 * brick;
  }));
  refine_a();
  const RenderServiceStats stats = service->stats();
  EXPECT_EQ(stats.mirrors_created, 2u);
  EXPECT_EQ(stats.mirror_resizes, 2u);  // A shrank, then grew.
  EXPECT_GE(stats.mirrors_dropped, 1u);
}

TEST(RenderServiceTest, RemoveDatasetClosesItsViewsAndFreesItsOctree) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene_a = Scene(NoiseSpec({48, 48, 32}));
  auto scene_b = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_TRUE(scene_a != nullptr && scene_b != nullptr);
  const Camera camera_b = Standard(*scene_b, StandardView::kZ, 32, 32);
  const RenderImage expected_b = DirectVolume(*scene_b, camera_b, Mip(), Refine());
  auto service = MakeBareService();
  ASSERT_NE(service, nullptr);
  const DatasetKey a = service->AddDataset(scene_a->tree.get(), scene_a->spec.spacing);
  const DatasetKey b = service->AddDataset(scene_b->tree.get(), scene_b->spec.spacing);
  // A refinement of A with one brick per pass: many passes, in flight when A is removed.
  std::atomic<bool> removed = false;
  std::atomic<int> after_remove = 0;
  std::promise<void> first_pass;
  std::atomic<bool> first = true;
  const ViewId view_a = OpenView(*service, a, [&](FrameResult) {
    if (removed) ++after_remove;
    if (first.exchange(false)) first_pass.set_value();
  });
  FrameOptions slow = Refine();
  slow.upload.max_bricks = 1;
  ASSERT_TRUE(
      service->Submit(view_a, VolumeRequest(Standard(*scene_a, StandardView::kZ, 48, 48), slow, 1))
          .ok());
  ASSERT_EQ(first_pass.get_future().wait_for(kTimeout), std::future_status::ready);
  service->RemoveDataset(a);
  removed = true;
  EXPECT_EQ(service->Submit(view_a, VolumeRequest(camera_b, FullFrame(), 2)).code(),
            StatusCode::kNotFound);
  EXPECT_EQ(service->OpenView(a, [](FrameResult) {}).status().code(), StatusCode::kNotFound);
  service->RemoveDataset(a);  // Again: ignored.
  // A's octree, page cache and store may go now; B renders on.
  scene_a.reset();
  FrameSink sink;
  const ViewId view_b = OpenView(*service, b, sink.Callback());
  ASSERT_TRUE(service->Submit(view_b, VolumeRequest(camera_b, Refine(), 1)).ok());
  std::optional<FrameResult> final = sink.WaitFinal(1);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_TRUE(Identical(final->image, expected_b));
  EXPECT_EQ(after_remove, 0);
  EXPECT_TRUE(Eventually([&] { return service->stats().mirrors == 1; }));
}

TEST(RenderServiceTest, FrameMemoryIsAdmittedBeforeItIsAllocated) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  const RenderParams dvr = DefaultRenderParams(1, volume::DataType::kUint16, RenderMode::kDvr);
  const Camera small = Standard(*scene, StandardView::kZ, 32, 32);
  const uint64_t small_bytes =
      TotalBytes(VolumeRenderer::BufferSizes(FrameMode::kRefine, dvr, 32, 32));
  {
    // Default limits: a 16384^2 refinement (about 9 GiB of ray state) is refused without touching
    // the device; the service goes on.
    Served service = MakeService(*scene);
    ASSERT_NE(service.service, nullptr);
    FrameSink sink;
    const ViewId view = service.Open(sink.Callback());
    const Camera huge = Standard(*scene, StandardView::kZ, kMaxImageSize, kMaxImageSize);
    ASSERT_TRUE(service->Submit(view, VolumeRequest(huge, Refine(), 1, dvr)).ok());
    std::optional<FrameResult> refused = sink.WaitFinal(1);
    ASSERT_TRUE(refused.has_value());
    EXPECT_EQ(refused->status.code(), StatusCode::kResourceExhausted) << refused->status.ToString();
    EXPECT_TRUE(refused->image.rgba.empty());
    EXPECT_EQ(service->stats().refused, 1u);
    EXPECT_EQ(service->stats().frame_memory_bytes, 0u);
    EXPECT_EQ(service->stats().passes, 0u);
    ASSERT_TRUE(service->Submit(view, VolumeRequest(small, Refine(), 2, dvr)).ok());
    std::optional<FrameResult> fine = sink.WaitFinal(2);
    ASSERT_TRUE(fine.has_value());
    EXPECT_TRUE(fine->status.ok()) << fine->status.ToString();
  }
  // Frame memory for one 32^2 DVR refinement at a time. A's refinement (one brick per pass) holds
  // it; B's request, submitted from A's first progress callback, waits until A finished.
  RenderServiceOptions options;
  options.frame_memory_bytes = small_bytes + small_bytes / 2;
  options.max_request_bytes = small_bytes;
  Served service = MakeService(*scene, options);
  ASSERT_NE(service.service, nullptr);
  std::mutex mu;
  std::vector<std::pair<char, bool>> order;  // (view, final)
  FrameSink sink_a, sink_b;
  ViewId view_b = 0;
  std::atomic<bool> submitted = false;
  FrameOptions slow = Refine();
  slow.upload.max_bricks = 1;
  const ViewId view_a = service.Open([&](FrameResult result) {
    {
      std::lock_guard lock(mu);
      order.emplace_back('A', result.final);
    }
    if (!submitted.exchange(true)) {
      EXPECT_TRUE(service->Submit(view_b, VolumeRequest(small, Refine(), 1, dvr)).ok());
    }
    sink_a.Add(std::move(result));
  });
  view_b = service.Open([&](FrameResult result) {
    {
      std::lock_guard lock(mu);
      order.emplace_back('B', result.final);
    }
    sink_b.Add(std::move(result));
  });
  ASSERT_TRUE(service->Submit(view_a, VolumeRequest(small, slow, 1, dvr)).ok());
  std::optional<FrameResult> final_a = sink_a.WaitFinal(1);
  std::optional<FrameResult> final_b = sink_b.WaitFinal(1);
  ASSERT_TRUE(final_a.has_value() && final_b.has_value());
  EXPECT_TRUE(final_a->status.ok()) << final_a->status.ToString();
  EXPECT_TRUE(final_b->status.ok()) << final_b->status.ToString();
  EXPECT_TRUE(Identical(final_a->image, final_b->image));
  EXPECT_GT(final_a->stats.passes, 2);
  // B's first result came after A's last.
  const auto a_final = std::find(order.begin(), order.end(), std::make_pair('A', true));
  const auto b_first =
      std::find_if(order.begin(), order.end(), [](const auto& e) { return e.first == 'B'; });
  EXPECT_LT(a_final - order.begin(), b_first - order.begin());
  RenderServiceStats stats = service->stats();
  EXPECT_GE(stats.admission_waits, 1u);
  EXPECT_EQ(stats.refused, 0u);
  EXPECT_LE(stats.frame_memory_bytes, options.frame_memory_bytes);
  // A request larger than max_request_bytes is refused at once.
  const Camera larger = Standard(*scene, StandardView::kZ, 64, 64);
  ASSERT_TRUE(service->Submit(view_a, VolumeRequest(larger, Refine(), 2, dvr)).ok());
  std::optional<FrameResult> refused = sink_a.WaitFinal(2);
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->status.code(), StatusCode::kResourceExhausted);
  // Without patience (admission_timeout 0) a request that must wait is refused instead.
  options.admission_timeout = 0ms;
  Served impatient = MakeService(*scene, options);
  ASSERT_NE(impatient.service, nullptr);
  FrameSink sink_c, sink_d;
  ViewId view_d = 0;
  std::atomic<bool> d_submitted = false;
  const ViewId view_c = impatient.Open([&](FrameResult result) {
    if (!d_submitted.exchange(true)) {
      EXPECT_TRUE(impatient->Submit(view_d, VolumeRequest(small, Refine(), 1, dvr)).ok());
    }
    sink_c.Add(std::move(result));
  });
  view_d = impatient.Open(sink_d.Callback());
  ASSERT_TRUE(impatient->Submit(view_c, VolumeRequest(small, slow, 1, dvr)).ok());
  std::optional<FrameResult> final_d = sink_d.WaitFinal(1);
  ASSERT_TRUE(final_d.has_value());
  EXPECT_EQ(final_d->status.code(), StatusCode::kResourceExhausted) << final_d->status.ToString();
  std::optional<FrameResult> final_c = sink_c.WaitFinal(1);
  ASSERT_TRUE(final_c.has_value());
  EXPECT_TRUE(final_c->status.ok());
}

TEST(RenderServiceTest, AViewReusesItsFrameBuffers) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  auto scene = Scene(NoiseSpec({32, 32, 24}));
  ASSERT_NE(scene, nullptr);
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  FrameSink sink;
  const ViewId view = service.Open(sink.Callback());
  const auto frame = [&](int side, FrameOptions options, uint64_t seq) {
    const Camera camera = Standard(*scene, StandardView::kZ, side, side);
    EXPECT_TRUE(service->Submit(view, VolumeRequest(camera, options, seq)).ok());
    std::optional<FrameResult> result = sink.WaitFinal(seq);
    EXPECT_TRUE(result.has_value() && result->status.ok());
    return service->stats().frame_buffer_allocations;
  };
  const uint64_t first = frame(32, FullFrame(), 1);
  EXPECT_GT(first, 0u);
  // The same size, or a little smaller, again and again: no allocation.
  for (uint64_t seq = 2; seq <= 10; ++seq)
    EXPECT_EQ(frame(seq % 2 ? 28 : 32, FullFrame(), seq), first);
  // A refinement adds its ray state once; the next refinements and full frames reuse it all.
  const uint64_t refined = frame(32, Refine(), 11);
  EXPECT_GT(refined, first);
  EXPECT_EQ(frame(32, Refine(), 12), refined);
  EXPECT_EQ(frame(32, FullFrame(), 13), refined);
  const RenderParams mip = Mip();
  EXPECT_EQ(service->stats().frame_memory_bytes,
            TotalBytes(VolumeRenderer::BufferSizes(FrameMode::kRefine, mip, 32, 32)));
}

// A scene whose octree reads its bricks through a small page cache over a slow store that can
// fail reads: the octree is built in RAM, saved and loaded again over `cache`.
struct PagedScene {
  std::unique_ptr<RenderScene> built;  // The octree as built (a RAM cache over `store`).
  std::unique_ptr<paging::FaultInjectingPageStore> faulty;
  std::unique_ptr<paging::PageCache> cache;
  std::unique_ptr<octree::Octree> tree;  // Loaded over `cache`.
  std::mutex mu;
  std::set<std::thread::id> reader_threads;  // Threads that read the store.
};

std::unique_ptr<PagedScene> MakePagedScene(SceneSpec spec, uint64_t cache_pages) {
  auto paged = std::make_unique<PagedScene>();
  spec.page_bytes = 2 * spec.brick[0] * spec.brick[1] * spec.brick[2] * 2;  // Two bricks a page.
  paged->built = Scene(spec);
  if (paged->built == nullptr) return nullptr;
  EXPECT_TRUE(paged->built->tree->Flush().ok());
  std::stringstream saved;
  EXPECT_TRUE(paged->built->tree->Save(saved).ok());
  paged->faulty = std::make_unique<paging::FaultInjectingPageStore>(paged->built->store.get());
  PagedScene* raw = paged.get();
  paged->faulty->SetBeforeRead([raw](uint64_t) {
    {
      std::lock_guard lock(raw->mu);
      raw->reader_threads.insert(std::this_thread::get_id());
    }
    std::this_thread::sleep_for(2ms);  // A slow disk.
  });
  paged->cache =
      std::make_unique<paging::PageCache>(paged->faulty.get(), cache_pages * spec.page_bytes);
  auto tree = octree::Octree::Load(saved, paged->cache.get());
  EXPECT_TRUE(tree.ok()) << tree.status().ToString();
  if (!tree.ok()) return nullptr;
  paged->tree = std::move(*tree);
  return paged;
}

TEST(RenderServiceTest, NeverWaitsForTheDiskAndStillEqualsTheReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // 64 x 64 x 32 voxels of noise in 16^3 bricks (37 bricks on 19 pages); the page cache holds 6
  // pages, each read takes 2 ms.
  auto paged = MakePagedScene(NoiseSpec({64, 64, 32}), 6);
  ASSERT_NE(paged, nullptr);
  RenderScene& built = *paged->built;
  const Camera camera = Standard(built, StandardView::kZ, 64, 64);
  const Camera side = Standard(built, StandardView::kX, 32, 64);
  const RenderImage expected = DirectVolume(built, camera, Mip(), Refine());
  const RenderImage expected_side = DirectVolume(built, side, Mip(), Refine());
  EXPECT_LE(CompareImages(expected, Reference(built, camera, Mip())).max_abs, kReferenceTolerance);
  ASSERT_TRUE(paged->cache->SetBudget(6 * built.spec.page_bytes).ok());

  RenderServiceOptions options;
  options.mirror_idle_timeout = 0ms;  // The mirror goes with the last view (see the end).
  auto service = MakeBareService(options);
  ASSERT_NE(service, nullptr);
  const DatasetKey dataset = service->AddDataset(paged->tree.get(), built.spec.spacing);
  std::atomic<std::thread::id> render_thread{};
  FrameSink sink, sink_side;
  const auto recorded = [&](FrameSink& target) {
    return [&](FrameResult result) {
      render_thread = std::this_thread::get_id();
      target.Add(std::move(result));
    };
  };
  const ViewId view = OpenView(*service, dataset, recorded(sink));
  const ViewId view_side = OpenView(*service, dataset, recorded(sink_side));
  // A full frame never waits: nothing is in RAM yet, it shows the nodes' averages at once.
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera, FullFrame(), 1)).ok());
  std::optional<FrameResult> full = sink.WaitFinal(1);
  ASSERT_TRUE(full.has_value() && full->status.ok());
  EXPECT_GT(full->stats.bricks_unavailable, 0u);
  // Two refinements side by side complete through the prefetcher and equal the reference.
  ASSERT_TRUE(service->Submit(view, VolumeRequest(camera, Refine(), 2)).ok());
  ASSERT_TRUE(service->Submit(view_side, VolumeRequest(side, Refine(), 1)).ok());
  std::optional<FrameResult> refined = sink.WaitFinal(2);
  std::optional<FrameResult> refined_side = sink_side.WaitFinal(1);
  ASSERT_TRUE(refined.has_value() && refined_side.has_value());
  ASSERT_TRUE(refined->status.ok()) << refined->status.ToString();
  ASSERT_TRUE(refined_side->status.ok()) << refined_side->status.ToString();
  EXPECT_TRUE(Identical(refined->image, expected));
  EXPECT_TRUE(Identical(refined_side->image, expected_side));
  EXPECT_LE(CompareImages(refined->image, Reference(built, camera, Mip())).max_abs,
            kReferenceTolerance);
  // The render thread never read the store (every read ran on an I/O thread), and it slept while
  // the refinements waited for their pages.
  const RenderServiceStats stats = service->stats();
  EXPECT_GT(stats.pages_requested, 0u);
  EXPECT_GT(stats.io_waits, 0u);
  EXPECT_GT(paged->faulty->reads(), 0u);
  {
    std::lock_guard lock(paged->mu);
    EXPECT_FALSE(paged->reader_threads.empty());
    EXPECT_EQ(paged->reader_threads.count(render_thread.load()), 0u);
  }
  EXPECT_LE(paged->cache->stats().peak_resident_bytes, 6 * built.spec.page_bytes);

  // A page that cannot be read: the refinement that needs it ends with the read error (no
  // hang), and the service goes on. Nothing on the device (the views close, the mirror goes)
  // and nothing in RAM any more.
  service->CloseView(view);
  service->CloseView(view_side);
  ASSERT_TRUE(Eventually([&] { return service->stats().mirrors == 0; }));
  FrameSink sink_again;
  const ViewId again = OpenView(*service, dataset, recorded(sink_again));
  ASSERT_TRUE(paged->cache->SetBudget(0).ok());
  ASSERT_TRUE(paged->cache->SetBudget(6 * built.spec.page_bytes).ok());
  std::vector<std::byte> raw(paged->tree->geometry().brick_bytes());
  uint64_t bad_page = 0;
  ASSERT_EQ(paged->tree->TryReadBrick(0, raw, &bad_page).code(), StatusCode::kUnavailable);
  paged->faulty->FailReadsOfPage(bad_page);  // The root brick's page: every view needs it.
  ASSERT_TRUE(service->Submit(again, VolumeRequest(camera, Refine(), 3)).ok());
  std::optional<FrameResult> failed = sink_again.WaitFinal(3);
  ASSERT_TRUE(failed.has_value());
  EXPECT_EQ(failed->status.code(), StatusCode::kIoError) << failed->status.ToString();
  EXPECT_NE(failed->status.message().find("page " + std::to_string(bad_page)), std::string::npos)
      << failed->status.ToString();
  EXPECT_GE(service->stats().page_errors, 1u);
  // Full frames keep showing what they can.
  ASSERT_TRUE(service->Submit(again, VolumeRequest(camera, FullFrame(), 4)).ok());
  std::optional<FrameResult> still = sink_again.WaitFinal(4);
  ASSERT_TRUE(still.has_value());
  EXPECT_TRUE(still->status.ok()) << still->status.ToString();
  std::lock_guard lock(paged->mu);
  EXPECT_EQ(paged->reader_threads.count(render_thread.load()), 0u);
}

// --- Scheduling: each test fails when its rule is broken. ---

TEST(RenderServiceTest, ContinuousFullFramesDoNotStarveARefinement) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // F sends full frames without pause (each callback submits the next); R refines another part
  // of the volume, one brick per pass. Full frames alone would keep the device busy forever.
  auto scene = Scene(NoiseSpec({64, 32, 32}));
  ASSERT_NE(scene, nullptr);
  const Camera f_camera = ZView(0, 0, 32), r_camera = ZView(32, 0, 32);
  const RenderImage expected = DirectVolume(*scene, r_camera, Mip(), Refine());
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  constexpr int kMaxFullFrames = 3000;  // F stops after these: R must be done long before.
  // Every callback, in order (they run on the render thread): 'F' full frame, 'r' refinement
  // pass, 'R' the last one; with the render-thread time charged for it (FrameResult::scheduled_ms).
  std::mutex mu;
  std::string order;
  std::vector<double> order_ms;
  std::atomic<int> f_frames = 0;
  std::atomic<bool> stop = false;
  ViewId f_view = 0;
  std::promise<void> f_busy;
  f_view = service.Open([&](FrameResult result) {
    const int n = ++f_frames;
    {
      std::lock_guard lock(mu);
      order.push_back('F');
      order_ms.push_back(result.scheduled_ms);
    }
    if (n == 3) f_busy.set_value();
    if (n < kMaxFullFrames && !stop) {
      EXPECT_TRUE(
          service->Submit(f_view, VolumeRequest(f_camera, FullFrame(), result.sequence + 1)).ok());
    }
  });
  FrameSink r_sink;
  std::atomic<int> f_at_final = 0;
  const ViewId r_view = service.Open([&](FrameResult result) {
    {
      std::lock_guard lock(mu);
      order.push_back(result.final ? 'R' : 'r');
      order_ms.push_back(result.scheduled_ms);
    }
    if (result.final) f_at_final = f_frames.load();
    r_sink.Add(std::move(result));
  });
  const ViewsClosedAtExit closed_at_exit(*service.service, {f_view, r_view});
  ASSERT_TRUE(service->Submit(f_view, VolumeRequest(f_camera, FullFrame(), 1)).ok());
  ASSERT_EQ(f_busy.get_future().wait_for(kTimeout), std::future_status::ready);
  FrameOptions slow = Refine();
  slow.upload.max_bricks = 1;
  size_t submitted_at = 0;
  {
    std::lock_guard lock(mu);
    submitted_at = order.size();
  }
  ASSERT_TRUE(service->Submit(r_view, VolumeRequest(r_camera, slow, 1)).ok());
  std::optional<FrameResult> final = r_sink.WaitFinal(1);
  stop = true;
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
  EXPECT_TRUE(Identical(final->image, expected));
  // R finished while F was still sending.
  EXPECT_LT(f_at_final.load(), kMaxFullFrames);
  std::string during;
  double full_ms = 0, max_full_ms = 0;
  {
    std::lock_guard lock(mu);
    const size_t end = order.find('R', submitted_at);
    ASSERT_NE(end, std::string::npos);
    during = order.substr(submitted_at, end + 1 - submitted_at);
    for (size_t i = submitted_at; i < end; ++i) {
      if (order[i] != 'F') continue;
      full_ms += order_ms[i];
      max_full_ms = std::max(max_full_ms, order_ms[i]);
    }
  }
  SCOPED_TRACE("events after R's submit: " + during);
  const int r_passes = final->stats.passes;
  const double refine_ms = final->scheduled_ms;
  EXPECT_GT(r_passes, 3);
  // Interaction keeps its priority: never two refinement passes in a row while F waits.
  EXPECT_EQ(during.find("rr"), std::string::npos);
  EXPECT_EQ(during.find("rR"), std::string::npos);
  // And the refinement gets its share (0.25): F's time meanwhile is about (1 - 0.25) / 0.25 = 3
  // times R's, plus at most a full frame per refinement pass (a pass is never split).
  std::printf("[ info     ] during R: %d full frames (%.1f ms), %d refinement passes (%.1f ms)\n",
              static_cast<int>(std::count(during.begin(), during.end(), 'F')), full_ms, r_passes,
              refine_ms);
  EXPECT_LE(full_ms, 4 * refine_ms + (r_passes + 2) * max_full_ms);
}

TEST(RenderServiceTest, FullFramesOfSeveralViewsShareTheDeviceEvenly) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // Three views send full frames without pause; their frames cost very different amounts (16^2,
  // 48^2 and 96^2 pixels). Deficit round robin on measured time keeps the time each view was
  // charged within two quanta and two passes of the others' (a view may run a pass beyond its
  // credit, and the first view starts a round before the others are busy), however long the
  // passes took on a loaded machine; a frame-by-frame round robin would give the 96^2 view most
  // of the device (seconds apart after 600 frames).
  auto scene = Scene(NoiseSpec({48, 48, 48}));
  ASSERT_NE(scene, nullptr);
  RenderServiceOptions options;
  options.quantum_ms = 5;
  Served service = MakeService(*scene, options);
  ASSERT_NE(service.service, nullptr);
  // The device mirror and the kernel exist before the views start (their creation is charged to
  // the view that needs them first).
  {
    FrameSink warm;
    const ViewId warm_view = service.Open(warm.Callback());
    const Camera all = Standard(*scene, StandardView::kIso, 96, 96);
    ASSERT_TRUE(service->Submit(warm_view, VolumeRequest(all, FullFrame(), 1)).ok());
    ASSERT_TRUE(warm.WaitFinal(1).has_value());
    service->CloseView(warm_view);
  }
  constexpr int kViews = 3;
  const int sides[kViews] = {16, 48, 96};
  std::atomic<bool> stop = false;
  std::mutex mu;
  double ms[kViews] = {0, 0, 0};         // Render time (FrameStats::ms_total).
  double scheduled[kViews] = {0, 0, 0};  // What the scheduler charged (FrameResult::scheduled_ms).
  double max_pass = 0;                   // The longest charge of one frame.
  int frames[kViews] = {0, 0, 0};
  std::atomic<int> total = 0;
  std::vector<ViewId> views(kViews);
  std::promise<void> done;
  for (int v = 0; v < kViews; ++v) {
    const Camera camera = Standard(*scene, StandardView::kIso, sides[v], sides[v]);
    views[v] = service.Open([&, v, camera](FrameResult result) {
      if (stop) return;
      {
        std::lock_guard lock(mu);
        ++frames[v];
        ms[v] += result.stats.ms_total;
        scheduled[v] += result.scheduled_ms;
        max_pass = std::max(max_pass, result.scheduled_ms);
      }
      if (++total == 600) {
        stop = true;
        done.set_value();
        return;
      }
      EXPECT_TRUE(
          service->Submit(views[v], VolumeRequest(camera, FullFrame(), result.sequence + 1)).ok());
    });
  }
  const ViewsClosedAtExit closed_at_exit(*service.service, views);
  for (int v = 0; v < kViews; ++v) {
    const Camera camera = Standard(*scene, StandardView::kIso, sides[v], sides[v]);
    ASSERT_TRUE(service->Submit(views[v], VolumeRequest(camera, FullFrame(), 1)).ok());
  }
  ASSERT_EQ(done.get_future().wait_for(kTimeout), std::future_status::ready);
  std::lock_guard lock(mu);
  const double sum = scheduled[0] + scheduled[1] + scheduled[2];
  const double bound = 2 * (options.quantum_ms + max_pass);
  std::printf("[ info     ] longest frame %.1f ms: charges may differ by %.1f ms\n", max_pass,
              bound);
  for (int v = 0; v < kViews; ++v) {
    std::printf("[ info     ] view %dx%d: %d frames, render %.1f ms, charged %.1f ms (%.0f %%)\n",
                sides[v], sides[v], frames[v], ms[v], scheduled[v], 100 * scheduled[v] / sum);
    EXPECT_GE(scheduled[v], ms[v]) << "view " << v;  // A charge covers the frame's render time.
    for (int w = 0; w < v; ++w) {
      EXPECT_LE(std::abs(scheduled[v] - scheduled[w]), bound) << "views " << w << ", " << v;
    }
  }
  EXPECT_GT(frames[0], frames[2]);  // The cheap view got more frames for the same time.
}

TEST(RenderServiceTest, AHugeRefinementDelaysAFullFrameByAtMostOnePass) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  // H refines a large image (each pass costs many small full frames); F, a client, sends a full
  // frame, waits for it, pauses briefly, and so on. Between F's submit and F's frame at most one
  // of H's passes may run (the one in flight when F submitted).
  auto scene = Scene(NoiseSpec({64, 64, 32}));
  ASSERT_NE(scene, nullptr);
  const Camera h_camera = Standard(*scene, StandardView::kZ, 256, 256);
  const Camera f_camera = ZView(0, 0, 16);
  Served service = MakeService(*scene);
  ASSERT_NE(service.service, nullptr);
  std::atomic<int> h_passes = 0;
  FrameSink h_sink, f_sink;
  const ViewId h = service.Open([&](FrameResult result) {
    ++h_passes;
    h_sink.Add(std::move(result));
  });
  // H's pass count when F's frame is delivered (on the render thread: exact, whenever this test
  // thread gets to run).
  std::atomic<int> passes_at_f_frame = 0;
  const ViewId f = service.Open([&, sink = f_sink.Callback()](FrameResult result) {
    passes_at_f_frame = h_passes.load();
    sink(std::move(result));
  });
  FrameOptions slow = Refine();
  slow.upload.max_bricks = 2;
  ASSERT_TRUE(service->Submit(h, VolumeRequest(h_camera, slow, 1)).ok());
  int worst = 0;
  int frames = 0;
  for (uint64_t seq = 1; seq <= 40; ++seq) {
    // Counted from just after the submit: a loaded machine may deschedule this thread between
    // reading the count and submitting, while H's passes (rightly) go on.
    ASSERT_TRUE(service->Submit(f, VolumeRequest(f_camera, FullFrame(), seq)).ok());
    const int before = h_passes;
    std::optional<FrameResult> frame = f_sink.WaitFinal(seq);
    ASSERT_TRUE(frame.has_value() && frame->status.ok());
    worst = std::max(worst, passes_at_f_frame - before);
    ++frames;
    if (h_sink.WaitFinalFor(1, 0ms)) break;  // H is done: nothing left to compete with.
    std::this_thread::sleep_for(std::chrono::milliseconds(seq % 4));
  }
  std::printf("[ info     ] %d full frames, %d refinement passes, worst delay %d passes\n", frames,
              h_passes.load(), worst);
  // One pass may be in flight when F submits; a second may be counted when a pass that ended
  // just before the submit is delivered just after it (the count follows callbacks, not kernel
  // ends). More means the scheduler let refinement run ahead of a waiting full frame.
  EXPECT_LE(worst, 2);
  EXPECT_GE(frames, 5);
  std::optional<FrameResult> final = h_sink.WaitFinal(1);
  ASSERT_TRUE(final.has_value());
  ASSERT_TRUE(final->status.ok()) << final->status.ToString();
}

}  // namespace
}  // namespace octoscope::render
