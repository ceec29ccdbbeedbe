// ChangeNotifier: the callbacks that want to hear when something changed (a dataset's status,
// progress or visible data), with RAII Subscriptions. Notify calls each callback on the calling
// thread, never under a lock the subscriber could need, catching whatever it throws; a callback
// is never run by two threads at once. Unsubscribing waits for a call of that callback in
// progress on another thread, so after Reset returns the callback will not run again (from
// inside its own callback Reset returns at once). A notification that a callback raises from
// inside itself is skipped for that callback (no recursion).
//
// Thread safety: all members are thread-safe.
#ifndef OCTOSCOPE_DATASET_CHANGE_NOTIFIER_H_
#define OCTOSCOPE_DATASET_CHANGE_NOTIFIER_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <thread>

namespace octoscope::dataset {

class ChangeNotifier;

// A registration with a ChangeNotifier; unsubscribes when destroyed or Reset. Move-only; may
// outlive its notifier.
class Subscription {
 public:
  Subscription() = default;
  Subscription(std::weak_ptr<ChangeNotifier> notifier, uint64_t id)
      : notifier_(std::move(notifier)), id_(id) {}
  Subscription(Subscription&& other) noexcept;
  Subscription& operator=(Subscription&& other) noexcept;
  Subscription(const Subscription&) = delete;
  Subscription& operator=(const Subscription&) = delete;
  ~Subscription();
  void Reset();
  bool active() const { return id_ != 0; }

 private:
  std::weak_ptr<ChangeNotifier> notifier_;
  uint64_t id_ = 0;
};

class ChangeNotifier : public std::enable_shared_from_this<ChangeNotifier> {
 public:
  // REQUIRES: the notifier is owned by a std::shared_ptr.
  Subscription Subscribe(std::function<void()> callback);
  void Notify();
  // Used by Subscription.
  void Unsubscribe(uint64_t id);

 private:
  struct Entry {
    std::mutex call_mu;  // Held while the callback runs.
    std::function<void()> callback;
    bool active = true;  // Guarded by call_mu.
    std::atomic<std::thread::id> caller{};
  };
  std::mutex mu_;
  uint64_t next_id_ = 1;                                // Guarded by mu_.
  std::map<uint64_t, std::shared_ptr<Entry>> entries_;  // Guarded by mu_.
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_CHANGE_NOTIFIER_H_
