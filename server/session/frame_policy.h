// FramePolicy: what one view renders next and how — the frame policy of docs/protocol.md. While
// the user interacts, one full frame per state version at a reduced scale chosen to hold a frame
// time target; once the state has been quiet for `idle_delay` and no interaction is active, one
// refinement at full scale (progress frames, then the final one). Pure logic over a clock the
// caller passes in: no threads, no rendering, no I/O — so every rule is tested directly.
//
// Versions: the caller numbers every change of what the view shows (state changes, and data
// that arrived) with an increasing `version`. A frame answers one version. At most one frame is
// in flight per view: a change while an interactive frame renders is answered by the next one
// (which shows the newest version); a change during a refinement supersedes it at once (the new
// interactive order replaces it in the render service, whose result for it never comes).
//
// Thread safety: not thread-safe; the owning session serialises calls.
#ifndef OCTOSCOPE_SESSION_FRAME_POLICY_H_
#define OCTOSCOPE_SESSION_FRAME_POLICY_H_

#include <chrono>
#include <cstdint>
#include <optional>

namespace octoscope::session {

using Clock = std::chrono::steady_clock;

struct FramePolicyOptions {
  double target_frame_ms = 100;  // Interactive frames: render time to hold.
  double min_scale = 0.25;       // Interactive frames: smallest scale per axis.
  // The first interactive frame's scale, before any frame time is known: a quarter of the
  // pixels, so that a view's first frame on a busy server does not cost a full-resolution pass.
  double initial_scale = 0.5;
  std::chrono::milliseconds idle_delay{200};  // Quiet time before refining.
};

// A frame the caller should submit now. Submitting it replaces whatever the view had pending or
// in flight (the render service's latest-state-wins slot).
struct FrameOrder {
  uint64_t sequence = 0;  // Increasing per policy; results of older orders are superseded.
  bool refine = false;    // A refinement at full scale, else an interactive full frame.
  double scale = 1;       // Per axis, (0, 1].
  uint64_t version = 0;
  // The 3-D level of detail measures footprints in the spacing the screen shows
  // (render::FrameOptions::lod_view_spacing): refinements. Interactive frames measure them in the
  // finest spacing, which with anisotropic voxels seen from the side is several times cheaper;
  // the refinement that follows shows every axis at the screen's resolution.
  bool lod_view_spacing = true;
};

class FramePolicy {
 public:
  explicit FramePolicy(const FramePolicyOptions& options = {})
      : options_(options), scale_(options.initial_scale) {}

  // What the view shows changed (a new state version, or new data).
  void OnChange(uint64_t version, Clock::time_point now);
  // New data arrived (the same state shows more). Unlike OnChange it does not restart the quiet
  // period: a quiet view goes straight to a new refinement (its first pass already shows the new
  // data at full resolution), an interacting one gets it in its next interactive frame.
  void OnDataChange(uint64_t version);
  void OnInteraction(bool active, Clock::time_point now);
  // The frame of order `sequence` was rendered (or failed: rendered = false). For an
  // interactive frame, `render_ms` adapts the scale. Results of superseded orders are ignored.
  void OnFrameDone(uint64_t sequence, bool rendered, double render_ms);
  // The view's viewport changed: the next frame must be a new one even without a change.
  void Invalidate(Clock::time_point now);

  // The frame to submit now, if any. When nothing is due, `*wake` (if given) is set to the time
  // the policy wants to be asked again (the end of the idle delay), or nullopt.
  std::optional<FrameOrder> Poll(Clock::time_point now,
                                 std::optional<Clock::time_point>* wake = nullptr);

  double scale() const { return scale_; }
  bool in_flight() const { return in_flight_; }
  uint64_t version() const { return version_; }
  // The newest version shown by a final frame (0 = none).
  uint64_t final_version() const { return refined_version_; }

 private:
  bool Quiet(Clock::time_point now) const;

  FramePolicyOptions options_;
  uint64_t version_ = 0;
  uint64_t shown_version_ = 0;    // Newest version an interactive frame was ordered for.
  uint64_t refined_version_ = 0;  // Newest version a refinement was ordered for.
  uint64_t sequence_ = 0;         // Of the last order.
  bool in_flight_ = false;
  bool in_flight_refine_ = false;
  bool interacting_ = false;
  Clock::time_point last_change_{};
  double scale_ = 1;
};

}  // namespace octoscope::session

#endif  // OCTOSCOPE_SESSION_FRAME_POLICY_H_
