#include "session/view_session.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "dataset/dataset_description.h"
#include "dataset/display_defaults.h"
#include "encode/image_encoder.h"
#include "protocol/dataset_json.h"
#include "protocol/frame_header.h"
#include "render/camera.h"
#include "volume/value_map.h"

namespace octoscope::session {
namespace {

using protocol::ViewId;
constexpr ViewId kAllViews[] = {ViewId::k3d, ViewId::kX, ViewId::kY, ViewId::kZ};
// Outbox views of screenshots: beyond the four views, one per screenshot id modulo this.
constexpr int kScreenshotViewBase = 16;
constexpr int kScreenshotViewCount = 64;

size_t Index(ViewId view) { return static_cast<size_t>(view); }

double Elapsed(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

// The volume's box in µm along each axis.
std::array<double, 3> Extent(const dataset::Dataset& dataset) {
  const auto spacing = dataset.spacing_um();
  const auto& size = dataset.info().size;
  return {size[0] * spacing[0], size[1] * spacing[1], size[2] * spacing[2]};
}

std::array<double, 3> Clamped(const std::array<double, 3>& p, const std::array<double, 3>& hi) {
  return {std::clamp(p[0], 0.0, hi[0]), std::clamp(p[1], 0.0, hi[1]), std::clamp(p[2], 0.0, hi[2])};
}

}  // namespace

std::shared_ptr<ViewSession> ViewSession::Create(const SessionContext& context,
                                                 std::shared_ptr<SessionSink> sink,
                                                 std::string session_id,
                                                 const ViewSessionOptions& options) {
  auto session = std::shared_ptr<ViewSession>(
      new ViewSession(context, std::move(sink), std::move(session_id), options));
  if (context.metrics != nullptr) context.metrics->SessionOpened();
  return session;
}

ViewSession::ViewSession(const SessionContext& context, std::shared_ptr<SessionSink> sink,
                         std::string id, const ViewSessionOptions& options)
    : context_(context),
      options_(options),
      id_(std::move(id)),
      sink_(std::move(sink)),
      outbox_(
          [sink = sink_, metrics = context.metrics](std::vector<uint8_t> bytes) {
            if (metrics != nullptr && bytes.size() > 25 && bytes[25] <= 3) {
              metrics->FrameSent(static_cast<protocol::FrameTier>(bytes[25]), bytes.size());
            }
            sink->SendBinary(std::move(bytes));
          },
          options.window),
      jpeg_interactive_(options.jpeg_interactive),
      jpeg_final_(options.jpeg_final) {
  for (ViewId v : kAllViews) {
    views_[Index(v)].id = v;
    views_[Index(v)].policy = FramePolicy(context.frame_policy);
  }
}

ViewSession::~ViewSession() { Close(); }

void ViewSession::Close() {
  std::vector<render::ViewId> to_close;
  std::vector<TimerQueue::TimerId> timers;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    closed_ = true;
    for (View& view : views_) {
      if (view.render_view != 0) to_close.push_back(view.render_view);
      view.render_view = 0;
    }
    for (const Screenshot& shot : screenshots_) to_close.push_back(shot.render_view);
    screenshots_.clear();
    for (auto* timer : {&wake_timer_, &dataset_event_timer_, &data_refresh_timer_, &stats_timer_}) {
      if (*timer) timers.push_back(**timer);
      timer->reset();
    }
  }
  // Outside mu_: CloseView waits for a callback of the view, which may be waiting for mu_.
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
  for (TimerQueue::TimerId timer : timers) context_.timers->Cancel(timer);
  dataset::Subscription subscription;
  {
    std::lock_guard<std::mutex> lock(mu_);
    subscription = std::move(dataset_subscription_);
  }
  subscription.Reset();
  const auto base = reinterpret_cast<uintptr_t>(this);
  for (int k = 0; k < kScreenshotViewBase + kScreenshotViewCount; ++k) {
    context_.encoders->Forget(base + k);
  }
  outbox_.Close();
  if (context_.metrics != nullptr) {
    context_.metrics->FramesDropped(outbox_.stats().dropped - last_stats_.dropped);
    context_.metrics->SessionClosed();
  }
}

void ViewSession::HandleText(std::string_view text) {
  std::string type;
  auto message = protocol::ParseClientMessage(text, &type);
  if (message.ok()) {
    OnMessage(std::move(*message));
    return;
  }
  bool fatal;
  {
    std::lock_guard<std::mutex> lock(mu_);
    fatal = ++malformed_ > protocol::kMaxMalformedMessages;
  }
  SendError(message.status().message(), type, fatal);
  if (fatal) sink_->Close(1008, "too many malformed messages");
}

void ViewSession::SendError(std::string_view message, std::string_view request, bool fatal) {
  sink_->SendText(protocol::ErrorEvent(message, request, fatal));
}

void ViewSession::OnMessage(protocol::ClientMessage message) {
  const std::string type(protocol::MessageTypeName(message));
  if (auto* hello = std::get_if<protocol::HelloMessage>(&message)) {
    (void)hello;
    sink_->SendText(protocol::WelcomeEvent(context_.server_version, id_));
    return;
  }
  if (auto* open = std::get_if<protocol::OpenMessage>(&message)) {
    OnOpen(*open);
    return;
  }
  if (auto* ping = std::get_if<protocol::PingMessage>(&message)) {
    sink_->SendText(protocol::PongEvent(ping->t));
    return;
  }
  if (auto* ack = std::get_if<protocol::AckMessage>(&message)) {
    outbox_.OnAck(ack->frame);
    return;
  }
  std::unique_lock<std::mutex> lock(mu_);
  if (closed_) return;
  const auto now = Clock::now();
  if (auto* interaction = std::get_if<protocol::InteractionMessage>(&message)) {
    for (View& view : views_) view.policy.OnInteraction(interaction->active, now);
    PumpLocked();
    return;
  }
  if (auto* quality = std::get_if<protocol::QualityMessage>(&message)) {
    if (quality->jpeg_interactive) jpeg_interactive_ = *quality->jpeg_interactive;
    if (quality->jpeg_final) jpeg_final_ = *quality->jpeg_final;
    if (quality->lossless_final) lossless_final_ = *quality->lossless_final;
    if (quality->lod_bias && *quality->lod_bias != lod_bias_) {
      lod_bias_ = *quality->lod_bias;
      if (state_) ChangedLocked({ViewId::k3d, ViewId::kX, ViewId::kY, ViewId::kZ});
    }
    return;
  }
  if (auto* viewport = std::get_if<protocol::ViewportMessage>(&message)) {
    View& view = views_[Index(viewport->view)];
    const protocol::PixelSize pixels = protocol::ViewportPixels(*viewport);
    if (pixels.width != view.pixels.width || pixels.height != view.pixels.height) {
      view.pixels = pixels;
      view.policy.Invalidate(now);
      PumpLocked();
    }
    return;
  }
  if (!state_ || dataset_ == nullptr) {
    lock.unlock();
    SendError("no dataset is open (send \"open\" first)", type, false);
    return;
  }
  if (auto* camera = std::get_if<protocol::CameraMessage>(&message)) {
    state_->camera = camera->camera;
    ChangedLocked({ViewId::k3d});
    return;
  }
  if (auto* params = std::get_if<protocol::ParamsMessage>(&message)) {
    auto applied = protocol::ApplyParams(params->params_json, state_->params);
    if (!applied.ok()) {
      lock.unlock();
      SendError(applied.status().message(), type, false);
      return;
    }
    state_->params = std::move(*applied);
    auto_contrast_pending_ = false;  // The client chose its own parameters.
    ChangedLocked({ViewId::k3d, ViewId::kX, ViewId::kY, ViewId::kZ});
    return;
  }
  if (auto* slices = std::get_if<protocol::SlicesMessage>(&message)) {
    const auto clamped = Clamped(slices->position_um, Extent(dataset_->dataset()));
    state_->slice_position_um = clamped;
    ChangedLocked({ViewId::kX, ViewId::kY, ViewId::kZ});
    if (clamped != slices->position_um) {
      sink_->SendText(protocol::StateEvent(*state_, state_version_));
    }
    return;
  }
  if (auto* shot = std::get_if<protocol::ScreenshotMessage>(&message)) {
    const View& view = views_[Index(shot->view)];
    const auto key = dataset_->render_key();
    if (!key || view.pixels.width == 0) {
      lock.unlock();
      SendError(key ? "the view has no viewport (send \"viewport\" first)"
                    : "the dataset cannot be rendered yet",
                type, false);
      return;
    }
    const uint32_t id = shot->id;
    auto render_view = context_.renderer->OpenView(
        *key, [weak = weak_from_this(), id](render::FrameResult result) {
          if (auto self = weak.lock()) self->OnScreenshotResult(id, std::move(result));
        });
    if (!render_view.ok()) {
      lock.unlock();
      SendError(render_view.status().message(), type, false);
      return;
    }
    FrameOrder order{1, true, static_cast<double>(shot->scale), view.content_version};
    auto request = RequestLocked(view, order);
    Status submitted = request.ok() ? Status::Ok() : request.status();
    if (request.ok()) {
      request->progress_images = false;
      screenshots_.push_back({id, shot->view, *render_view, state_version_});
      submitted = context_.renderer->Submit(*render_view, std::move(*request));
    }
    if (!submitted.ok()) {
      std::erase_if(screenshots_, [&](const Screenshot& s) { return s.id == id; });
      lock.unlock();
      context_.renderer->CloseView(*render_view);
      SendError(submitted.message(), type, false);
    }
    return;
  }
}

void ViewSession::OnOpen(const protocol::OpenMessage& message) {
  if (options_.may_open && !options_.may_open(message.dataset)) {
    SendError("no dataset '" + message.dataset + "'", "open", false);
    return;
  }
  auto use = context_.datasets->Use(message.dataset);
  if (!use.ok()) {
    SendError(use.status().message(), "open", false);
    return;
  }
  const dataset::Dataset& dataset = (*use)->dataset();
  const volume::VolumeInfo& info = dataset.info();
  const auto spacing = dataset.spacing_um();
  const dataset::Histogram histogram = dataset.histogram();
  const render::Box3 bounds =
      render::PhysicalBounds(info.size, render::Vec3{spacing[0], spacing[1], spacing[2]});

  // The dataset's defaults (docs/protocol.md "State document"), then what the client sent.
  auto camera = render::Camera::Standard(render::StandardView::kIso,
                                         render::Projection::kPerspective, bounds, 1, 1);
  if (!camera.ok()) {
    SendError(camera.status().message(), "open", false);
    return;
  }
  protocol::ViewState state{*camera,
                            dataset::DefaultDisplayParams(info, volume::StoredTypeFor(info.dtype),
                                                          &histogram, render::RenderMode::kMip),
                            {},
                            std::nullopt};
  const auto extent = Extent(dataset);
  state.slice_position_um = {extent[0] / 2, extent[1] / 2, extent[2] / 2};
  bool client_params = false;
  if (message.state) {
    const protocol::StateUpdate& update = *message.state;
    if (update.camera) state.camera = *update.camera;
    if (update.params_json) {
      auto params = protocol::ApplyParams(*update.params_json, state.params);
      if (!params.ok()) {
        SendError("state.params: " + params.status().message(), "open", false);
        return;
      }
      state.params = std::move(*params);
      client_params = true;
    }
    if (update.slice_position_um) {
      state.slice_position_um = Clamped(*update.slice_position_um, extent);
    }
    if (update.layout) state.maximized = update.layout->maximized;
  }

  std::vector<render::ViewId> to_close;
  dataset::Subscription old_subscription;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    for (View& view : views_) {
      if (view.render_view != 0) to_close.push_back(view.render_view);
      view.render_view = 0;
    }
    old_subscription = std::move(dataset_subscription_);
    dataset_ = *use;
    state_ = std::move(state);
    auto_contrast_pending_ = !client_params && !dataset.status().histogram_complete;
    seen_planes_ = dataset.status().planes_inserted;
    ++state_version_;
    sink_->SendText(protocol::OpenedEvent(DatasetJsonLocked(), *state_, state_version_));
    for (View& view : views_) view.policy.OnChange(++view.content_version, Clock::now());
    AttachRenderViewsLocked();
    PumpLocked();
  }
  old_subscription.Reset();
  for (render::ViewId view : to_close) context_.renderer->CloseView(view);
  // Subscribed last: the callback takes mu_.
  auto subscription = (*use)->dataset().OnChange([weak = weak_from_this()] {
    if (auto self = weak.lock()) self->OnDatasetChange();
  });
  std::lock_guard<std::mutex> lock(mu_);
  if (!closed_ && dataset_ == *use) dataset_subscription_ = std::move(subscription);
}

void ViewSession::ChangedLocked(std::initializer_list<ViewId> views) {
  ++state_version_;
  const auto now = Clock::now();
  for (ViewId v : views) {
    View& view = views_[Index(v)];
    view.policy.OnChange(++view.content_version, now);
  }
  PumpLocked();
}

void ViewSession::AttachRenderViewsLocked() {
  if (dataset_ == nullptr) return;
  bool missing = false;
  for (const View& view : views_) missing |= view.render_view == 0;
  if (!missing) return;
  const auto key = dataset_->render_key();
  if (!key) return;
  for (View& view : views_) {
    if (view.render_view != 0) continue;
    auto opened = context_.renderer->OpenView(
        *key, [weak = weak_from_this(), v = view.id](render::FrameResult result) {
          if (auto self = weak.lock()) self->OnRenderResult(v, std::move(result));
        });
    if (!opened.ok()) {
      SendError(opened.status().message(), "open", false);
      return;
    }
    view.render_view = *opened;
    view.policy.Invalidate(Clock::now());
  }
}

void ViewSession::PumpLocked() {
  if (closed_ || !state_) return;
  const auto now = Clock::now();
  std::optional<Clock::time_point> earliest;
  for (View& view : views_) {
    if (view.render_view == 0 || view.pixels.width == 0) continue;
    std::optional<Clock::time_point> wake;
    PumpViewLocked(view, now, &wake);
    if (wake && (!earliest || *wake < *earliest)) earliest = wake;
  }
  if (earliest) {
    ArmTimerLocked(&wake_timer_, *earliest, [](ViewSession& s) { s.PumpLocked(); });
  }
}

void ViewSession::PumpViewLocked(View& view, Clock::time_point now,
                                 std::optional<Clock::time_point>* wake) {
  auto order = view.policy.Poll(now, wake);
  if (!order) return;
  auto request = RequestLocked(view, *order);
  Status status = request.ok() ? Status::Ok() : request.status();
  if (request.ok()) {
    view.order_sequence = order->sequence;
    view.order_state_version = state_version_;
    view.order_refine = order->refine;
    view.order_submitted = now;
    status = context_.renderer->Submit(view.render_view, std::move(*request));
  }
  if (!status.ok()) {
    view.policy.OnFrameDone(order->sequence, false, 0);
    SendError(status.message(), "render", false);
  }
}

Result<render::FrameRequest> ViewSession::RequestLocked(const View& view,
                                                        const FrameOrder& order) const {
  const int width = std::max(1, static_cast<int>(std::lround(view.pixels.width * order.scale)));
  const int height = std::max(1, static_cast<int>(std::lround(view.pixels.height * order.scale)));
  render::FrameRequest request;
  request.params = state_->params;
  request.sequence = order.sequence;
  render::FrameOptions options;
  options.mode = order.refine ? render::FrameMode::kRefine : render::FrameMode::kFullFrame;
  options.lod_bias = lod_bias_;
  // Interactive frames shrink first (FramePolicy); once at the smallest scale, the renderer
  // coarsens the level of detail to hold the frame time.
  if (!order.refine && view.policy.scale() <= context_.frame_policy.min_scale) {
    options.target_frame_ms = context_.frame_policy.target_frame_ms;
  }
  request.options = options;
  if (view.id == ViewId::k3d) {
    request.kind = render::FrameKind::kVolume;
    auto camera = protocol::CameraForSize(state_->camera, width, height);
    if (!camera.ok()) return camera.status();
    request.camera = *camera;
  } else {
    request.kind = render::FrameKind::kSlice;
    render::SliceView slice;
    slice.axis = static_cast<int>(view.id) - 1;
    slice.position_um = state_->slice_position_um[slice.axis];
    slice.width = width;
    slice.height = height;
    request.slice = slice;
  }
  return request;
}

void ViewSession::OnRenderResult(ViewId v, render::FrameResult result) {
  EncodeJob job;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    View& view = views_[Index(v)];
    if (result.view != view.render_view || result.sequence != view.order_sequence) return;
    if (!result.status.ok()) {
      if (result.final) view.policy.OnFrameDone(result.sequence, false, 0);
      SendError(result.status.message(), "render", false);
      PumpLocked();
      return;
    }
    const auto tier = !view.order_refine ? protocol::FrameTier::kInteractive
                      : result.final     ? protocol::FrameTier::kFinal
                                         : protocol::FrameTier::kRefining;
    // The policy holds the frame rate the user sees: submit to result, so that the time a frame
    // waits for other views' frames on the shared device counts too (N busy clients each shrink
    // their frames instead of each waiting N times longer).
    if (result.final) {
      view.policy.OnFrameDone(result.sequence, true,
                              std::max(result.stats.ms_total, Elapsed(view.order_submitted)));
    }
    if (context_.metrics != nullptr) {
      context_.metrics->Rendered(tier, result.stats.ms_total, result.stats.bricks_uploaded);
    }
    bricks_pending_ = result.stats.bricks_unavailable;
    const auto now = Clock::now();
    bool send = true;
    if (tier == protocol::FrameTier::kRefining) {
      // Progress frames at most every progress_interval: the final one is what matters.
      send = now - view.last_progress >= options_.progress_interval;
      if (send) view.last_progress = now;
    }
    PumpLocked();
    if (!send || result.image.width <= 0 || result.image.height <= 0) return;
    job.outbox_view = static_cast<int>(v);
    job.sequence = result.sequence;
    job.png = tier == protocol::FrameTier::kFinal && lossless_final_;
    job.jpeg_quality = tier == protocol::FrameTier::kInteractive ? jpeg_interactive_
                       : tier == protocol::FrameTier::kRefining  ? options_.jpeg_refining
                                                                 : jpeg_final_;
    protocol::FrameHeader& header = job.header;
    header.state_version = view.order_state_version;
    header.view = v;
    header.tier = tier;
    header.final = tier == protocol::FrameTier::kFinal;
    header.progress = view.order_refine
                          ? static_cast<float>(std::clamp(result.stats.finished_fraction, 0.0, 1.0))
                          : 0.f;
    if (header.final) header.progress = 1.f;
    header.render_ms = static_cast<float>(std::max(0.0, result.stats.ms_total));
    header.lod_bias = static_cast<float>(result.stats.lod_bias_used);
    job.image = std::move(result.image);
  }
  const uint64_t key = reinterpret_cast<uintptr_t>(this) + job.outbox_view;
  context_.encoders->Submit(key, [weak = weak_from_this(), job = std::move(job)]() mutable {
    if (auto self = weak.lock()) self->Encode(std::move(job));
  });
}

void ViewSession::OnScreenshotResult(uint32_t id, render::FrameResult result) {
  if (!result.final) return;
  EncodeJob job;
  render::ViewId render_view = 0;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    auto it = std::find_if(screenshots_.begin(), screenshots_.end(),
                           [&](const Screenshot& s) { return s.id == id; });
    if (it == screenshots_.end()) return;
    const Screenshot shot = *it;
    screenshots_.erase(it);
    render_view = shot.render_view;
    if (result.status.ok() && result.image.width > 0) {
      job.outbox_view = kScreenshotViewBase + static_cast<int>(id % kScreenshotViewCount);
      job.sequence = ++screenshot_sequence_;
      job.png = true;
      protocol::FrameHeader& header = job.header;
      header.state_version = shot.state_version;
      header.view = shot.view;
      header.tier = protocol::FrameTier::kScreenshot;
      header.final = true;
      header.progress = 1.f;
      header.render_ms = static_cast<float>(std::max(0.0, result.stats.ms_total));
      header.lod_bias = static_cast<float>(result.stats.lod_bias_used);
      header.screenshot_id = id;
      job.image = std::move(result.image);
      if (context_.metrics != nullptr) {
        context_.metrics->Rendered(protocol::FrameTier::kScreenshot, result.stats.ms_total,
                                   result.stats.bricks_uploaded);
      }
    }
  }
  // From the view's own callback CloseView does not wait.
  context_.renderer->CloseView(render_view);
  if (!result.status.ok()) {
    SendError("screenshot " + std::to_string(id) + ": " + result.status.message(), "screenshot",
              false);
    return;
  }
  const uint64_t key = reinterpret_cast<uintptr_t>(this) + job.outbox_view;
  context_.encoders->Submit(key, [weak = weak_from_this(), job = std::move(job)]() mutable {
    if (auto self = weak.lock()) self->Encode(std::move(job));
  });
}

void ViewSession::Encode(EncodeJob job) {
  const auto start = Clock::now();
  std::vector<uint8_t> png;  // Owns PNG bytes; JPEG bytes live in the leased encoder.
  std::optional<encode::JpegEncoderPool::Lease> encoder;
  Result<std::span<const uint8_t>> image = InternalError("not encoded");
  if (job.png) {
    // The pixels as shown (over black), opaque: exactly what the JPEG frames approximate.
    encode::Rgba8Image rgba = encode::ToRgba8(job.image.rgba.data(), job.image.width,
                                              job.image.height, encode::AlphaMode::kOverBlack);
    for (size_t i = 3; i < rgba.pixels.size(); i += 4) rgba.pixels[i] = 255;
    auto encoded = encode::EncodePng(rgba);
    if (encoded.ok()) png = std::move(*encoded);
    image = encoded.ok() ? Result<std::span<const uint8_t>>(std::span<const uint8_t>(png))
                         : Result<std::span<const uint8_t>>(encoded.status());
  } else {
    auto lease = context_.jpeg->Acquire();
    if (!lease.ok()) {
      image = lease.status();
    } else {
      encoder.emplace(std::move(*lease));
      // Final frames get the exact DCT; interactive and progress frames the fast one.
      image = (*encoder)->Encode(job.image.rgba.data(), job.image.width, job.image.height,
                                 job.jpeg_quality, job.header.final);
    }
  }
  if (!image.ok()) {
    SendError("encoding a frame: " + image.status().message(), "render", false);
    return;
  }
  const double encode_ms = Elapsed(start);
  protocol::FrameHeader header = job.header;
  header.format = job.png ? protocol::ImageFormat::kPng : protocol::ImageFormat::kJpeg;
  header.lossless = job.png;
  header.width = static_cast<uint16_t>(job.image.width);
  header.height = static_cast<uint16_t>(job.image.height);
  header.encode_ms = static_cast<float>(encode_ms);
  auto message = protocol::BuildFrameMessage(header, *image);
  if (!message.ok()) {
    SendError("framing: " + message.status().message(), "render", false);
    return;
  }
  if (context_.metrics != nullptr) context_.metrics->Encoded(header.format, encode_ms);
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (closed_) return;
    ArmTimerLocked(&stats_timer_, Clock::now() + options_.stats_interval,
                   [](ViewSession& s) { s.SendStatsLocked(); });
  }
  outbox_.Offer(OutgoingFrame{job.outbox_view, job.sequence, header.final, std::move(*message)});
}

void ViewSession::OnDatasetChange() {
  std::lock_guard<std::mutex> lock(mu_);
  if (closed_ || dataset_ == nullptr) return;
  AttachRenderViewsLocked();
  const auto now = Clock::now();
  ArmTimerLocked(&dataset_event_timer_, now + options_.dataset_event_interval,
                 [](ViewSession& s) { s.SendDatasetEventLocked(); });
  if (dataset_->dataset().status().planes_inserted != seen_planes_) {
    ArmTimerLocked(&data_refresh_timer_, now + options_.data_refresh_interval,
                   [](ViewSession& s) { s.RefreshDataLocked(); });
  }
  PumpLocked();
}

void ViewSession::SendDatasetEventLocked() {
  if (dataset_ == nullptr) return;
  sink_->SendText(protocol::DatasetEvent(DatasetJsonLocked()));
}

void ViewSession::RefreshDataLocked() {
  if (dataset_ == nullptr || !state_) return;
  const dataset::DatasetStatus status = dataset_->dataset().status();
  seen_planes_ = status.planes_inserted;
  if (auto_contrast_pending_) {
    // The histogram grows with the data: keep the opening auto-contrast up to date until the
    // client sets its own parameters or every voxel is counted.
    const dataset::Histogram histogram = dataset_->dataset().histogram();
    bool changed = false;
    for (int c = 0;
         c < histogram.channels() && c < static_cast<int>(state_->params.channels.size()); ++c) {
      const render::ChannelParams before = state_->params.channels[c];
      if (dataset::AutoContrast(histogram, c, state_->params.channels[c])) {
        changed |= before.window != state_->params.channels[c].window ||
                   before.level != state_->params.channels[c].level;
      }
    }
    auto_contrast_pending_ = !status.histogram_complete;
    if (changed) {
      ++state_version_;
      sink_->SendText(protocol::StateEvent(*state_, state_version_));
      const auto now = Clock::now();
      for (View& view : views_) view.policy.OnChange(++view.content_version, now);
      PumpLocked();
      return;
    }
  }
  for (View& view : views_) view.policy.OnDataChange(++view.content_version);
  PumpLocked();
}

void ViewSession::SendStatsLocked() {
  const OutboxStats stats = outbox_.stats();
  if (context_.metrics != nullptr && stats.dropped > last_stats_.dropped) {
    context_.metrics->FramesDropped(stats.dropped - last_stats_.dropped);
  }
  if (stats.sent == last_stats_.sent && stats.dropped == last_stats_.dropped) return;
  last_stats_ = stats;
  sink_->SendText(
      protocol::StatsEvent({stats.sent, stats.dropped, stats.bytes_sent, bricks_pending_}));
}

void ViewSession::ArmTimerLocked(std::optional<TimerQueue::TimerId>* timer, Clock::time_point when,
                                 void (*fire)(ViewSession&)) {
  if (*timer) return;  // Armed: it fires no later than a new one would matter.
  *timer = context_.timers->Schedule(when, [weak = weak_from_this(), timer, fire] {
    auto self = weak.lock();
    if (self == nullptr) return;
    std::lock_guard<std::mutex> lock(self->mu_);
    timer->reset();
    if (!self->closed_) fire(*self);
  });
}

std::string ViewSession::DatasetJsonLocked() const {
  return protocol::DatasetJson(dataset::Describe(dataset_->dataset()));
}

}  // namespace octoscope::session
