// RenderService: frame jobs of many views rendered against ONE octree on ONE OpenCL device by ONE
// render thread (docs/render_service.md). It is what `octoscope serve` puts its sessions on: each
// browser view (a 3-D view or a slice view of some session) is a View; every state change the
// client sends becomes a FrameRequest (a snapshot of camera, parameters and options), and the
// service answers with FrameResults through the view's callback.
//
// One render thread per device: Create starts a thread that creates and exclusively owns the
// device objects — the ProgramCache (unless a shared one is passed), the DeviceOctree, the
// VolumeRenderer and the SliceRenderer (both on the one DeviceOctree) — and is the only thread that
// enqueues work on the device queue through them. No other thread ever touches them; other threads
// only hand requests over (Submit) and receive results (callbacks, which run ON the render thread).
//
// Latest state wins: a view has ONE pending slot. Submit replaces the pending request (the old one
// is dropped without a callback) and bumps the view's atomic generation; the view's in-flight job
// (a refinement, several passes long) sees the new generation at its next pass boundary and is
// dropped without a callback. A pass that already started finishes and its image is delivered
// (a stale but complete image is better than none while the user keeps interacting).
// Cancelled or replaced requests therefore produce NO callback; every request that is not
// cancelled ends in exactly one callback with final == true (an image, or an error status).
//
// Scheduling (render thread, one step at a time):
//  1. a refinement whose last pass made no progress runs its next pass at once (see pinning);
//  2. pending FULL-FRAME requests (interaction), round robin over views: one pass each;
//  3. refinements, round robin over views: a pending refine request starts a new job (replacing
//     that view's job); otherwise the view's job advances ONE pass. A long refinement thus never
//     delays a full frame of another view by more than one pass.
// After every refinement pass the callback receives a progress image (final == false) unless
// the request asked for the final image only.
//
// Pinning ("bricks in use by an in-flight frame stay pinned"): a pass is Sync + kernel +
// feedback read-back + Upload, all on the render thread, and every eviction happens inside
// DeviceOctree::Upload. So no brick can be evicted while a kernel that samples it runs: the only
// thread that could evict is the one waiting for that kernel. Within a pass, Upload protects the
// bricks the pass sampled (UploadBudget::protect_frame) and the bricks it uploads itself.
// Between passes of different jobs nothing is pinned — a paused refinement ray holds no brick
// (its state is a sample index and an accumulated colour), and the next pass re-requests what it
// needs. Progress with a brick buffer too small for all views together: a pass that advanced no
// ray (no new sample, no newly finished ray) is re-run immediately, before any other job's
// upload can evict what it just uploaded, and the renderer guarantees that such a pass advances.
//
// Construction may be inserting into the octree concurrently: every pass starts with Sync (in
// the renderer), so each frame shows the tree as it was at its start and later frames fill in.
//
// Thread safety: OpenView, CloseView, Submit and stats are thread-safe and may be called from any
// thread, including from a callback. Submit never waits for rendering: it takes one small mutex
// (the request is moved into place outside it) and notifies the render thread. CloseView waits
// only for a callback of that view that is running at that moment (unless called from it).
// Callbacks run on the render thread, one at a time: they must be quick (copy or move the image
// and hand it to another thread; encode elsewhere) and must not destroy the service. An
// exception thrown by a callback is caught on the render thread, recorded in stats(), and its
// view is closed; exceptions never cross threads.
#ifndef OCTOSCOPE_RENDER_RENDER_SERVICE_H_
#define OCTOSCOPE_RENDER_RENDER_SERVICE_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "octree/octree.h"
#include "render/camera.h"
#include "render/device.h"
#include "render/device_octree.h"
#include "render/linear_algebra.h"
#include "render/program_cache.h"
#include "render/render_image.h"
#include "render/render_params.h"
#include "render/slice_renderer.h"
#include "render/volume_renderer.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::render {

using ViewId = uint64_t;  // 1, 2, ...; never 0.

enum class FrameKind { kVolume, kSlice };

// A snapshot of everything one frame of a view needs. Owned by the service once submitted.
struct FrameRequest {
  FrameKind kind = FrameKind::kVolume;
  // kVolume: the camera (required; Camera has no default value).
  std::optional<Camera> camera;
  // kSlice: the slice (required).
  std::optional<SliceView> slice;
  RenderParams params;
  // Mode (full frame or refinement), LOD bias, upload budget, max passes; nullopt = the
  // service's RenderServiceOptions::default_frame. Slices: a full frame is one slice frame; a
  // refinement repeats slice frames (one per pass, with progress images) until a frame requests
  // no brick (final, stats.final true) or max_passes (0 = kDefaultSliceMaxPasses) ran.
  std::optional<FrameOptions> options;
  // The caller's number for this state, echoed in its FrameResults.
  uint64_t sequence = 0;
  // Refinement: deliver the image after every pass (true) or only the final one.
  bool progress_images = true;
};

// Slice refinements without max_passes stop after this many frames (a slice whose bricks do not
// all fit in the brick buffer never stops requesting).
inline constexpr int kDefaultSliceMaxPasses = 32;

// What a view's callback receives.
struct FrameResult {
  ViewId view = 0;
  uint64_t sequence = 0;
  FrameKind kind = FrameKind::kVolume;
  RenderImage image;  // Empty when !status.ok().
  // Of this request so far (all passes). Slices: ms_total, passes, samples, requests,
  // bricks_uploaded, final (the last frame requested nothing); finished_fraction 1.
  FrameStats stats;
  // The last result for this request: a full frame, the last refinement pass (complete or
  // max_passes reached), or an error.
  bool final = false;
  Status status;
};

// Runs on the render thread; see the thread-safety note in the file comment.
using FrameCallback = std::function<void(FrameResult result)>;

struct RenderServiceOptions {
  DeviceOctreeOptions device_octree;
  FrameOptions default_frame;  // For requests without options.
  // Extra build options of the slice kernels (SliceRenderer::Create).
  std::string slice_build_options;
};

// Counters since Create (a consistent snapshot).
struct RenderServiceStats {
  uint64_t requests = 0;          // Accepted Submits.
  uint64_t replaced = 0;          // Pending requests replaced by a newer Submit before starting.
  uint64_t cancelled = 0;         // Started jobs dropped at a pass boundary (newer state/close).
  uint64_t passes = 0;            // Kernel passes run (full frames and refinement passes).
  uint64_t stall_retries = 0;     // Refinement passes re-run at once after a pass without progress.
  uint64_t frames_delivered = 0;  // Callbacks made with final == true (counted before the call).
  uint64_t progress_delivered = 0;  // Callbacks made with final == false.
  uint64_t callback_failures = 0;   // Callbacks that threw (their views were closed).
  std::string last_callback_error;  // what() of the last one.
};

class RenderService {
 public:
  // Takes `context` (the device). `octree` must outlive the service; `spacing_um` is the
  // volume's voxel pitch. Starts the render thread and returns once it created the device
  // objects, or with their error (the thread is then gone).
  static Result<std::unique_ptr<RenderService>> Create(ComputeContext context,
                                                       octree::Octree* octree,
                                                       const Vec3& spacing_um,
                                                       const RenderServiceOptions& options = {});
  // The same on a context and ProgramCache owned elsewhere (tests share one per binary), which
  // must outlive the service. Nothing else should enqueue on the context's queue meanwhile.
  static Result<std::unique_ptr<RenderService>> CreateShared(
      const ComputeContext* context, ProgramCache* programs, octree::Octree* octree,
      const Vec3& spacing_um, const RenderServiceOptions& options = {});

  // Stops the render thread after its current pass (at most one pass; a callback running then
  // completes), drops pending requests and jobs without callbacks, joins. Never throws.
  // REQUIRES: not called from a callback.
  ~RenderService();
  RenderService(const RenderService&) = delete;
  RenderService& operator=(const RenderService&) = delete;

  // A new view whose results go to `callback` (not empty).
  ViewId OpenView(FrameCallback callback);
  // Drops the view's pending request and job; once CloseView returns, the view's callback is
  // never called again (it waits for a callback of this view running on the render thread).
  // Unknown or already closed views are ignored.
  void CloseView(ViewId view);
  // Makes `request` the view's pending state (see "Latest state wins"). kNotFound when the view
  // is not open (never opened, closed, or closed after its callback threw); kInvalidArgument
  // for a request that cannot be rendered at all (volume frame without camera, slice frame
  // without slice).
  // Parameter errors are reported through the callback (status, final == true).
  Status Submit(ViewId view, FrameRequest request);

  RenderServiceStats stats() const;
  const DeviceInfo& device() const { return context_->device(); }

 private:
  struct View {
    std::shared_ptr<FrameCallback> callback;
    std::unique_ptr<FrameRequest> pending;
    // Bumped by every Submit and by CloseView; a started job of an older generation is dropped
    // at its next pass boundary. Shared with the render thread's job.
    std::shared_ptr<std::atomic<uint64_t>> generation;
  };
  struct Job;      // Render-thread state of one started request (render_service.cpp).
  struct Devices;  // The render thread's device objects.
  struct Step;     // What the render thread does next.

  RenderService(const ComputeContext* context, ProgramCache* programs, octree::Octree* octree,
                const Vec3& spacing_um, const RenderServiceOptions& options);
  static Result<std::unique_ptr<RenderService>> Start(std::unique_ptr<RenderService> service);

  // The render thread: creates the device objects, reports `init` and loops over steps.
  void Run(std::function<void(Status)> init);
  // REQUIRES: mu_ held, on the render thread. Picks the next step; false when there is none.
  bool PickLocked(std::map<ViewId, std::unique_ptr<Job>>& jobs, Step* step);
  void Execute(Devices& devices, std::map<ViewId, std::unique_ptr<Job>>& jobs, Step& step);
  // Calls the view's callback unless the view was closed meanwhile.
  void Deliver(ViewId view, const std::shared_ptr<FrameCallback>& callback, FrameResult result);

  std::unique_ptr<ComputeContext> owned_context_;  // Create's context; null for CreateShared.
  const ComputeContext* context_;
  ProgramCache* shared_programs_;  // CreateShared's cache; null: the render thread makes one.
  octree::Octree* const octree_;
  const Vec3 spacing_;
  const RenderServiceOptions options_;

  mutable std::mutex mu_;                // Guards everything below.
  std::condition_variable work_cv_;      // Render thread: new work or stop.
  std::condition_variable callback_cv_;  // CloseView: a callback finished.
  bool stop_ = false;
  ViewId next_view_ = 1;
  std::map<ViewId, View> views_;
  ViewId full_frame_cursor_ = 0;  // Round robin: the last view served in step 2 / step 3.
  ViewId refine_cursor_ = 0;
  ViewId retry_view_ = 0;    // Step 1's view (0 = none).
  ViewId calling_view_ = 0;  // The view whose callback runs now (0 = none).
  RenderServiceStats stats_;

  std::thread thread_;  // Last: started after everything above exists.
  std::thread::id render_thread_id_;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_RENDER_SERVICE_H_
