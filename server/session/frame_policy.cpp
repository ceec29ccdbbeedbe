#include "session/frame_policy.h"

#include <algorithm>
#include <cmath>

namespace octoscope::session {

void FramePolicy::OnChange(uint64_t version, Clock::time_point now) {
  if (version > version_) version_ = version;
  last_change_ = now;
}

void FramePolicy::OnDataChange(uint64_t version) {
  if (version > version_) version_ = version;
}

void FramePolicy::OnInteraction(bool active, Clock::time_point now) {
  interacting_ = active;
  last_change_ = now;
}

void FramePolicy::Invalidate(Clock::time_point now) {
  // A new frame is due for the current version: forget what was shown of it.
  shown_version_ = 0;
  refined_version_ = 0;
  last_change_ = now;
}

void FramePolicy::OnFrameDone(uint64_t sequence, bool rendered, double render_ms) {
  if (sequence != sequence_ || !in_flight_) return;  // Superseded.
  const bool was_refine = in_flight_refine_;
  in_flight_ = false;
  in_flight_refine_ = false;
  if (!rendered || was_refine || render_ms <= 0) return;
  // Render time follows the pixel count, i.e. the square of the scale. A dead band keeps the
  // scale steady against timing noise; each step is at most a factor 2 down, 1.25 up.
  const double ratio = options_.target_frame_ms / render_ms;
  if (ratio < 0.8 || ratio > 1.6) {
    const double step = std::clamp(std::sqrt(ratio), 0.5, 1.25);
    scale_ = std::clamp(scale_ * step, options_.min_scale, 1.0);
  }
}

bool FramePolicy::Quiet(Clock::time_point now) const {
  return !interacting_ && now - last_change_ >= options_.idle_delay;
}

std::optional<FrameOrder> FramePolicy::Poll(Clock::time_point now,
                                            std::optional<Clock::time_point>* wake) {
  if (wake != nullptr) wake->reset();
  // An interactive frame in flight: the next one answers whatever changed meanwhile. A
  // refinement in flight is superseded by any change.
  if (in_flight_ && !(in_flight_refine_ && shown_version_ < version_)) return std::nullopt;
  // Quiet long enough: refine the newest version once.
  if (Quiet(now) && refined_version_ < version_) {
    in_flight_ = in_flight_refine_ = true;
    refined_version_ = shown_version_ = version_;
    return FrameOrder{++sequence_, true, 1.0, version_, true};
  }
  // Something new to show: an interactive frame at once.
  if (shown_version_ < version_) {
    in_flight_ = true;
    in_flight_refine_ = false;
    shown_version_ = version_;
    return FrameOrder{++sequence_, false, scale_, version_, false};
  }
  if (wake != nullptr && refined_version_ < version_ && !interacting_) {
    *wake = last_change_ + options_.idle_delay;
  }
  return std::nullopt;
}

}  // namespace octoscope::session
