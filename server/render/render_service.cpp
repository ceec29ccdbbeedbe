#include "render/render_service.h"

#include <exception>
#include <future>
#include <system_error>
#include <utility>
#include <vector>

namespace octoscope::render {

// One started request of a view (render thread only).
struct RenderService::Job {
  ViewId view = 0;
  uint64_t generation = 0;  // The view's generation when the request was submitted.
  std::shared_ptr<std::atomic<uint64_t>> view_generation;
  std::shared_ptr<FrameCallback> callback;
  FrameRequest request;
  FrameOptions options;                       // Resolved (request's or the default).
  std::unique_ptr<Refinement> refinement;     // Volume refinements, once started.
  FrameStats slice_stats;                     // Slice refinements: summed over the passes.
  uint64_t slice_last_requests = UINT64_MAX;  // Slice refinements: requests of the last pass.

  bool Stale() const { return view_generation->load(std::memory_order_acquire) != generation; }
};

// The render thread's device objects; created and destroyed on it.
struct RenderService::Devices {
  std::unique_ptr<ProgramCache> owned_programs;
  std::unique_ptr<DeviceOctree> device_octree;
  std::unique_ptr<VolumeRenderer> volume_renderer;
  std::unique_ptr<SliceRenderer> slice_renderer;
};

namespace {

// One slice frame (no convergence loop: the service interleaves the frames of a refinement).
SliceOptions OneSliceFrame(const FrameOptions& options) {
  SliceOptions slice;
  slice.lod_bias = options.lod_bias;
  slice.upload = options.upload;
  slice.converge = false;
  slice.max_frames = 1;
  return slice;
}

// Adds one slice frame's stats to a request's.
void AddSliceStats(const SliceStats& slice, FrameStats* stats) {
  stats->ms_total += slice.ms;
  stats->passes += slice.frames;
  stats->samples += slice.samples;
  stats->requests += slice.requests;
  stats->bricks_uploaded += slice.bricks_uploaded;
  stats->finished_fraction = 1;
  stats->pass_finished.push_back(1);
  stats->final = slice.last_requests == 0;
}

}  // namespace

struct RenderService::Step {
  enum class Kind { kNone, kFullFrame, kStartRefinement, kRefinePass } kind = Kind::kNone;
  ViewId view = 0;
  std::unique_ptr<Job> new_job;  // kFullFrame, kStartRefinement: the job taken from the slot.
};

RenderService::RenderService(const ComputeContext* context, ProgramCache* programs,
                             octree::Octree* octree, const Vec3& spacing_um,
                             const RenderServiceOptions& options)
    : context_(context),
      shared_programs_(programs),
      octree_(octree),
      spacing_(spacing_um),
      options_(options) {}

Result<std::unique_ptr<RenderService>> RenderService::Create(ComputeContext context,
                                                             octree::Octree* octree,
                                                             const Vec3& spacing_um,
                                                             const RenderServiceOptions& options) {
  auto owned = std::make_unique<ComputeContext>(std::move(context));
  std::unique_ptr<RenderService> service(
      new RenderService(owned.get(), nullptr, octree, spacing_um, options));
  service->owned_context_ = std::move(owned);
  return Start(std::move(service));
}

Result<std::unique_ptr<RenderService>> RenderService::CreateShared(
    const ComputeContext* context, ProgramCache* programs, octree::Octree* octree,
    const Vec3& spacing_um, const RenderServiceOptions& options) {
  if (context == nullptr || programs == nullptr || octree == nullptr) {
    return InvalidArgumentError("RenderService: context, programs and octree are required");
  }
  return Start(std::unique_ptr<RenderService>(
      new RenderService(context, programs, octree, spacing_um, options)));
}

Result<std::unique_ptr<RenderService>> RenderService::Start(
    std::unique_ptr<RenderService> service) {
  if (service->octree_ == nullptr) return InvalidArgumentError("RenderService: no octree");
  // The thread reports whether it could create the device objects before Create returns.
  auto init = std::make_shared<std::promise<Status>>();
  std::future<Status> init_done = init->get_future();
  try {
    service->thread_ = std::thread(
        [raw = service.get(), init] { raw->Run([init](Status s) { init->set_value(s); }); });
  } catch (const std::system_error& e) {
    return ResourceExhaustedError(std::string("RenderService: cannot start the render thread: ") +
                                  e.what());
  }
  {
    std::lock_guard lock(service->mu_);
    service->render_thread_id_ = service->thread_.get_id();
  }
  Status status = init_done.get();
  if (!status.ok()) {
    // Run returned after reporting the error; the destructor joins it.
    return status;
  }
  return service;
}

RenderService::~RenderService() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  work_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

ViewId RenderService::OpenView(FrameCallback callback) {
  View view;
  view.callback = std::make_shared<FrameCallback>(std::move(callback));
  view.generation = std::make_shared<std::atomic<uint64_t>>(0);
  std::lock_guard lock(mu_);
  const ViewId id = next_view_++;
  views_.emplace(id, std::move(view));
  return id;
}

void RenderService::CloseView(ViewId view) {
  std::unique_ptr<FrameRequest> dropped;  // Destroyed outside the lock.
  std::unique_lock lock(mu_);
  auto it = views_.find(view);
  if (it == views_.end()) return;
  dropped = std::move(it->second.pending);
  // The render thread drops the view's job at its next pass boundary.
  it->second.generation->fetch_add(1, std::memory_order_acq_rel);
  views_.erase(it);
  // A callback of this view may be running right now: wait for it, unless this IS that callback.
  if (std::this_thread::get_id() != render_thread_id_) {
    callback_cv_.wait(lock, [&] { return calling_view_ != view; });
  }
}

Status RenderService::Submit(ViewId view, FrameRequest request) {
  if (request.kind == FrameKind::kVolume && !request.camera.has_value()) {
    return InvalidArgumentError("RenderService::Submit: a volume frame needs a camera");
  }
  if (request.kind == FrameKind::kSlice && !request.slice.has_value()) {
    return InvalidArgumentError("RenderService::Submit: a slice frame needs a slice");
  }
  // Move the (possibly large) request into its own allocation before taking the lock.
  auto boxed = std::make_unique<FrameRequest>(std::move(request));
  {
    std::lock_guard lock(mu_);
    auto it = views_.find(view);
    if (it == views_.end()) {
      return NotFoundError("RenderService::Submit: view " + std::to_string(view) + " is not open");
    }
    if (it->second.pending != nullptr) ++stats_.replaced;
    ++stats_.requests;
    // The old pending request (if any) leaves in `boxed` and is destroyed after unlocking.
    std::swap(it->second.pending, boxed);
    it->second.generation->fetch_add(1, std::memory_order_acq_rel);
  }
  work_cv_.notify_one();
  return Status::Ok();
}

RenderServiceStats RenderService::stats() const {
  std::lock_guard lock(mu_);
  return stats_;
}

void RenderService::Run(std::function<void(Status)> init) {
  Devices devices;
  // Step 0: create the device objects on this thread, which owns them from now on.
  {
    ProgramCache* programs = shared_programs_;
    if (programs == nullptr) {
      devices.owned_programs = std::make_unique<ProgramCache>(context_);
      programs = devices.owned_programs.get();
    }
    Result<std::unique_ptr<DeviceOctree>> device_octree =
        DeviceOctree::Create(context_, octree_, options_.device_octree);
    if (!device_octree.ok()) {
      init(device_octree.status().WithContext("RenderService"));
      return;
    }
    devices.device_octree = std::move(*device_octree);
    Result<std::unique_ptr<VolumeRenderer>> volume_renderer =
        VolumeRenderer::Create(context_, programs, devices.device_octree.get(), spacing_);
    if (!volume_renderer.ok()) {
      init(volume_renderer.status().WithContext("RenderService"));
      return;
    }
    devices.volume_renderer = std::move(*volume_renderer);
    Result<std::unique_ptr<SliceRenderer>> slice_renderer = SliceRenderer::Create(
        context_, programs, devices.device_octree.get(), spacing_, options_.slice_build_options);
    if (!slice_renderer.ok()) {
      init(slice_renderer.status().WithContext("RenderService"));
      return;
    }
    devices.slice_renderer = std::move(*slice_renderer);
  }
  init(Status::Ok());

  // Started refinements, one per view at most. Declared after `devices` so that they are
  // destroyed first (a Refinement's device state belongs to the renderer).
  std::map<ViewId, std::unique_ptr<Job>> jobs;
  while (true) {
    Step step;
    {
      std::unique_lock lock(mu_);
      work_cv_.wait(lock, [&] { return stop_ || PickLocked(jobs, &step); });
      if (stop_) break;
    }
    // Exceptions never leave the render thread: one that escapes a frame (e.g. bad_alloc for an
    // absurd image) ends that view's request with an error, and the thread keeps serving.
    const ViewId view = step.view;
    const Job* job =
        step.new_job ? step.new_job.get() : (jobs.count(view) != 0 ? jobs.at(view).get() : nullptr);
    std::shared_ptr<FrameCallback> callback = job != nullptr ? job->callback : nullptr;
    FrameResult failed;
    failed.view = view;
    failed.final = true;
    if (job != nullptr) {
      failed.sequence = job->request.sequence;
      failed.kind = job->request.kind;
    }
    try {
      Execute(devices, jobs, step);
    } catch (const std::exception& e) {
      failed.status = InternalError(std::string("rendering failed: ") + e.what());
    } catch (...) {
      failed.status = InternalError("rendering failed: unknown exception");
    }
    if (!failed.status.ok()) {
      jobs.erase(view);
      if (callback != nullptr) Deliver(view, callback, std::move(failed));
    }
  }
  // Shutdown: drop every job (no callbacks), then the renderers before the device octree.
  jobs.clear();
  devices.slice_renderer.reset();
  devices.volume_renderer.reset();
  devices.device_octree.reset();
}

bool RenderService::PickLocked(std::map<ViewId, std::unique_ptr<Job>>& jobs, Step* step) {
  // Cancel at the pass boundary: jobs of closed views or superseded by a newer Submit.
  for (auto it = jobs.begin(); it != jobs.end();) {
    if (it->second->Stale()) {
      ++stats_.cancelled;
      it = jobs.erase(it);
    } else {
      ++it;
    }
  }
  const auto take_pending = [&](ViewId id, View& view) {
    auto job = std::make_unique<Job>();
    job->view = id;
    job->generation = view.generation->load(std::memory_order_acquire);
    job->view_generation = view.generation;
    job->callback = view.callback;
    job->request = std::move(*view.pending);
    view.pending.reset();
    job->options = job->request.options.value_or(options_.default_frame);
    return job;
  };
  // Step 1: a refinement that made no progress goes again before anything can evict its bricks.
  if (retry_view_ != 0) {
    const ViewId id = std::exchange(retry_view_, 0);
    if (jobs.count(id) != 0) {
      step->kind = Step::Kind::kRefinePass;
      step->view = id;
      ++stats_.stall_retries;
      return true;
    }
  }
  // Round robin: views after `cursor` first, then from the start.
  const auto round_robin = [&](ViewId cursor, auto&& wants) -> ViewId {
    for (auto it = views_.upper_bound(cursor); it != views_.end(); ++it) {
      if (wants(it->first, it->second)) return it->first;
    }
    for (auto it = views_.begin(); it != views_.end() && it->first <= cursor; ++it) {
      if (wants(it->first, it->second)) return it->first;
    }
    return 0;
  };
  // Step 2: interaction first — pending full frames.
  const ViewId full = round_robin(full_frame_cursor_, [&](ViewId, const View& v) {
    return v.pending != nullptr &&
           v.pending->options.value_or(options_.default_frame).mode == FrameMode::kFullFrame;
  });
  if (full != 0) {
    full_frame_cursor_ = full;
    step->kind = Step::Kind::kFullFrame;
    step->view = full;
    step->new_job = take_pending(full, views_.at(full));
    return true;
  }
  // Step 3: refinements, one pass per turn (a pending request replaces the view's job).
  const ViewId refine = round_robin(refine_cursor_, [&](ViewId id, const View& v) {
    return v.pending != nullptr || jobs.count(id) != 0;
  });
  if (refine != 0) {
    refine_cursor_ = refine;
    step->view = refine;
    View& view = views_.at(refine);
    if (view.pending != nullptr) {
      step->kind = Step::Kind::kStartRefinement;
      step->new_job = take_pending(refine, view);
    } else {
      step->kind = Step::Kind::kRefinePass;
    }
    return true;
  }
  return false;
}

void RenderService::Execute(Devices& devices, std::map<ViewId, std::unique_ptr<Job>>& jobs,
                            Step& step) {
  VolumeRenderer& volume = *devices.volume_renderer;
  SliceRenderer& slice = *devices.slice_renderer;
  const auto count_pass = [&] {
    std::lock_guard lock(mu_);
    ++stats_.passes;
  };
  const auto result_of = [](const Job& job) {
    FrameResult result;
    result.view = job.view;
    result.sequence = job.request.sequence;
    result.kind = job.request.kind;
    return result;
  };
  // A frame's image, or its error (which ends the request).
  const auto finish = [](Result<RenderImage> image, FrameResult* result) {
    if (image.ok()) {
      result->image = std::move(*image);
    } else {
      result->status = image.status();
      result->final = true;
    }
  };

  if (step.kind == Step::Kind::kFullFrame) {
    // A full frame is one pass: Sync, kernel, read-back, upload for the next frame.
    Job& job = *step.new_job;
    FrameResult result = result_of(job);
    result.final = true;
    if (job.request.kind == FrameKind::kSlice) {
      SliceStats slice_stats;
      finish(slice.Render(*job.request.slice, job.request.params, OneSliceFrame(job.options),
                          &slice_stats),
             &result);
      AddSliceStats(slice_stats, &result.stats);
    } else {
      // Brick-buffer pressure coarsens this view's frames only.
      FrameOptions options = job.options;
      options.view = job.view;
      finish(
          volume.RenderFullFrame(*job.request.camera, job.request.params, options, &result.stats),
          &result);
    }
    count_pass();
    Deliver(job.view, job.callback, std::move(result));
    return;
  }

  if (step.kind == Step::Kind::kStartRefinement) {
    // The new request replaces the view's previous job (an older generation: cancelled).
    if (jobs.erase(step.view) != 0) {
      std::lock_guard lock(mu_);
      ++stats_.cancelled;
    }
    Job& job = *step.new_job;
    if (job.request.kind == FrameKind::kVolume) {
      Result<std::unique_ptr<Refinement>> refinement =
          volume.StartRefinement(*job.request.camera, job.request.params, job.options);
      if (!refinement.ok()) {
        FrameResult result = result_of(job);
        result.final = true;
        result.status = refinement.status();
        Deliver(job.view, job.callback, std::move(result));
        return;
      }
      job.refinement = std::move(*refinement);
    }
    jobs[step.view] = std::move(step.new_job);
  }

  // One refinement pass of the view's job.
  auto it = jobs.find(step.view);
  if (it == jobs.end()) return;
  Job& job = *it->second;
  FrameResult result = result_of(job);
  Status error;                      // The pass's or the read-back's failure.
  std::optional<RenderImage> image;  // Read back only when someone will see it.
  bool stalled = false;              // The pass advanced nothing.
  if (job.request.kind == FrameKind::kSlice) {
    // A slice pass is a complete slice frame; it converges when a frame requests nothing.
    SliceStats slice_stats;
    Result<RenderImage> frame = slice.Render(*job.request.slice, job.request.params,
                                             OneSliceFrame(job.options), &slice_stats);
    count_pass();
    if (frame.ok()) {
      AddSliceStats(slice_stats, &job.slice_stats);
      const int max_passes =
          job.options.max_passes > 0 ? job.options.max_passes : kDefaultSliceMaxPasses;
      result.final = job.slice_stats.final || job.slice_stats.passes >= max_passes;
      stalled =
          slice_stats.last_requests > 0 && slice_stats.last_requests >= job.slice_last_requests;
      job.slice_last_requests = slice_stats.last_requests;
      image = std::move(*frame);
    } else {
      error = frame.status();
    }
    result.stats = job.slice_stats;
  } else {
    Refinement& refinement = *job.refinement;
    const uint64_t samples_before = refinement.stats().samples;
    const double finished_before = refinement.stats().finished_fraction;
    Result<double> finished = volume.RefinePass(refinement);
    count_pass();
    if (finished.ok()) {
      const bool out_of_passes =
          job.options.max_passes > 0 && refinement.stats().passes >= job.options.max_passes;
      result.final = refinement.complete() || out_of_passes;
      stalled = refinement.stats().samples == samples_before &&
                refinement.stats().finished_fraction == finished_before;
      if (result.final || job.request.progress_images) {
        Result<RenderImage> read = volume.ReadImage(refinement);
        if (read.ok()) {
          image = std::move(*read);
        } else {
          error = read.status();
        }
      }
    } else {
      error = finished.status();
    }
    result.stats = refinement.stats();
  }
  if (!error.ok()) {
    // A failed request ends with its error.
    result.final = true;
    result.status = error;
  } else if (!result.final) {
    if (stalled) {
      // No progress: what this pass uploaded must be used before another job can evict it.
      std::lock_guard lock(mu_);
      retry_view_ = step.view;
    }
    if (!job.request.progress_images) return;
  }
  if (error.ok() && image.has_value()) result.image = std::move(*image);
  std::shared_ptr<FrameCallback> callback = job.callback;
  if (result.final) jobs.erase(it);
  Deliver(step.view, callback, std::move(result));
}

void RenderService::Deliver(ViewId view, const std::shared_ptr<FrameCallback>& callback,
                            FrameResult result) {
  const bool final = result.final;
  {
    std::lock_guard lock(mu_);
    // A view closed meanwhile gets nothing (CloseView promises no callback after it returns).
    if (views_.count(view) == 0) return;
    calling_view_ = view;
    // Counted before the call, so that whoever saw the callback sees it counted.
    ++(final ? stats_.frames_delivered : stats_.progress_delivered);
  }
  std::string failure;
  // Exceptions never leave the render thread: a throwing callback closes its view.
  try {
    (*callback)(std::move(result));
  } catch (const std::exception& e) {
    failure = std::string("view ") + std::to_string(view) + " callback threw: " + e.what();
  } catch (...) {
    failure = std::string("view ") + std::to_string(view) + " callback threw a non-exception";
  }
  std::unique_ptr<FrameRequest> dropped;  // Destroyed outside the lock.
  {
    std::lock_guard lock(mu_);
    calling_view_ = 0;
    if (!failure.empty()) {
      ++stats_.callback_failures;
      stats_.last_callback_error = failure;
      auto it = views_.find(view);
      if (it != views_.end()) {
        dropped = std::move(it->second.pending);
        it->second.generation->fetch_add(1, std::memory_order_acq_rel);
        views_.erase(it);
      }
    }
  }
  callback_cv_.notify_all();
}

}  // namespace octoscope::render
