#include "render/render_service.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <future>
#include <limits>
#include <new>
#include <system_error>
#include <utility>

namespace octoscope::render {

namespace {

using Clock = std::chrono::steady_clock;

// How long a page whose read failed counts as failed (the prefetcher's failure_hold).
constexpr std::chrono::milliseconds kFailureHold{10'000};
// Failed pages remembered per dataset at most (a damaged store must not grow the map forever).
constexpr size_t kMaxFailedPages = 4096;
// A prefetch whose completion did not come within this long is requested again (a completion
// the prefetcher could not record must not leave a page waited for forever).
constexpr std::chrono::milliseconds kInFlightExpiry{5'000};

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

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
  stats->bricks_unavailable += slice.bricks_unavailable;
  stats->finished_fraction = 1;
  stats->pass_finished.push_back(1);
  stats->final = slice.last_requests == 0;
}

// Water-filling of `budget` over `needs` (bytes each dataset can use at most): equal shares, a
// dataset needing less keeps only its need and the rest is divided among the others. (A mirror
// has at least kMinBrickSlots bricks whatever its share, so with very many datasets the mirrors
// may exceed the budget by that floor.)
std::map<DatasetKey, uint64_t> DivideBudget(uint64_t budget,
                                            std::vector<std::pair<uint64_t, DatasetKey>> needs) {
  std::sort(needs.begin(), needs.end());
  std::map<DatasetKey, uint64_t> shares;
  uint64_t left = budget;
  for (size_t i = 0; i < needs.size(); ++i) {
    const uint64_t equal = left / (needs.size() - i);
    const uint64_t share = std::min(needs[i].first, equal);
    shares[needs[i].second] = share;
    left -= std::min(left, share);
  }
  return shares;
}

}  // namespace

namespace {

constexpr int kInteraction = 0;  // Scheduling classes (index into the per-class arrays).
constexpr int kRefinement = 1;

// One started request of a view (render thread only).
struct Job {
  ViewId view = 0;
  DatasetKey dataset = 0;
  uint64_t generation = 0;  // The view's generation when the request was submitted.
  std::shared_ptr<std::atomic<uint64_t>> view_generation;
  std::shared_ptr<FrameCallback> callback;
  FrameRequest request;
  FrameOptions options;                       // Resolved (request's or the default).
  std::unique_ptr<Refinement> refinement;     // Volume refinements, once started.
  FrameStats slice_stats;                     // Slice refinements: summed over the passes.
  double charged_ms = 0;                      // Render-thread time charged for its passes.
  uint64_t slice_last_requests = UINT64_MAX;  // Slice refinements: requests of the last pass.
  // Waiting for brick pages (a pass that advanced nothing because its bricks are not in RAM): not
  // scheduled until every awaited page completed (any completion of the dataset when none could
  // be requested) or until retry_at.
  bool waiting_io = false;
  std::set<uint64_t> awaited;
  Clock::time_point retry_at;

  bool Stale() const { return view_generation->load(std::memory_order_acquire) != generation; }
};
using Jobs = std::map<ViewId, std::unique_ptr<Job>>;

// The fields of a result that identify `job`'s request.
FrameResult ResultOf(const Job& job) {
  FrameResult result;
  result.view = job.view;
  result.dataset = job.dataset;
  result.sequence = job.request.sequence;
  result.version = job.request.version;
  result.kind = job.request.kind;
  result.mode = job.options.mode;
  return result;
}

// What the render thread does next: one pass (or a refusal, which costs no device time).
struct Step {
  enum class Kind { kNone, kRefuse, kFullFrame, kStartRefinement, kRefinePass } kind = Kind::kNone;
  ViewId view = 0;
  int service_class = kInteraction;
  std::unique_ptr<Job> new_job;  // kRefuse, kFullFrame, kStartRefinement: taken from the slot.
  Status refusal;                // kRefuse.
};

// What the render thread takes from the shared state at the top of each loop.
struct Inputs {
  struct DatasetInfo {
    DatasetKey key = 0;
    octree::Octree* octree = nullptr;
    Vec3 spacing;
    bool has_views = false;
  };
  std::vector<paging::PrefetchCompletion> completions;
  std::vector<DatasetKey> drops;
  bool datasets_changed = false;
  std::vector<DatasetInfo> datasets;  // When datasets_changed: every dataset now.
};

// What prefetching the pages a pass missed found.
struct PageOutcome {
  bool missing = false;         // The pass skipped bricks whose pages are not in RAM.
  bool resident_again = false;  // One of those pages is back already: no need to wait.
  Status error;                 // One of those pages cannot be read.
};

// A dataset's device objects. Members are destroyed renderers first.
struct Mirror {
  std::unique_ptr<DeviceOctree> device;
  std::unique_ptr<VolumeRenderer> volume;
  std::unique_ptr<SliceRenderer> slice;
};

struct FailedPage {
  Status status;
  Clock::time_point when;
};

// The render thread's view of one dataset.
struct DatasetState {
  octree::Octree* octree = nullptr;
  Vec3 spacing;
  bool has_views = false;
  Clock::time_point idle_since;  // When has_views last became false.
  uint64_t share = 0;            // Its share of the brick-buffer budget (datasets with views).
  std::unique_ptr<Mirror> mirror;
  // Pages requested whose completion did not come yet, with the time of their request.
  std::map<uint64_t, Clock::time_point> in_flight;
  std::map<uint64_t, FailedPage> failed;
};

// Per open view: its frame buffers and its deficits (deficit round robin, per class).
struct ViewState {
  explicit ViewState(const ComputeContext* context) : buffers(context) {}
  FrameBuffers buffers;
  double deficit[2] = {0, 0};
  std::optional<Clock::time_point> memory_wait_since;  // Its pending request waits for memory.
};

}  // namespace

struct RenderService::Worker {
  explicit Worker(RenderService& service) : s(service) {}
  ~Worker() {
    // Jobs first (a Refinement belongs to its mirror's renderer), then buffers, then mirrors.
    jobs.clear();
    views.clear();
    datasets.clear();
  }

  // The loop of the render thread until stop.
  void Loop();

  // --- With s.mu_ held. ---
  void TakeInputsLocked(Inputs* in);
  // Copies the current memory figures into the stats.
  void PublishLocked();
  // Ends the jobs of closed views or superseded by a newer Submit; frees closed views' buffers.
  void SweepLocked();
  // Picks the next step (see the header comment); false when there is nothing to do now.
  bool PickLocked(Step* step);
  // Whether the frame buffers `sizes` of `view` fit the frame memory (releasing the buffers of
  // views with nothing to render if needed).
  bool AdmitLocked(ViewId view, const FrameBufferSizes& sizes);
  ViewId DrrPick(int c, const std::vector<ViewId>& busy);

  // --- Without the lock. ---
  void Housekeeping(Inputs& in);
  void Rebalance();
  void DropMirror(DatasetKey key, DatasetState& ds);
  void FailDataset(DatasetKey key, const Status& status);
  void FailJob(Jobs::iterator it, const Status& status);
  void EraseJob(Jobs::iterator it);
  std::optional<Clock::time_point> NextDeadline() const;
  void RunStep(Step& step);
  void Execute(Step& step);
  Result<Mirror*> MirrorFor(DatasetKey key);
  void RequestPages(DatasetKey key, Job* job, PageOutcome* outcome);
  void Deliver(ViewId view, const std::shared_ptr<FrameCallback>& callback, FrameResult result) {
    result.scheduled_ms = step_charged_before + std::max(0.0, MsSince(step_start) - callback_ms);
    CountAllocations();  // Whoever sees the frame sees its allocations counted.
    callback_ms += s.Deliver(view, callback, std::move(result));
  }
  // Ends the request of `result` with `status` (final).
  void DeliverError(FrameResult result, const std::shared_ptr<FrameCallback>& callback,
                    const Status& status) {
    result.final = true;
    result.status = status;
    const ViewId view = result.view;
    Deliver(view, callback, std::move(result));
  }
  // Adds the frame buffers the current step's view allocated since the last call to the stats.
  // Publishes the memory figures too.
  void CountAllocations() {
    const auto it = views.find(step_view);
    std::lock_guard lock(s.mu_);
    if (it != views.end()) {
      const uint64_t now = it->second->buffers.allocations();
      s.stats_.frame_buffer_allocations += now - step_allocations;
      step_allocations = now;
    }
    PublishLocked();
  }
  void Count(uint64_t RenderServiceStats::*counter) {
    std::lock_guard lock(s.mu_);
    ++(s.stats_.*counter);
  }

  ViewState& State(ViewId view) {
    auto& state = views[view];
    if (state == nullptr) state = std::make_unique<ViewState>(s.context_);
    return *state;
  }
  uint64_t FrameBytes() const {
    uint64_t total = 0;
    for (const auto& [id, state] : views) total += state->buffers.bytes();
    return total;
  }
  uint64_t BrickBytes() const {
    uint64_t total = 0;
    for (const auto& [key, ds] : datasets) {
      if (ds.mirror != nullptr) total += ds.mirror->device->brick_buffer_bytes();
    }
    return total;
  }

  RenderService& s;
  std::unique_ptr<ProgramCache> owned_programs;
  ProgramCache* programs = nullptr;
  std::map<DatasetKey, DatasetState> datasets;
  uint64_t datasets_version = 0;
  std::map<ViewId, std::unique_ptr<ViewState>> views;
  Jobs jobs;  // Started refinements, one per view at most.
  // Scheduling state (see the header comment).
  double class_vt[2] = {0, 0};
  bool class_busy[2] = {false, false};
  bool refined_while_full_waited = false;
  ViewId cursor[2] = {0, 0};
  double callback_ms = 0;          // Time spent in callbacks during the current step.
  Clock::time_point step_start;    // The current step's start,
  double step_charged_before = 0;  // and its job's charged time before it.
  ViewId step_view = 0;            // The current step's view, and its buffers' allocations counted.
  uint64_t step_allocations = 0;
};

// ------------------------------------------------------------------------------------------------
// The render thread.

void RenderService::Run(std::function<void(Status)> init) {
  std::unique_ptr<Worker> worker;
  // Start-up inside the error handling: a failure here is Create's error, never a terminate.
  try {
    worker = std::make_unique<Worker>(*this);
    worker->programs = shared_programs_;
    if (worker->programs == nullptr) {
      worker->owned_programs = std::make_unique<ProgramCache>(context_);
      worker->programs = worker->owned_programs.get();
    }
  } catch (const std::exception& e) {
    init(ResourceExhaustedError(std::string("RenderService: render thread start-up: ") + e.what()));
    return;
  }
  init(Status::Ok());
  // Outside a pass (whose exceptions end only its request) the loop only allocates host memory;
  // should that fail, the service stops serving and says why instead of terminating.
  std::string failure;
  try {
    worker->Loop();
    return;
  } catch (const std::exception& e) {
    failure = e.what();
  } catch (...) {
    failure = "unknown exception";
  }
  {
    std::lock_guard lock(mu_);
    failed_ = InternalError("RenderService: the render thread failed: " + failure);
    calling_view_ = 0;
  }
  // Nobody waits for this thread any more (RemoveDataset, CloseView).
  dropped_cv_.notify_all();
  callback_cv_.notify_all();
}

void RenderService::Worker::Loop() {
  while (true) {
    Inputs in;
    {
      std::lock_guard lock(s.mu_);
      if (s.stop_) return;
      TakeInputsLocked(&in);
    }
    Housekeeping(in);
    Step step;
    {
      std::unique_lock lock(s.mu_);
      if (s.stop_) return;
      // New inputs first; then a step, or sleep until work arrives or the earliest deadline.
      if (!s.completions_.empty() || !s.drop_queue_.empty() ||
          s.datasets_version_ != datasets_version) {
        continue;
      }
      PublishLocked();
      if (!PickLocked(&step)) {
        const std::optional<Clock::time_point> deadline = NextDeadline();
        if (deadline.has_value()) {
          s.work_cv_.wait_until(lock, *deadline);
        } else {
          s.work_cv_.wait(lock);
        }
        continue;
      }
    }
    RunStep(step);
  }
}

void RenderService::Worker::TakeInputsLocked(Inputs* in) {
  in->completions = std::exchange(s.completions_, {});
  in->drops = std::exchange(s.drop_queue_, {});
  if (s.datasets_version_ != datasets_version) {
    in->datasets_changed = true;
    datasets_version = s.datasets_version_;
    for (const auto& [key, ds] : s.datasets_) {
      in->datasets.push_back({key, ds.octree, ds.spacing, ds.open_views > 0});
    }
  }
  SweepLocked();
  PublishLocked();
}

void RenderService::Worker::PublishLocked() {
  RenderServiceStats& stats = s.stats_;
  stats.mirrors = 0;
  for (const auto& [key, ds] : datasets) stats.mirrors += ds.mirror != nullptr ? 1 : 0;
  stats.brick_memory_bytes = BrickBytes();
  stats.frame_memory_bytes = FrameBytes();
}

void RenderService::Worker::SweepLocked() {
  for (auto it = jobs.begin(); it != jobs.end();) {
    const auto next = std::next(it);
    if (it->second->Stale()) {
      ++s.stats_.cancelled;
      EraseJob(it);
    }
    it = next;
  }
  for (auto it = views.begin(); it != views.end();) {
    it = s.views_.count(it->first) == 0 ? views.erase(it) : std::next(it);
  }
}

void RenderService::Worker::EraseJob(Jobs::iterator it) {
  const auto ds = datasets.find(it->second->dataset);
  if (ds != datasets.end() && ds->second.mirror != nullptr) {
    ds->second.mirror->device->ReleaseReservations(it->first);
  }
  jobs.erase(it);
}

void RenderService::Worker::Housekeeping(Inputs& in) {
  const Clock::time_point now = Clock::now();
  // Removed datasets (views closed, jobs swept): drop the state and mirror, then tell
  // RemoveDataset.
  for (DatasetKey key : in.drops) {
    for (auto it = jobs.begin(); it != jobs.end();) {
      const auto next = std::next(it);
      if (it->second->dataset == key) EraseJob(it);
      it = next;
    }
    if (const auto it = datasets.find(key); it != datasets.end()) {
      if (it->second.mirror != nullptr) Count(&RenderServiceStats::mirrors_dropped);
      datasets.erase(it);
    }
  }
  if (!in.drops.empty()) {
    {
      std::lock_guard lock(s.mu_);
      s.dropped_.insert(in.drops.begin(), in.drops.end());
      PublishLocked();
    }
    s.dropped_cv_.notify_all();
  }
  if (in.datasets_changed) {
    std::set<DatasetKey> present;
    for (const Inputs::DatasetInfo& info : in.datasets) {
      present.insert(info.key);
      DatasetState& ds = datasets[info.key];
      ds.octree = info.octree;
      ds.spacing = info.spacing;
      if (ds.has_views && !info.has_views) ds.idle_since = now;
      ds.has_views = info.has_views;
    }
    for (auto it = datasets.begin(); it != datasets.end();) {
      it = present.count(it->first) == 0 ? datasets.erase(it) : std::next(it);
    }
    Rebalance();
  }
  // Idle mirrors are dropped a while after their dataset's last view closed.
  for (auto& [key, ds] : datasets) {
    if (ds.mirror != nullptr && !ds.has_views &&
        now - ds.idle_since >= s.options_.mirror_idle_timeout) {
      DropMirror(key, ds);
    }
  }
  // Prefetch completions wake (or fail) the jobs waiting for their pages.
  for (const paging::PrefetchCompletion& c : in.completions) {
    const bool read_error = !c.status.ok() && c.status.code() != StatusCode::kResourceExhausted;
    for (auto& [key, ds] : datasets) {
      if (ds.octree->page_cache() != c.cache) continue;
      ds.in_flight.erase(c.page);
      if (read_error) {
        if (ds.failed.size() >= kMaxFailedPages) ds.failed.erase(ds.failed.begin());
        ds.failed[c.page] = {c.status, now};
        Count(&RenderServiceStats::page_errors);
      }
      for (auto it = jobs.begin(); it != jobs.end();) {
        const auto next = std::next(it);
        Job& job = *it->second;
        if (job.dataset == key && job.waiting_io) {
          const bool awaited = job.awaited.erase(c.page) != 0;
          if (awaited && read_error) {
            FailJob(it, c.status.WithContext("brick page " + std::to_string(c.page)));
          } else if (job.awaited.empty()) {
            job.waiting_io = false;
          }
        }
        it = next;
      }
    }
  }
  // Refinements that waited long enough for pages try again.
  for (auto& [id, job] : jobs) {
    if (job->waiting_io && job->retry_at <= now) job->waiting_io = false;
  }
}

void RenderService::Worker::Rebalance() {
  std::vector<std::pair<uint64_t, DatasetKey>> needs;
  for (const auto& [key, ds] : datasets) {
    if (ds.has_views) {
      needs.emplace_back(DeviceOctree::MaxBrickBufferBytes(ds.octree->geometry()), key);
    }
  }
  const std::map<DatasetKey, uint64_t> shares = DivideBudget(s.device_memory_bytes_, needs);
  uint64_t used = 0;
  for (auto& [key, ds] : datasets) {
    const auto share = shares.find(key);
    ds.share = share != shares.end() ? share->second : 0;
    used += ds.share;
  }
  // Idle mirrors keep their memory only while the datasets with views leave it unused; the
  // longest idle leave first.
  std::vector<std::pair<Clock::time_point, DatasetKey>> idle;
  uint64_t idle_bytes = 0;
  for (auto& [key, ds] : datasets) {
    if (ds.mirror != nullptr && !ds.has_views) {
      idle.emplace_back(ds.idle_since, key);
      idle_bytes += ds.mirror->device->brick_buffer_bytes();
    }
  }
  std::sort(idle.begin(), idle.end());
  for (const auto& [since, key] : idle) {
    if (used + idle_bytes <= s.device_memory_bytes_) break;
    DatasetState& ds = datasets.at(key);
    idle_bytes -= ds.mirror->device->brick_buffer_bytes();
    DropMirror(key, ds);
  }
  // Shrink first (frees memory), then grow the mirrors whose share grew enough.
  for (const bool shrink : {true, false}) {
    for (auto& [key, ds] : datasets) {
      if (ds.mirror == nullptr || !ds.has_views) continue;
      const DeviceOctree& device = *ds.mirror->device;
      const uint64_t size = device.brick_buffer_bytes();
      const uint64_t brick = device.device_brick_bytes();
      const bool too_big = std::max<uint64_t>(ds.share / brick, kMinBrickSlots) < size / brick;
      const bool can_grow =
          static_cast<double>(ds.share) > static_cast<double>(size) * kMirrorGrowth &&
          size < DeviceOctree::MaxBrickBufferBytes(ds.octree->geometry());
      if (shrink ? !too_big : !can_grow) continue;
      Status resized;
      try {
        resized = ds.mirror->device->ResizeBrickBuffer(ds.share);
        // Resizing dropped every brick: the coarsest levels come back at once.
        if (resized.ok()) resized = ds.mirror->device->UploadCoarseLevels(kCoarseLevelBytes);
      } catch (const std::exception& e) {
        resized = ResourceExhaustedError(std::string("resizing the brick buffer: ") + e.what());
      }
      Count(&RenderServiceStats::mirror_resizes);
      if (!resized.ok()) FailDataset(key, resized.WithContext("dataset " + std::to_string(key)));
    }
  }
}

void RenderService::Worker::DropMirror(DatasetKey key, DatasetState& ds) {
  // Its jobs go with it (their views are closed, or they were failed first).
  for (auto it = jobs.begin(); it != jobs.end();) {
    it = it->second->dataset == key ? jobs.erase(it) : std::next(it);
  }
  ds.mirror.reset();
  // Its queued prefetches are of no use now (CancelAll never waits for I/O).
  s.prefetcher_->CancelAll(ds.octree->page_cache());
  ds.in_flight.clear();
  Count(&RenderServiceStats::mirrors_dropped);
}

void RenderService::Worker::FailDataset(DatasetKey key, const Status& status) {
  for (auto it = jobs.begin(); it != jobs.end();) {
    const auto next = std::next(it);
    if (it->second->dataset == key) FailJob(it, status);
    it = next;
  }
  if (const auto it = datasets.find(key); it != datasets.end() && it->second.mirror != nullptr) {
    DropMirror(key, it->second);
  }
}

void RenderService::Worker::FailJob(Jobs::iterator it, const Status& status) {
  FrameResult result = ResultOf(*it->second);
  std::shared_ptr<FrameCallback> callback = it->second->callback;
  EraseJob(it);
  DeliverError(std::move(result), callback, status);
}

std::optional<Clock::time_point> RenderService::Worker::NextDeadline() const {
  std::optional<Clock::time_point> deadline;
  const auto consider = [&deadline](Clock::time_point t) {
    if (!deadline.has_value() || t < *deadline) deadline = t;
  };
  for (const auto& [id, job] : jobs) {
    if (job->waiting_io) consider(job->retry_at);
  }
  for (const auto& [id, state] : views) {
    if (state->memory_wait_since.has_value()) {
      consider(*state->memory_wait_since + s.options_.admission_timeout);
    }
  }
  for (const auto& [key, ds] : datasets) {
    if (ds.mirror != nullptr && !ds.has_views) {
      consider(ds.idle_since + s.options_.mirror_idle_timeout);
    }
  }
  return deadline;
}

bool RenderService::Worker::PickLocked(Step* step) {
  SweepLocked();
  const Clock::time_point now = Clock::now();
  const RenderServiceOptions& options = s.options_;
  const auto take_pending = [&](ViewId id, View& view) {
    auto job = std::make_unique<Job>();
    job->view = id;
    job->dataset = view.dataset;
    job->generation = view.generation->load(std::memory_order_acquire);
    job->view_generation = view.generation;
    job->callback = view.callback;
    job->request = std::move(*view.pending);
    view.pending.reset();
    job->options = job->request.options.value_or(options.default_frame);
    job->options.view = id;
    job->options.upload.reserve_for = 0;
    if (job->options.pass_target_ms == 0) job->options.pass_target_ms = options.refine_pass_ms;
    return job;
  };
  // Admission of each pending request: refused (too large, or waited too long), waiting for frame
  // memory, or admitted (then it competes in its class). Started refinements compete unless they
  // wait for pages.
  std::vector<ViewId> busy[2];
  for (auto& [id, view] : s.views_) {
    if (view.pending == nullptr) {
      if (const auto job = jobs.find(id); job != jobs.end() && !job->second->waiting_io) {
        busy[kRefinement].push_back(id);
      }
      continue;
    }
    const FrameRequest& request = *view.pending;
    const FrameMode mode = request.options.value_or(options.default_frame).mode;
    const FrameBufferSizes sizes =
        request.kind == FrameKind::kSlice
            ? SliceRenderer::BufferSizes(*request.slice, request.params)
            : VolumeRenderer::BufferSizes(mode, request.params, request.camera->width(),
                                          request.camera->height());
    ViewState& state = State(id);
    const uint64_t request_bytes = TotalBytes(sizes);
    Status refusal;
    if (request_bytes > options.max_request_bytes) {
      refusal =
          ResourceExhaustedError("the request needs " + std::to_string(request_bytes) +
                                 " bytes of device memory for its frame buffers; the limit is " +
                                 std::to_string(options.max_request_bytes));
    } else if (!AdmitLocked(id, sizes)) {
      if (!state.memory_wait_since.has_value()) {
        state.memory_wait_since = now;
        ++s.stats_.admission_waits;
      }
      if (now - *state.memory_wait_since < options.admission_timeout) continue;
      refusal = ResourceExhaustedError(
          "no device memory for the frame buffers (" + std::to_string(request_bytes) +
          " bytes) within " + std::to_string(options.admission_timeout.count()) +
          " ms: other views hold " + std::to_string(FrameBytes() - state.buffers.bytes()) + " of " +
          std::to_string(s.frame_memory_bytes_) + " bytes");
    }
    state.memory_wait_since.reset();
    if (!refusal.ok()) {
      // Costs no device time: done at once.
      ++s.stats_.refused;
      step->kind = Step::Kind::kRefuse;
      step->view = id;
      step->refusal = std::move(refusal);
      step->new_job = take_pending(id, view);
      return true;
    }
    busy[mode == FrameMode::kFullFrame ? kInteraction : kRefinement].push_back(id);
  }
  const bool full = !busy[kInteraction].empty();
  const bool refine = !busy[kRefinement].empty();
  // A class that becomes busy while the other is busy catches up with it: no credit saved up
  // while idle, but its debt stays. With no work at all the clocks restart.
  for (int c : {kInteraction, kRefinement}) {
    if (!busy[c].empty() && !class_busy[c] && class_busy[1 - c]) {
      class_vt[c] = std::max(class_vt[c], class_vt[1 - c]);
    }
  }
  class_busy[kInteraction] = full;
  class_busy[kRefinement] = refine;
  if (!full && !refine) {
    class_vt[kInteraction] = class_vt[kRefinement] = 0;
    return false;
  }
  // Interaction unless refinement is owed time — and never two refinement passes in a row while
  // a full frame waits.
  int c = kInteraction;
  if (!full) {
    c = kRefinement;
  } else if (refine && !refined_while_full_waited &&
             class_vt[kRefinement] < class_vt[kInteraction]) {
    c = kRefinement;
  }
  refined_while_full_waited = c == kRefinement && full;
  // Views not busy in a class keep no credit there (their debt stays).
  for (auto& [id, state] : views) {
    for (int k : {kInteraction, kRefinement}) {
      if (!std::binary_search(busy[k].begin(), busy[k].end(), id)) {
        state->deficit[k] = std::min(state->deficit[k], 0.0);
      }
    }
  }
  const ViewId chosen = DrrPick(c, busy[c]);
  step->view = chosen;
  step->service_class = c;
  View& view = s.views_.at(chosen);
  if (view.pending != nullptr) {
    step->kind = c == kInteraction ? Step::Kind::kFullFrame : Step::Kind::kStartRefinement;
    step->new_job = take_pending(chosen, view);
  } else {
    step->kind = Step::Kind::kRefinePass;
  }
  return true;
}

bool RenderService::Worker::AdmitLocked(ViewId view, const FrameBufferSizes& sizes) {
  ViewState& state = State(view);
  const auto fits = [&] {
    return FrameBytes() - state.buffers.bytes() + state.buffers.BytesAfterReserve(sizes) <=
           s.frame_memory_bytes_;
  };
  if (fits()) return true;
  // Buffers of views with nothing to render are only a cache: release them.
  for (auto& [id, other] : views) {
    if (id == view || jobs.count(id) != 0) continue;
    const auto v = s.views_.find(id);
    if (v != s.views_.end() && v->second.pending != nullptr) continue;
    other->buffers.Release();
  }
  return fits();
}

ViewId RenderService::Worker::DrrPick(int c, const std::vector<ViewId>& busy) {
  // `busy` is in ascending id order. The cursor's view goes on while it has credit, then the next
  // busy view with credit (round robin); when none has credit, a new round gives every busy view
  // its quantum (as many rounds at once as the view closest to credit needs).
  const double quantum = s.options_.quantum_ms;
  const size_t first =
      static_cast<size_t>(std::lower_bound(busy.begin(), busy.end(), cursor[c]) - busy.begin());
  while (true) {
    for (size_t i = 0; i < busy.size(); ++i) {
      const ViewId id = busy[(first + i) % busy.size()];
      if (State(id).deficit[c] > 0) {
        cursor[c] = id;
        return id;
      }
    }
    double best = -std::numeric_limits<double>::infinity();
    for (ViewId id : busy) best = std::max(best, State(id).deficit[c]);
    const double rounds = std::floor(-best / quantum) + 1;
    for (ViewId id : busy) State(id).deficit[c] += rounds * quantum;
  }
}

void RenderService::Worker::RunStep(Step& step) {
  const Clock::time_point start = Clock::now();
  callback_ms = 0;
  const ViewId view = step.view;
  step_start = start;
  const auto job_of_step = [&]() -> Job* {
    const bool job_step =
        step.kind == Step::Kind::kRefinePass || step.kind == Step::Kind::kStartRefinement;
    const auto it = jobs.find(view);
    return job_step && it != jobs.end() ? it->second.get() : nullptr;
  };
  step_charged_before = step.kind == Step::Kind::kRefinePass && job_of_step() != nullptr
                            ? job_of_step()->charged_ms
                            : 0;
  step_view = view;
  step_allocations = State(view).buffers.allocations();
  // Exceptions never leave the render thread: one that escapes a pass (e.g. bad_alloc for an
  // absurd image) ends that view's request with an error, and the thread keeps serving.
  Status failure;
  try {
    Execute(step);
  } catch (const std::bad_alloc&) {
    failure = ResourceExhaustedError("rendering failed: out of memory");
  } catch (const std::exception& e) {
    failure = InternalError(std::string("rendering failed: ") + e.what());
  } catch (...) {
    failure = InternalError("rendering failed: unknown exception");
  }
  if (!failure.ok()) {
    if (step.new_job != nullptr) {
      // The request never became the view's job: it ends here.
      DeliverError(ResultOf(*step.new_job), step.new_job->callback, failure);
    } else if (const auto it = jobs.find(view); it != jobs.end()) {
      FailJob(it, failure);
    }
  }
  if (step.kind == Step::Kind::kRefuse) return;
  // Charge the pass's render-thread time (callbacks excluded) to its class and its view.
  const double ms = std::max(0.0, MsSince(start) - callback_ms);
  const int c = step.service_class;
  const double weight = c == kRefinement ? s.options_.refine_share : 1 - s.options_.refine_share;
  class_vt[c] += ms / weight;
  if (const auto it = views.find(view); it != views.end()) it->second->deficit[c] -= ms;
  if (Job* job = job_of_step(); job != nullptr) job->charged_ms += ms;
  CountAllocations();
  std::lock_guard lock(s.mu_);
  (c == kRefinement ? s.stats_.refine_ms : s.stats_.full_frame_ms) += ms;
}

Result<Mirror*> RenderService::Worker::MirrorFor(DatasetKey key) {
  const auto it = datasets.find(key);
  if (it == datasets.end()) return NotFoundError("dataset " + std::to_string(key) + " is removed");
  DatasetState& ds = it->second;
  if (ds.mirror != nullptr) return ds.mirror.get();
  // Created on first use with the dataset's share; any failure (device memory, bad_alloc,
  // kernels) fails the request that needed it, and the next request tries again.
  DeviceOctreeOptions options = s.options_.device_octree;
  options.brick_buffer_bytes = ds.share;  // At least kMinBrickSlots bricks (DeviceOctree).
  options.brick_reads = BrickReads::kResidentOnly;
  auto mirror = std::make_unique<Mirror>();
  const auto create = [&]() -> Status {
    OCTO_ASSIGN_OR_RETURN(mirror->device, DeviceOctree::Create(s.context_, ds.octree, options));
    // The coarsest levels whose pages are in RAM at once (the others are prefetched after the
    // first frame): a view's first frame shows data, not node averages.
    OCTO_RETURN_IF_ERROR(mirror->device->UploadCoarseLevels(kCoarseLevelBytes));
    OCTO_ASSIGN_OR_RETURN(mirror->volume, VolumeRenderer::Create(s.context_, programs,
                                                                 mirror->device.get(), ds.spacing));
    OCTO_ASSIGN_OR_RETURN(
        mirror->slice, SliceRenderer::Create(s.context_, programs, mirror->device.get(), ds.spacing,
                                             s.options_.slice_build_options));
    return Status::Ok();
  };
  Status status;
  try {
    status = create();
  } catch (const std::bad_alloc&) {
    status = ResourceExhaustedError("out of memory");
  } catch (const std::exception& e) {
    status = InternalError(e.what());
  }
  if (!status.ok()) {
    Count(&RenderServiceStats::mirror_failures);
    return status.WithContext("dataset " + std::to_string(key) + ": device mirror");
  }
  Count(&RenderServiceStats::mirrors_created);
  ds.mirror = std::move(mirror);
  return ds.mirror.get();
}

void RenderService::Worker::RequestPages(DatasetKey key, Job* job, PageOutcome* outcome) {
  DatasetState& ds = datasets.at(key);
  const std::vector<uint64_t> pages = ds.mirror->device->TakeMissingPages();
  if (pages.empty()) return;
  outcome->missing = true;
  paging::PageCache* const cache = ds.octree->page_cache();
  // At most half the cache in flight per dataset: pages loaded for a pass must not evict each
  // other before the pass uses them.
  const size_t cap = std::max<size_t>(1, static_cast<size_t>(cache->capacity_pages() / 2));
  const Clock::time_point now = Clock::now();
  std::erase_if(ds.in_flight,
                [now](const auto& item) { return now - item.second >= kInFlightExpiry; });
  for (uint64_t page : pages) {
    if (const auto failed = ds.failed.find(page); failed != ds.failed.end()) {
      if (now - failed->second.when < kFailureHold) {
        outcome->error = failed->second.status.WithContext("brick page " + std::to_string(page));
        continue;
      }
      ds.failed.erase(failed);
    }
    if (ds.in_flight.count(page) != 0) {
      if (job != nullptr) job->awaited.insert(page);
      continue;
    }
    if (ds.in_flight.size() >= cap) continue;
    switch (s.prefetcher_->Request(cache, page)) {
      case paging::PrefetchRequestResult::kQueued:
        Count(&RenderServiceStats::pages_requested);
        [[fallthrough]];
      case paging::PrefetchRequestResult::kDuplicate:
        ds.in_flight.emplace(page, now);
        if (job != nullptr) job->awaited.insert(page);
        break;
      case paging::PrefetchRequestResult::kResident:
        outcome->resident_again = true;
        break;
      case paging::PrefetchRequestResult::kRecentlyFailed:
        outcome->error = IoError("brick page " + std::to_string(page) +
                                 " could not be read (its read failed recently)");
        break;
      case paging::PrefetchRequestResult::kQueueFull:
      case paging::PrefetchRequestResult::kShutDown:
        break;
    }
  }
}

void RenderService::Worker::Execute(Step& step) {
  // A frame's image, or its error (which ends the request).
  const auto finish = [](Result<RenderImage> image, FrameResult* result) {
    if (image.ok()) {
      result->image = std::move(*image);
    } else {
      result->status = image.status();
      result->final = true;
    }
  };

  if (step.kind == Step::Kind::kRefuse) {
    DeliverError(ResultOf(*step.new_job), step.new_job->callback, step.refusal);
    return;
  }
  const ViewId view = step.view;
  ViewState& state = State(view);
  const DatasetKey dataset =
      step.new_job != nullptr ? step.new_job->dataset : jobs.at(view)->dataset;
  Result<Mirror*> mirror_or = MirrorFor(dataset);
  if (!mirror_or.ok()) {
    // The request that needed the mirror ends with its error.
    if (step.new_job != nullptr) {
      DeliverError(ResultOf(*step.new_job), step.new_job->callback, mirror_or.status());
    } else {
      FailJob(jobs.find(view), mirror_or.status());
    }
    return;
  }
  Mirror& mirror = **mirror_or;

  if (step.kind == Step::Kind::kFullFrame) {
    // A full frame is one pass: Sync, kernel, read-back, upload for the next frame.
    Job& job = *step.new_job;
    FrameResult result = ResultOf(job);
    result.final = true;
    if (job.request.kind == FrameKind::kSlice) {
      SliceStats slice_stats;
      finish(mirror.slice->Render(*job.request.slice, job.request.params,
                                  OneSliceFrame(job.options), &slice_stats, &state.buffers),
             &result);
      AddSliceStats(slice_stats, &result.stats);
    } else {
      // Brick-buffer pressure coarsens this view's frames only (options.view).
      finish(mirror.volume->RenderFullFrame(*job.request.camera, job.request.params, job.options,
                                            &result.stats, &state.buffers),
             &result);
    }
    Count(&RenderServiceStats::passes);
    // Missing pages are fetched for the next frames; a full frame never waits for them.
    PageOutcome pages;
    RequestPages(dataset, nullptr, &pages);
    Deliver(job.view, job.callback, std::move(result));
    return;
  }

  if (step.kind == Step::Kind::kStartRefinement) {
    // The new request replaces the view's previous job (an older generation: cancelled).
    if (const auto old = jobs.find(view); old != jobs.end()) {
      EraseJob(old);
      Count(&RenderServiceStats::cancelled);
    }
    Job& job = *step.new_job;
    // Its uploads are reserved for its next pass (progress with a small brick buffer).
    job.options.upload.reserve_for = view;
    if (job.request.kind == FrameKind::kVolume) {
      Result<std::unique_ptr<Refinement>> refinement = mirror.volume->StartRefinement(
          *job.request.camera, job.request.params, job.options, &state.buffers);
      if (!refinement.ok()) {
        DeliverError(ResultOf(job), job.callback, refinement.status());
        return;
      }
      job.refinement = std::move(*refinement);
    }
    jobs[view] = std::move(step.new_job);
  }

  // One refinement pass of the view's job.
  auto it = jobs.find(view);
  if (it == jobs.end()) return;
  Job& job = *it->second;
  FrameResult result = ResultOf(job);
  Status error;                      // The pass's or the read-back's failure.
  std::optional<RenderImage> image;  // Read back only when someone will see it.
  bool stalled = false;              // The pass advanced nothing.
  if (job.request.kind == FrameKind::kSlice) {
    // A slice pass is a complete slice frame; it converges when a frame requests nothing.
    SliceStats slice_stats;
    Result<RenderImage> frame =
        mirror.slice->Render(*job.request.slice, job.request.params, OneSliceFrame(job.options),
                             &slice_stats, &state.buffers);
    Count(&RenderServiceStats::passes);
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
    Result<double> finished = mirror.volume->RefinePass(refinement);
    Count(&RenderServiceStats::passes);
    if (finished.ok()) {
      const bool out_of_passes =
          job.options.max_passes > 0 && refinement.stats().passes >= job.options.max_passes;
      result.final = refinement.complete() || out_of_passes;
      stalled = refinement.stats().samples == samples_before &&
                refinement.stats().finished_fraction == finished_before;
      if (result.final || job.request.progress_images) {
        Result<RenderImage> read = mirror.volume->ReadImage(refinement);
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
  // Bricks whose pages are not in RAM: prefetch them; a pass that advanced nothing because of
  // them waits for their arrival instead of running again at once.
  PageOutcome pages;
  RequestPages(dataset, &job, &pages);
  if (error.ok() && !result.final && !pages.error.ok()) error = pages.error;
  if (!error.ok()) {
    // A failed request ends with its error.
    result.final = true;
    result.status = error;
  } else if (!result.final) {
    if (stalled && pages.missing && !pages.resident_again) {
      job.waiting_io = true;
      job.retry_at = Clock::now() + s.options_.io_retry;
      Count(&RenderServiceStats::io_waits);
    }
    if (!job.request.progress_images) return;
  }
  if (error.ok() && image.has_value()) result.image = std::move(*image);
  std::shared_ptr<FrameCallback> callback = job.callback;
  if (result.final) EraseJob(it);
  Deliver(view, callback, std::move(result));
}

RenderService::RenderService(const ComputeContext* context, ProgramCache* programs,
                             const RenderServiceOptions& options)
    : context_(context), shared_programs_(programs), options_(options) {
  const DeviceInfo& device = context->device();
  const uint64_t global = device.global_memory_bytes;
  device_memory_bytes_ = options.device_memory_bytes;
  if (device_memory_bytes_ == 0) {
    device_memory_bytes_ = global / 5 * 2;
    if (device.type == DeviceType::kCpu)
      device_memory_bytes_ = std::min(device_memory_bytes_, uint64_t{1} << 30);
    device_memory_bytes_ = std::max(device_memory_bytes_, uint64_t{64} << 20);
  }
  frame_memory_bytes_ = options.frame_memory_bytes;
  if (frame_memory_bytes_ == 0)
    frame_memory_bytes_ = std::max(global / 4, options.max_request_bytes);
}

Result<std::unique_ptr<RenderService>> RenderService::Create(ComputeContext context,
                                                             const RenderServiceOptions& options) {
  auto owned = std::make_unique<ComputeContext>(std::move(context));
  std::unique_ptr<RenderService> service(new RenderService(owned.get(), nullptr, options));
  service->owned_context_ = std::move(owned);
  return Start(std::move(service));
}

Result<std::unique_ptr<RenderService>> RenderService::CreateShared(
    const ComputeContext* context, ProgramCache* programs, const RenderServiceOptions& options) {
  if (context == nullptr || programs == nullptr) {
    return InvalidArgumentError("RenderService: null context or program cache");
  }
  return Start(std::unique_ptr<RenderService>(new RenderService(context, programs, options)));
}

Result<std::unique_ptr<RenderService>> RenderService::Start(
    std::unique_ptr<RenderService> service) {
  const RenderServiceOptions& o = service->options_;
  if (!(o.refine_share > 0 && o.refine_share < 1) || !(o.quantum_ms > 0) ||
      !(o.refine_pass_ms >= 0) || !std::isfinite(o.refine_pass_ms) ||
      !std::isfinite(o.quantum_ms) || o.max_request_bytes == 0 || o.io_retry.count() <= 0 ||
      o.admission_timeout.count() < 0 || o.mirror_idle_timeout.count() < 0) {
    return InvalidArgumentError(
        "RenderService: refine_share must lie in (0, 1), quantum_ms, max_request_bytes and "
        "io_retry must be > 0, the timeouts and refine_pass_ms >= 0 (finite)");
  }
  if (o.max_request_bytes > service->frame_memory_bytes_) {
    return InvalidArgumentError(
        "RenderService: max_request_bytes (" + std::to_string(o.max_request_bytes) +
        ") exceeds frame_memory_bytes (" + std::to_string(service->frame_memory_bytes_) + ")");
  }
  try {
    paging::PagePrefetcherOptions prefetch;
    prefetch.io_threads = o.io_threads;
    prefetch.failure_hold = kFailureHold;
    prefetch.on_complete = [raw = service.get()](const paging::PrefetchCompletion& completion) {
      raw->OnPrefetchComplete(completion);
    };
    service->prefetcher_ = std::make_unique<paging::PagePrefetcher>(std::move(prefetch));
  } catch (const std::exception& e) {
    return ResourceExhaustedError(std::string("RenderService: cannot start the I/O threads: ") +
                                  e.what());
  }
  auto init = std::make_shared<std::promise<Status>>();
  std::future<Status> init_done = init->get_future();
  try {
    std::lock_guard lock(service->mu_);
    service->thread_ = std::thread(
        [raw = service.get(), init] { raw->Run([init](Status s) { init->set_value(s); }); });
    service->render_thread_id_ = service->thread_.get_id();
  } catch (const std::exception& e) {
    return ResourceExhaustedError(std::string("RenderService: cannot start the render thread: ") +
                                  e.what());
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
  // The I/O threads last: they may still deliver completions into completions_ meanwhile.
  prefetcher_.reset();
}

DatasetKey RenderService::AddDataset(octree::Octree* octree, const Vec3& spacing_um) {
  std::lock_guard lock(mu_);
  const DatasetKey key = next_dataset_++;
  datasets_.emplace(key, Dataset{octree, spacing_um, 0});
  ++datasets_version_;
  return key;
}

void RenderService::RemoveDataset(DatasetKey dataset) {
  std::vector<std::unique_ptr<FrameRequest>> dropped;  // Destroyed outside the lock.
  std::unique_lock lock(mu_);
  const auto it = datasets_.find(dataset);
  if (it == datasets_.end()) return;
  paging::PageCache* const cache = it->second.octree->page_cache();
  std::set<ViewId> closed;
  for (auto v = views_.begin(); v != views_.end();) {
    if (v->second.dataset != dataset) {
      ++v;
      continue;
    }
    const auto current = v++;
    closed.insert(current->first);
    dropped.push_back(EraseViewLocked(current));
  }
  datasets_.erase(it);
  ++datasets_version_;
  drop_queue_.push_back(dataset);
  work_cv_.notify_all();
  if (std::this_thread::get_id() == render_thread_id_) return;  // From a callback: no waiting.
  // The render thread drops the mirror after its current pass; a callback of the dataset's views
  // may be running meanwhile.
  dropped_cv_.wait(lock, [&] { return dropped_.count(dataset) != 0 || stop_ || !failed_.ok(); });
  callback_cv_.wait(lock, [&] { return closed.count(calling_view_) == 0; });
  dropped_.erase(dataset);
  bool shared_cache = false;
  for (const auto& [key, other] : datasets_) shared_cache |= other.octree->page_cache() == cache;
  lock.unlock();
  if (shared_cache) return;
  // No prefetch uses the cache any more; completions it delivered before are forgotten.
  prefetcher_->Detach(cache);
  lock.lock();
  std::erase_if(completions_,
                [cache](const paging::PrefetchCompletion& c) { return c.cache == cache; });
}

Result<ViewId> RenderService::OpenView(DatasetKey dataset, FrameCallback callback) {
  View view;
  view.dataset = dataset;
  view.callback = std::make_shared<FrameCallback>(std::move(callback));
  view.generation = std::make_shared<std::atomic<uint64_t>>(0);
  if (!*view.callback) return InvalidArgumentError("RenderService::OpenView: empty callback");
  std::lock_guard lock(mu_);
  OCTO_RETURN_IF_ERROR(failed_);
  const auto it = datasets_.find(dataset);
  if (it == datasets_.end()) {
    return NotFoundError("RenderService::OpenView: dataset " + std::to_string(dataset) +
                         " is not added");
  }
  if (it->second.open_views++ == 0) ++datasets_version_;
  const ViewId id = next_view_++;
  views_.emplace(id, std::move(view));
  return id;
}

void RenderService::CloseView(ViewId view) {
  std::unique_ptr<FrameRequest> dropped;  // Destroyed outside the lock.
  std::unique_lock lock(mu_);
  auto it = views_.find(view);
  if (it == views_.end()) return;
  dropped = EraseViewLocked(it);
  // The render thread frees the view's buffers (memory other views may wait for).
  work_cv_.notify_all();
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
    OCTO_RETURN_IF_ERROR(failed_);
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

std::unique_ptr<FrameRequest> RenderService::EraseViewLocked(std::map<ViewId, View>::iterator it) {
  std::unique_ptr<FrameRequest> pending = std::move(it->second.pending);
  // The render thread drops the view's job at its next pass boundary.
  it->second.generation->fetch_add(1, std::memory_order_acq_rel);
  if (const auto ds = datasets_.find(it->second.dataset);
      ds != datasets_.end() && --ds->second.open_views == 0) {
    ++datasets_version_;
  }
  views_.erase(it);
  return pending;
}

RenderServiceStats RenderService::stats() const {
  std::lock_guard lock(mu_);
  return stats_;
}

void RenderService::OnPrefetchComplete(const paging::PrefetchCompletion& completion) {
  {
    std::lock_guard lock(mu_);
    completions_.push_back(completion);
  }
  work_cv_.notify_one();
}

double RenderService::Deliver(ViewId view, const std::shared_ptr<FrameCallback>& callback,
                              FrameResult result) {
  const Clock::time_point start = Clock::now();
  const bool final = result.final;
  {
    std::lock_guard lock(mu_);
    // A view closed meanwhile gets nothing (CloseView promises no callback after it returns).
    if (views_.count(view) == 0) return MsSince(start);
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
      if (const auto it = views_.find(view); it != views_.end()) dropped = EraseViewLocked(it);
    }
  }
  callback_cv_.notify_all();
  return MsSince(start);
}

}  // namespace octoscope::render
