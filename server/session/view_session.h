// ViewSession: one browser tab's viewing session (docs/protocol.md): the dataset it views, its
// state (camera, render parameters, slice positions, layout, quality preferences), its four views
// (3-D, x, y, z) and their frames. It turns client messages into render requests following each
// view's FramePolicy, the render service's images into encoded frames (JPEG, or PNG for lossless
// finals and screenshots) on the shared encoder threads, and those into binary messages through
// an Outbox (at most 2 unacknowledged frames; a stalled client only fills its own mailboxes).
//
// The session knows nothing of sockets: it talks to its client through a SessionSink (the app
// adapts the net layer's WebSocket to it). Dataset events (construction and streaming progress)
// go out at most 4 per second; new data re-renders the views at most every 250 ms.
//
// Threads: HandleText and Close run on the connection's strand; render results arrive on the
// render thread, encoded frames on encoder threads, timers on the timer thread. Nothing here
// blocks any of them for long: render submissions and outbox offers take small mutexes, encoding
// runs on the encoder pool (latest image per view wins), disk work stays in the dataset layer.
//
// Thread safety: every public member function is thread-safe. A ViewSession must be owned by a
// std::shared_ptr (callbacks hold weak references); Close must be called before the last
// reference goes (it closes the render views and unsubscribes).
#ifndef OCTOSCOPE_SESSION_VIEW_SESSION_H_
#define OCTOSCOPE_SESSION_VIEW_SESSION_H_

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "encode/jpeg_encoder.h"
#include "protocol/view_id.h"
#include "protocol/ws_messages.h"
#include "render/render_service.h"
#include "session/dataset_hub.h"
#include "session/frame_policy.h"
#include "session/outbox.h"
#include "session/server_metrics.h"
#include "util/latest_wins_executor.h"
#include "util/timer_queue.h"

namespace octoscope::session {

// How a session reaches its client. Every call may come from any thread and must not block.
class SessionSink {
 public:
  virtual ~SessionSink() = default;
  virtual void SendText(std::string text) = 0;
  virtual void SendBinary(std::vector<uint8_t> bytes) = 0;
  // Ends the connection (WebSocket close code and a one-line reason).
  virtual void Close(uint16_t code, std::string reason) = 0;
};

// The services every session shares; all must outlive the sessions.
struct SessionContext {
  render::RenderService* renderer = nullptr;
  DatasetHub* datasets = nullptr;
  LatestWinsExecutor* encoders = nullptr;  // Encoding jobs (latest image per view wins).
  encode::JpegEncoderPool* jpeg = nullptr;
  TimerQueue* timers = nullptr;
  ServerMetrics* metrics = nullptr;
  std::string server_version;
  FramePolicyOptions frame_policy;
  // A shared server's limits and links (docs/server.md, "Configuration"; `serve` fills them).
  int max_sessions = 64;
  int max_participants = 16;  // Per session.
  // A session nobody is connected to is released after this long (datasets: DatasetHub).
  std::chrono::seconds idle_timeout{900};
  std::string public_url;           // Base of share and view links, with a trailing slash.
  std::filesystem::path state_dir;  // Durable state (view links).
};

struct ViewSessionOptions {
  int window = 2;  // Unacknowledged frames.
  int jpeg_interactive = 70;
  int jpeg_refining = 80;
  int jpeg_final = 92;
  std::chrono::milliseconds progress_interval{250};  // Between progress frames of a view.
  std::chrono::milliseconds dataset_event_interval{250};
  std::chrono::milliseconds data_refresh_interval{250};
  std::chrono::milliseconds stats_interval{1000};
  // Whether this connection may open the dataset `id` (its principal's access); null = any. A
  // dataset it may not open is answered like one that does not exist.
  std::function<bool(std::string_view id)> may_open;
};

class ViewSession : public std::enable_shared_from_this<ViewSession> {
 public:
  static std::shared_ptr<ViewSession> Create(const SessionContext& context,
                                             std::shared_ptr<SessionSink> sink,
                                             std::string session_id,
                                             const ViewSessionOptions& options = {});
  ~ViewSession();
  ViewSession(const ViewSession&) = delete;
  ViewSession& operator=(const ViewSession&) = delete;

  // One client text message. Malformed ones get an error event; after
  // protocol::kMaxMalformedMessages of them the connection is closed (1008).
  void HandleText(std::string_view text);
  // The connection ended: closes the render views, forgets pending work. Idempotent.
  void Close();

  const std::string& id() const { return id_; }
  OutboxStats outbox_stats() const { return outbox_.stats(); }

 private:
  struct View {
    protocol::ViewId id = protocol::ViewId::k3d;
    render::ViewId render_view = 0;  // 0 until the dataset is renderable.
    FramePolicy policy;
    protocol::PixelSize pixels;    // Full-resolution size; 0 x 0 = not shown.
    uint64_t content_version = 0;  // FramePolicy's versions: state changes and new data.
    // The order in flight: its state version, kind and scale.
    uint64_t order_sequence = 0;
    uint64_t order_state_version = 0;
    bool order_refine = false;
    Clock::time_point order_submitted{};
    Clock::time_point last_progress{};
  };
  struct Screenshot {
    uint32_t id = 0;
    protocol::ViewId view = protocol::ViewId::k3d;
    render::ViewId render_view = 0;
    uint64_t state_version = 0;
  };
  // An image on its way to the encoder.
  struct EncodeJob {
    int outbox_view = 0;
    uint64_t sequence = 0;
    protocol::FrameHeader header;
    bool png = false;
    int jpeg_quality = 90;
    render::RenderImage image;
  };

  ViewSession(const SessionContext& context, std::shared_ptr<SessionSink> sink, std::string id,
              const ViewSessionOptions& options);

  void OnMessage(protocol::ClientMessage message);
  void OnOpen(const protocol::OpenMessage& message);
  void SendError(std::string_view message, std::string_view request, bool fatal);

  // The rest REQUIRES mu_ held unless named otherwise.
  // State changed for `views`: a new state version, the policies told, frames submitted.
  void ChangedLocked(std::initializer_list<protocol::ViewId> views);
  // Submits what each view's policy orders now and arms the wake timer.
  void PumpLocked();
  void PumpViewLocked(View& view, Clock::time_point now, std::optional<Clock::time_point>* wake);
  // The render request of `view` for `order`, or why there is none.
  Result<render::FrameRequest> RequestLocked(const View& view, const FrameOrder& order) const;
  // Opens the views in the render service once the dataset can be rendered.
  void AttachRenderViewsLocked();
  void SendDatasetEventLocked();
  // New data became visible: re-render (and keep the opening auto-contrast current).
  void RefreshDataLocked();
  void SendStatsLocked();
  // Runs `fire` (with mu_ held) at `when` unless `timer` is armed already.
  void ArmTimerLocked(std::optional<TimerQueue::TimerId>* timer, Clock::time_point when,
                      void (*fire)(ViewSession&));
  std::string DatasetJsonLocked() const;

  // Render thread.
  void OnRenderResult(protocol::ViewId view, render::FrameResult result);
  void OnScreenshotResult(uint32_t id, render::FrameResult result);
  // Encoder threads.
  void Encode(EncodeJob job);
  // Dataset threads.
  void OnDatasetChange();

  const SessionContext context_;
  const ViewSessionOptions options_;
  const std::string id_;
  std::shared_ptr<SessionSink> sink_;
  Outbox outbox_;

  mutable std::mutex mu_;  // Guards everything below.
  bool closed_ = false;
  int malformed_ = 0;
  std::shared_ptr<DatasetUse> dataset_;
  dataset::Subscription dataset_subscription_;
  uint64_t seen_planes_ = 0;  // Planes inserted when the views last re-rendered.
  uint64_t state_version_ = 0;
  std::optional<protocol::ViewState> state_;
  int jpeg_interactive_;
  int jpeg_final_;
  bool lossless_final_ = false;
  double lod_bias_ = 0;
  std::array<View, protocol::kViewCount> views_;
  std::vector<Screenshot> screenshots_;
  uint64_t screenshot_sequence_ = 0;
  bool auto_contrast_pending_ = false;  // Follow the growing histogram (see RefreshDataLocked).
  std::optional<TimerQueue::TimerId> wake_timer_;
  std::optional<TimerQueue::TimerId> dataset_event_timer_;
  std::optional<TimerQueue::TimerId> data_refresh_timer_;
  std::optional<TimerQueue::TimerId> stats_timer_;
  OutboxStats last_stats_;
  uint64_t bricks_pending_ = 0;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_VIEW_SESSION_H_
