// RenderService: ONE render thread per OpenCL device rendering the views of SEVERAL datasets
// (design, scheduling and memory rules: docs/render_service.md).
//
// Model: AddDataset registers an octree (possibly still being built); OpenView opens a view of
// one dataset with a callback; every state the client shows becomes a FrameRequest submitted to
// the view. A view has ONE pending slot: Submit replaces the pending request (dropped, no
// callback) and supersedes the view's started refinement (dropped at its next pass boundary, no
// callback). Renders never queue up.
//
// Results. Every request that is not replaced, superseded or closed ends in exactly ONE callback
// with final == true; a refinement's passes before it give progress callbacks (final == false)
// unless progress_images is false. A FrameResult carries the image (RenderImage: width x height
// RGBA floats), FrameStats (stats.ms_total: render ms so far) and the request's identifying
// fields: view, dataset, sequence and version (echoed), kind, mode (full frame = interactive
// tier, refine = refinement tier), stats.passes (passes so far), stats.finished_fraction
// (refinement progress, 0..1) and final.
//
// Errors. Submit answers at once only kNotFound (view not open), kInvalidArgument (no camera
// / no slice) and kInternal once the render thread itself failed (host memory exhausted outside
// a pass: the service then serves nothing more; never a terminate). Everything else ends that
// request through its callback: final == true, an empty image and status = kResourceExhausted
// (frame buffers over max_request_bytes, frame memory not free within admission_timeout, device
// allocation failed), kInvalidArgument (parameters invalid for the dataset), kIoError/kDataLoss (a
// brick page cannot be read; refinements only), or the device error; a device mirror (DeviceOctree
// + renderers) that cannot be created (bad_alloc, OpenCL failure) fails the requests that needed
// it, "device mirror" in the message. Nothing throws out of the render thread; the service keeps
// serving the other views.
//
// Callbacks run ON THE RENDER THREAD, one at a time, while no other view renders: they must
// return quickly (move the image into a slot and notify another thread; never encode, wait, or
// do I/O there). A callback may call Submit, OpenView and CloseView (of any view; closing its own
// does not wait) and RemoveDataset (does not wait then); it must not destroy the service. A
// callback that throws is caught, counted in stats() and its view closed.
//
// Thread safety: every public method is thread-safe. Submit never waits for rendering (one short
// mutex). CloseView returns once no callback of the view runs and none will; RemoveDataset also
// waits for the render thread to drop the dataset's device mirror (after its current pass) and for
// prefetches of its page cache. The render thread never blocks on disk: bricks not in RAM are
// skipped and their pages prefetched by I/O threads that wake it.
#ifndef OCTOSCOPE_RENDER_RENDER_SERVICE_H_
#define OCTOSCOPE_RENDER_RENDER_SERVICE_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "octree/octree.h"
#include "paging/page_prefetcher.h"
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

using ViewId = uint64_t;      // 1, 2, ...; never 0.
using DatasetKey = uint64_t;  // 1, 2, ...; never 0.

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
  // (options.view and options.upload.reserve_for are set by the service.)
  std::optional<FrameOptions> options;
  // The caller's numbers for this request and for the state version it shows, echoed in its
  // FrameResults (the service uses neither).
  uint64_t sequence = 0;
  uint64_t version = 0;
  // Refinement: deliver the image after every pass (true) or only the final one.
  bool progress_images = true;
};

// Slice refinements without max_passes stop after this many frames (a slice whose bricks do not
// all fit in the brick buffer never stops requesting).
inline constexpr int kDefaultSliceMaxPasses = 32;

// What a view's callback receives.
struct FrameResult {
  ViewId view = 0;
  DatasetKey dataset = 0;
  uint64_t sequence = 0;  // FrameRequest::sequence.
  uint64_t version = 0;   // FrameRequest::version.
  FrameKind kind = FrameKind::kVolume;
  FrameMode mode = FrameMode::kFullFrame;  // The request's (resolved) mode.
  RenderImage image;                       // Empty when !status.ok().
  // Of this request so far (all passes). Slices: ms_total, passes, samples, requests,
  // bricks_uploaded, final (the last frame requested nothing); finished_fraction 1.
  FrameStats stats;
  // Render-thread time this request was charged so far (what fair scheduling counts: its passes,
  // the service's work around them, callbacks excluded), up to this callback.
  double scheduled_ms = 0;
  // The last result for this request: a full frame, the last refinement pass (complete or
  // max_passes reached), or an error.
  bool final = false;
  // kResourceExhausted: the request needs more device memory than max_request_bytes, or waited
  // admission_timeout for frame memory; kIoError/kDataLoss...: a brick page could not be read;
  // kInvalidArgument: parameters invalid for the dataset; others: device errors.
  Status status;
};

// Runs on the render thread and must return quickly (see the file comment).
using FrameCallback = std::function<void(FrameResult result)>;

// A request of 4096^2 pixels (36 bytes per pixel for DVR, 20 + 4 per enabled channel for
// MIP/MinIP refinements) fits; 16384^2 (9 GiB and more) does not.
inline constexpr uint64_t kDefaultMaxRequestBytes = uint64_t{1} << 30;
// A mirror grows to a larger share only when the share exceeds its size by this factor.
inline constexpr double kMirrorGrowth = 1.25;

struct RenderServiceOptions {
  // Options of every dataset's DeviceOctree, except brick_buffer_bytes (each mirror gets its
  // share of device_memory_bytes) and brick_reads (always kResidentOnly).
  DeviceOctreeOptions device_octree;
  // Brick-buffer budget of the whole device, divided among the datasets with open views.
  // 0 = automatic: 40 % of the device's global memory (at most 1 GiB on CPU devices, whose
  // memory is the host RAM the page caches use too), at least 64 MiB.
  uint64_t device_memory_bytes = 0;
  // Device memory for the frame buffers of all views together. 0 = automatic: 25 % of the
  // device's global memory, at least max_request_bytes.
  uint64_t frame_memory_bytes = 0;
  // The most device memory one request's frame buffers may need (see kDefaultMaxRequestBytes).
  uint64_t max_request_bytes = kDefaultMaxRequestBytes;
  // How long an admissible request waits for frame memory held by other views.
  std::chrono::milliseconds admission_timeout{10'000};
  FrameOptions default_frame;  // For requests without options.
  // Extra build options of the slice kernels (SliceRenderer::Create).
  std::string slice_build_options;
  // Scheduling (docs/render_service.md): the share of render time refinements get while full
  // frames wait too, in (0, 1); and the deficit round robin quantum.
  double refine_share = 0.25;
  double quantum_ms = 10;
  // Volume refinements whose request sets no FrameOptions::pass_target_ms get this one: a pass
  // runs a slice of the unfinished tiles taking about this long, so a full frame waits at most
  // about this long for a refinement pass in flight, however large the refinement (a 4K
  // screenshot). 0 = every pass runs all unfinished tiles.
  double refine_pass_ms = 50;
  // A dataset's mirror is dropped this long after its last view closed.
  std::chrono::milliseconds mirror_idle_timeout{30'000};
  // Non-blocking brick reads: I/O threads of the service's prefetcher, and how long a refinement
  // waiting for pages waits before it tries again anyway.
  int io_threads = 2;
  std::chrono::milliseconds io_retry{250};
};

// Counters since Create (a consistent snapshot); *_bytes and mirrors are current values.
struct RenderServiceStats {
  uint64_t requests = 0;            // Accepted Submits.
  uint64_t replaced = 0;            // Pending requests replaced by a newer Submit before starting.
  uint64_t cancelled = 0;           // Started jobs dropped at a pass boundary (newer state/close).
  uint64_t passes = 0;              // Kernel passes run (full frames and refinement passes).
  uint64_t frames_delivered = 0;    // Callbacks made with final == true (counted before the call).
  uint64_t progress_delivered = 0;  // Callbacks made with final == false.
  uint64_t callback_failures = 0;   // Callbacks that threw (their views were closed).
  std::string last_callback_error;  // what() of the last one.
  uint64_t refused = 0;             // Requests ended with kResourceExhausted by admission.
  uint64_t admission_waits = 0;     // Requests that had to wait for frame memory.
  uint64_t frame_buffer_allocations = 0;  // Device buffers allocated for frames (all views).
  uint64_t io_waits = 0;                  // Refinement passes after which the job waited for pages.
  uint64_t pages_requested = 0;           // Prefetch requests accepted (kQueued).
  uint64_t page_errors = 0;               // Prefetch completions with a read error.
  uint64_t mirrors_created = 0;
  uint64_t mirrors_dropped = 0;
  uint64_t mirror_resizes = 0;
  uint64_t mirror_failures = 0;     // Mirrors that could not be created (requests failed).
  double full_frame_ms = 0;         // Render-thread time of full-frame passes.
  double refine_ms = 0;             // Render-thread time of refinement passes.
  uint64_t mirrors = 0;             // Mirrors now.
  uint64_t brick_memory_bytes = 0;  // Brick buffers of all mirrors now.
  uint64_t frame_memory_bytes = 0;  // Frame buffers of all views now.
};

class RenderService {
 public:
  // Takes `context` (the device). Starts the prefetcher and the render thread and returns once
  // the thread is running, or with the error that prevented it (nothing is left running).
  // Device objects of datasets are created later, on the render thread (errors reach the views).
  static Result<std::unique_ptr<RenderService>> Create(ComputeContext context,
                                                       const RenderServiceOptions& options = {});
  // The same on a context and ProgramCache owned elsewhere (tests share one per binary), which
  // must outlive the service. Nothing else should enqueue on the context's queue meanwhile.
  static Result<std::unique_ptr<RenderService>> CreateShared(
      const ComputeContext* context, ProgramCache* programs,
      const RenderServiceOptions& options = {});

  // Stops the render thread after its current pass (a callback running then completes), drops
  // pending requests and jobs without callbacks, the mirrors and the prefetches; joins. Never
  // throws. REQUIRES: not called from a callback.
  ~RenderService();
  RenderService(const RenderService&) = delete;
  RenderService& operator=(const RenderService&) = delete;

  // Adds a dataset: `octree` (and its page cache) must stay alive until RemoveDataset(key)
  // returned or the service is destroyed; `spacing_um` is its voxel pitch (finite, > 0).
  // Nothing is allocated on the device until a view of it renders.
  DatasetKey AddDataset(octree::Octree* octree, const Vec3& spacing_um);
  // Closes the dataset's views (no callback of them after this returns), makes the render thread
  // drop its mirror (after its current pass) and waits until no prefetch uses its page cache.
  // Unknown keys are ignored. From a callback it cannot wait: the views are closed at once and
  // the mirror is dropped right after the callback; the octree must then live until the
  // service is destroyed.
  void RemoveDataset(DatasetKey dataset);

  // A new view of `dataset` whose results go to `callback`. kNotFound for a dataset that is not
  // added (or removed); kInvalidArgument for an empty callback.
  Result<ViewId> OpenView(DatasetKey dataset, FrameCallback callback);
  // Drops the view's pending request and job; once CloseView returns, the view's callback is
  // never called again (it waits for a callback of this view running on the render thread).
  // Unknown or already closed views are ignored.
  void CloseView(ViewId view);
  // Makes `request` the view's pending state (replacing a pending one). kNotFound when the view
  // is not open (never opened, closed, its dataset removed, or closed after its callback threw);
  // kInvalidArgument for a request that cannot be rendered at all (volume frame without camera,
  // slice frame without slice). Parameter and memory errors are reported through the callback
  // (status, final == true).
  Status Submit(ViewId view, FrameRequest request);

  RenderServiceStats stats() const;
  const DeviceInfo& device() const { return context_->device(); }
  // The budgets in effect (automatic values resolved).
  uint64_t device_memory_bytes() const { return device_memory_bytes_; }
  uint64_t frame_memory_bytes() const { return frame_memory_bytes_; }

 private:
  struct View {
    DatasetKey dataset = 0;
    std::shared_ptr<FrameCallback> callback;
    std::unique_ptr<FrameRequest> pending;
    // Bumped by every Submit and by CloseView; a started job of an older generation is dropped
    // at its next pass boundary. Shared with the render thread's job.
    std::shared_ptr<std::atomic<uint64_t>> generation;
  };
  struct Dataset {
    octree::Octree* octree = nullptr;
    Vec3 spacing;
    int open_views = 0;
  };
  // Everything the render thread owns — mirrors, jobs, frame buffers, scheduling state — and
  // its steps (render_service.cpp). A nested type: it may use the members below.
  struct Worker;

  RenderService(const ComputeContext* context, ProgramCache* programs,
                const RenderServiceOptions& options);
  static Result<std::unique_ptr<RenderService>> Start(std::unique_ptr<RenderService> service);

  // The render thread: reports `init` (start-up errors included) and runs the Worker.
  void Run(std::function<void(Status)> init);
  // Calls the view's callback unless the view was closed meanwhile (render thread); returns the
  // milliseconds it took.
  double Deliver(ViewId view, const std::shared_ptr<FrameCallback>& callback, FrameResult result);
  // REQUIRES: mu_ held. Closes the view (its job is dropped at the next pass boundary) and
  // returns its pending request, to be destroyed outside the lock.
  std::unique_ptr<FrameRequest> EraseViewLocked(std::map<ViewId, View>::iterator it);
  // The prefetcher's completion callback (an I/O thread).
  void OnPrefetchComplete(const paging::PrefetchCompletion& completion);

  std::unique_ptr<ComputeContext> owned_context_;  // Create's context; null for CreateShared.
  const ComputeContext* context_;
  ProgramCache* shared_programs_;  // CreateShared's cache; null: the render thread makes one.
  const RenderServiceOptions options_;
  uint64_t device_memory_bytes_ = 0;
  uint64_t frame_memory_bytes_ = 0;

  mutable std::mutex mu_;                // Guards everything below up to stats_.
  std::condition_variable work_cv_;      // Render thread: new work, completions or stop.
  std::condition_variable callback_cv_;  // CloseView/RemoveDataset: a callback finished.
  std::condition_variable dropped_cv_;   // RemoveDataset: the render thread dropped a dataset.
  bool stop_ = false;
  Status failed_;  // Set when the render thread ended by an exception (see Run).
  ViewId next_view_ = 1;
  DatasetKey next_dataset_ = 1;
  std::map<ViewId, View> views_;
  std::map<DatasetKey, Dataset> datasets_;
  uint64_t datasets_version_ = 1;  // Bumped when datasets or their open-view counts change.
  std::vector<paging::PrefetchCompletion> completions_;  // From the I/O threads.
  std::vector<DatasetKey> drop_queue_;                   // Removed, mirror still to drop.
  std::set<DatasetKey> dropped_;                         // Dropped, RemoveDataset not returned.
  ViewId calling_view_ = 0;  // The view whose callback runs now (0 = none).
  RenderServiceStats stats_;

  std::thread::id render_thread_id_;
  // Declared after mu_ and completions_: destroyed (its I/O threads joined) before them.
  std::unique_ptr<paging::PagePrefetcher> prefetcher_;
  std::thread thread_;  // Last: started after everything above exists.
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_RENDER_SERVICE_H_
