// ViewSession: one viewing session (docs/protocol.md): the dataset it views, its shared state
// (camera, render parameters, slice positions, layout), its four views (3-D, x, y, z) and the
// participants that watch it (session/participant.h: an owner, controllers, viewers). It turns
// participants' messages into state changes (refused for viewers) and render requests following
// the views' FramePolicy, the render service's images into encoded frames (JPEG, or PNG for
// lossless finals and screenshots) on the shared encoder threads, and those into binary messages
// through each participant's own Outbox.
//
// Rendering is shared: per view, the participants whose viewports have the same aspect ratio
// (session/aspect_groups.h) form a group with ONE render view and ONE FramePolicy, rendered at
// the largest member's size; smaller members get the image area-averaged down to their own size,
// each at its own JPEG quality. A slow participant only fills its own mailboxes.
//
// Sharing: the owner creates share links (registered in the SessionRegistry), revokes them
// (closing those who joined through them, 4001), changes roles and removes participants. State
// changes are announced to the other participants (`state` events), the participant list with
// who is driving to everyone (`participants`). `view_save` stores the state in the ViewStore.
//
// Grants (docs/server.md, "Threat model"): the session is owned under a grant (its owner's user,
// or the view link it was opened through); each participant acts under the owner's grant or the
// share link it joined through. A participant opens only datasets its grant covers (a share link
// covers the dataset it was made for), share links are made only under grants without a share
// link in their chain, and view links record the grant they were made under. Revalidate() ends
// what no longer holds: the whole session (4005) when the owner's grant ended, expired share
// links (4001 for those who joined through them).
//
// Threads: HandleText, Join and Leave run on connections' strands; render results arrive on the
// render thread, encoded frames on encoder threads, timers on the timer thread. Nothing here
// blocks any of them for long: render submissions and outbox offers take small mutexes, encoding
// and view-link writes run on the encoder pool, disk reads of datasets stay in the dataset layer.
//
// Thread safety: every public member function is thread-safe. A ViewSession must be owned by a
// std::shared_ptr (callbacks hold weak references); Close must be called before the last
// reference goes (it closes the render views and unsubscribes). Lock order: a session's mutex
// may be held while calling the SessionRegistry, never the other way round.
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
#include <utility>
#include <vector>

#include "encode/jpeg_encoder.h"
#include "protocol/view_id.h"
#include "protocol/ws_messages.h"
#include "render/render_service.h"
#include "session/aspect_groups.h"
#include "session/dataset_hub.h"
#include "session/frame_policy.h"
#include "session/grant_checker.h"
#include "session/outbox.h"
#include "session/participant.h"
#include "session/server_metrics.h"
#include "util/latest_wins_executor.h"
#include "util/timer_queue.h"

namespace octoscope::session {

class SessionRegistry;
class ViewStore;

// The base of share and view links ("http://127.0.0.1:8080/"; links are base + "?share=TOKEN"):
// set once the server knows its port, read by sessions on any thread.
class LinkBase {
 public:
  void Set(std::string url) {
    std::lock_guard<std::mutex> lock(mu_);
    url_ = std::move(url);
  }
  std::string Get() const {
    std::lock_guard<std::mutex> lock(mu_);
    return url_.empty() ? std::string("/") : url_;
  }

 private:
  mutable std::mutex mu_;
  std::string url_;
};

// The services every session shares; all must outlive the sessions.
struct SessionContext {
  render::RenderService* renderer = nullptr;
  DatasetHub* datasets = nullptr;
  LatestWinsExecutor* encoders = nullptr;  // Encoding jobs (latest image per key wins).
  encode::JpegEncoderPool* jpeg = nullptr;
  TimerQueue* timers = nullptr;
  ServerMetrics* metrics = nullptr;
  SessionRegistry* registry = nullptr;  // Share links; null: share_create is refused.
  ViewStore* views = nullptr;           // View links; null: view_save is refused.
  // Disk I/O of view links (saving, reading); null: the encoders (tests only).
  LatestWinsExecutor* state_io = nullptr;
  // Who may do what; null: every grant holds (tests of other parts).
  const GrantChecker* grants = nullptr;
  // Whether `owner` may store one more view link now (count and rate limits); null: always.
  std::function<Status(const protocol::GrantRef& owner)> admit_view_link;
  std::string server_version;
  const LinkBase* link_base = nullptr;  // Null: links are relative ("/?share=TOKEN").
  int max_participants = 16;
  FramePolicyOptions frame_policy;
};

struct ViewSessionOptions {
  int window = 2;  // Unacknowledged frames per participant.
  int jpeg_interactive = 70;
  int jpeg_refining = 80;
  int jpeg_final = 92;
  std::chrono::milliseconds progress_interval{250};  // Between progress frames of a view.
  std::chrono::milliseconds dataset_event_interval{250};
  std::chrono::milliseconds data_refresh_interval{250};
  std::chrono::milliseconds stats_interval{1000};
  std::chrono::milliseconds driving_hold{2000};  // A state change marks its sender driving.
  // Per participant: screenshots rendering at once, and message rates (acknowledgements are not
  // counted): beyond them a non-fatal error, the message dropped.
  int max_screenshots_in_flight = 2;
  double messages_per_second = 200;
  double message_burst = 400;
  double hellos_per_second = 1;
  double hello_burst = 5;
  // Seconds since 1970 now (share-link and view-link expiry); null: the system clock. A seam for
  // tests that let links expire.
  std::function<int64_t()> unix_clock;
};

struct JoinOptions {
  protocol::Role role = protocol::Role::kViewer;
  std::string name;         // Display name; "" = a default from the role and number.
  std::string share_token;  // The share link used to join ("" for none: the owner).
};

class ViewSession : public std::enable_shared_from_this<ViewSession> {
 public:
  // A session without participants yet, owned under `owner`; `resume_key` reattaches its owner
  // (hello.resume).
  static std::shared_ptr<ViewSession> Create(const SessionContext& context, std::string session_id,
                                             std::string resume_key,
                                             const ViewSessionOptions& options = {},
                                             protocol::GrantRef owner = {});
  ~ViewSession();
  ViewSession(const ViewSession&) = delete;
  ViewSession& operator=(const ViewSession&) = delete;

  // Adds a participant reached through `sink`; its id, or kResourceExhausted ("session full")
  // when max_participants are connected, kFailedPrecondition when the session is closed or the
  // share link it joins through is no longer one of the session's valid links (revoked or
  // expired meanwhile). Joining as the owner closes a previous owner connection still attached
  // (4002). Events start with the participant's `hello` (welcome, opened, shares, participants).
  Result<std::string> Join(std::shared_ptr<SessionSink> sink, JoinOptions options);
  // One text message of participant `participant`. Malformed ones get an error event; after
  // protocol::kMaxMalformedMessages of them the connection is closed (1008).
  void HandleText(std::string_view participant, std::string_view text);
  // Opens a stored view (a view link) for `participant` once it has been welcomed: the dataset
  // and exactly the stored state.
  void OpenViewLink(std::string_view participant, protocol::ViewLink link);
  // The participant's connection ended. Idempotent.
  void Leave(std::string_view participant);
  // Closes every participant's connection with `code` and releases the session (render views
  // closed, share links unregistered). Idempotent.
  void Close(uint16_t code = 1001, std::string reason = "session released");
  // Ends what no longer holds (see the header comment). Never call with a session's mutex held.
  void Revalidate();

  // What a share link of this session is (the access layer's view of it), nullopt when the
  // session holds no valid link of that id.
  struct ShareState {
    protocol::Role role = protocol::Role::kViewer;
    std::string dataset;  // The dataset it was made for ("" until the session opens one).
    std::optional<int64_t> expires_unix_s;
  };
  std::optional<ShareState> share_state(std::string_view id) const;

  const std::string& id() const { return id_; }
  // The id of the dataset the session views ("" before the first open).
  std::string dataset_id() const;
  const std::string& resume_key() const { return resume_key_; }
  const protocol::GrantRef& owner_grant() const { return owner_grant_; }
  size_t participant_count() const;
  bool closed() const;
  // Since when no participant is connected (nullopt while one is).
  std::optional<Clock::time_point> empty_since() const;
  // Of participant `participant` (zeros when unknown).
  OutboxStats outbox_stats(std::string_view participant) const;

 private:
  struct Group {
    uint64_t key = 0;                // Unique within the session (callbacks name it).
    render::ViewId render_view = 0;  // 0 until the dataset is renderable.
    FramePolicy policy;
    protocol::PixelSize pixels;  // Render size: the largest member's.
    double lod_bias = 0;
    std::vector<uint64_t> members;  // Participant numbers, largest first.
    // The order in flight: its sequences, state version and kind.
    uint64_t order_sequence = 0;
    uint64_t order_frame_sequence = 0;  // Session-wide, increasing: what outboxes compare.
    uint64_t order_state_version = 0;
    bool order_refine = false;
    Clock::time_point order_submitted{};
    Clock::time_point last_progress{};
  };
  struct View {
    protocol::ViewId id = protocol::ViewId::k3d;
    uint64_t content_version = 0;  // FramePolicy's versions: state changes and new data.
    std::vector<Group> groups;
  };
  struct Screenshot {
    uint32_t id = 0;
    protocol::ViewId view = protocol::ViewId::k3d;
    render::ViewId render_view = 0;
    uint64_t state_version = 0;
    std::shared_ptr<Participant> participant;
  };
  // One encoding of an image for the recipients that want the same bytes.
  struct EncodeJob {
    int outbox_view = 0;
    uint64_t sequence = 0;
    protocol::FrameHeader header;
    bool png = false;
    int jpeg_quality = 90;
    protocol::PixelSize size;  // Resampled to this size when smaller than the image.
    std::shared_ptr<const render::RenderImage> image;
    std::vector<std::shared_ptr<Participant>> recipients;
  };

  ViewSession(const SessionContext& context, std::string id, std::string resume_key,
              const ViewSessionOptions& options, protocol::GrantRef owner);

  void OnMessage(const std::shared_ptr<Participant>& from, protocol::ClientMessage message);
  void OnHello(const std::shared_ptr<Participant>& from, const protocol::HelloMessage& hello);
  void OnOpen(const std::shared_ptr<Participant>& from, const std::string& dataset_id,
              const std::optional<protocol::StateUpdate>& update, bool exact);
  void OnOwnerMessage(const std::shared_ptr<Participant>& from,
                      const protocol::ClientMessage& message);
  void OnViewSave(const std::shared_ptr<Participant>& from,
                  const protocol::ViewSaveMessage& message);
  // The verdict of the grant checker (every grant holds without one).
  GrantVerdict CheckGrant(const protocol::GrantRef& grant, std::string_view dataset) const;
  int64_t WallClock() const;
  // Runs disk I/O of view links off the I/O threads (and off the frame encoders).
  void RunStateIo(std::function<void()> job) const;
  void SendError(Participant& to, std::string_view message, std::string_view request, bool fatal);

  // The rest REQUIRES mu_ held unless named otherwise.
  std::shared_ptr<Participant> FindLocked(std::string_view id) const;
  std::shared_ptr<Participant> FindLocked(uint64_t number) const;
  void SendAllLocked(const std::string& text, const Participant* except = nullptr);
  void SendErrorAllLocked(std::string_view message, std::string_view request);
  // `from` changed the state for `views`: a new state version, the others told, frames ordered.
  void ChangedLocked(std::initializer_list<protocol::ViewId> views, Participant* from);
  void MarkDrivingLocked(Participant* from);
  // Sends `participants` to everyone when the list or who is driving changed (or `force`).
  void BroadcastParticipantsLocked(bool force);
  std::vector<protocol::ParticipantInfo> ParticipantsLocked(Clock::time_point now) const;
  void SendSharesLocked();
  // Removes the share link `token` and closes those who joined through it with 4001 `reason`.
  void RemoveShareLocked(const std::string& token, const std::string& reason,
                         std::vector<render::ViewId>* to_close);
  // Recomputes the render groups of every view from the participants' viewports.
  void RegroupLocked();
  void RegroupViewLocked(View& view, Clock::time_point now, std::vector<render::ViewId>* to_close);
  bool AnyInteractingLocked() const;
  // Submits what each group's policy orders now and arms the wake timer.
  void PumpLocked();
  void PumpGroupLocked(View& view, Group& group, Clock::time_point now,
                       std::optional<Clock::time_point>* wake);
  // The render request for `pixels` at `order`, or why there is none.
  Result<render::FrameRequest> RequestLocked(protocol::ViewId view, protocol::PixelSize pixels,
                                             double lod_bias, const FramePolicy& policy,
                                             const FrameOrder& order) const;
  // Opens the groups' render views once the dataset can be rendered.
  void AttachRenderViewsLocked();
  Group* FindGroupLocked(protocol::ViewId view, uint64_t key);
  void SendDatasetEventLocked();
  void RefreshDataLocked();
  void SendStatsLocked(const std::shared_ptr<Participant>& participant);
  // Removes `participant` (closing its connection with `code` when not 0).
  void RemoveLocked(const std::shared_ptr<Participant>& participant, uint16_t code,
                    const std::string& reason, std::vector<render::ViewId>* to_close);
  // Runs `fire` (with mu_ held) at `when` unless `timer` is armed already.
  void ArmTimerLocked(std::optional<TimerQueue::TimerId>* timer, Clock::time_point when,
                      void (*fire)(ViewSession&));
  std::string DatasetJsonLocked() const;
  std::string LinkUrl(std::string_view key, std::string_view value) const;

  // Render thread.
  void OnRenderResult(protocol::ViewId view, uint64_t group, render::FrameResult result);
  void OnScreenshotResult(uint32_t id, uint64_t participant, render::FrameResult result);
  void SubmitEncode(EncodeJob job);
  // Encoder threads.
  void Encode(EncodeJob job);
  // Dataset threads.
  void OnDatasetChange();

  const SessionContext context_;
  const ViewSessionOptions options_;
  const std::string id_;
  const std::string resume_key_;
  const protocol::GrantRef owner_grant_;

  mutable std::mutex mu_;  // Guards everything below.
  bool closed_ = false;
  std::vector<std::shared_ptr<Participant>> participants_;  // In joining order.
  uint64_t next_participant_ = 1;
  std::optional<Clock::time_point> empty_since_;
  struct Share {
    std::string token;
    std::string id;  // Public: names the link in grants.
    protocol::Role role = protocol::Role::kViewer;
    std::optional<int64_t> expires_unix_s;
    std::string dataset;  // The dataset it admits to ("" until the session opens one).
  };
  std::vector<Share> shares_;
  // A view link to open for a participant once it has been welcomed (OpenViewLink).
  std::optional<std::pair<std::string, protocol::ViewLink>> pending_view_;
  // Who drives: the sender of the latest state change (for driving_hold) and the interacting.
  uint64_t last_changer_ = 0;
  Clock::time_point last_change_{};
  std::vector<std::string> last_participants_sent_;  // "id:role:driving" of the last event.
  std::optional<TimerQueue::TimerId> driving_timer_;
  std::shared_ptr<DatasetUse> dataset_;
  dataset::Subscription dataset_subscription_;
  uint64_t seen_planes_ = 0;  // Planes inserted when the views last re-rendered.
  uint64_t state_version_ = 0;
  std::optional<protocol::ViewState> state_;
  std::array<View, protocol::kViewCount> views_;
  uint64_t next_group_key_ = 1;
  uint64_t frame_sequence_ = 0;  // Session-wide order numbers (Group::order_frame_sequence).
  bool interacting_ = false;     // Any participant interacting (what the policies were told).
  std::vector<Screenshot> screenshots_;
  uint64_t screenshot_sequence_ = 0;
  bool auto_contrast_pending_ = false;  // Follow the growing histogram (see RefreshDataLocked).
  std::optional<TimerQueue::TimerId> wake_timer_;
  std::optional<TimerQueue::TimerId> dataset_event_timer_;
  std::optional<TimerQueue::TimerId> data_refresh_timer_;
  uint64_t bricks_pending_ = 0;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_VIEW_SESSION_H_
