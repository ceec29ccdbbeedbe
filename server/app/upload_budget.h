// UploadBudget: the RAM that slab uploads in flight may hold together (docs/api.md, "Limits"):
// their bodies, read into memory before the insert, and the planes a TIFF body decodes to. An
// upload reserves its worst case before the first byte of its body is read and keeps the
// reservation until its insert has finished (or it failed, or the client left); an upload that
// does not fit is refused at once, its body unread, so that concurrent uploads never hold more
// than the budget however many arrive at once.
//
// Thread safety: TryReserve and the counters may be called from any thread; a Reservation may be
// released (destroyed, reset) on any thread, also after the budget itself is gone.
#ifndef OCTOSCOPE_APP_UPLOAD_BUDGET_H_
#define OCTOSCOPE_APP_UPLOAD_BUDGET_H_

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>

namespace octoscope::app {

class UploadBudget {
 public:
  // Bytes held by one admitted upload; returned to the budget when destroyed or reset. Move-only.
  class Reservation {
   public:
    Reservation() = default;
    Reservation(Reservation&& other) noexcept = default;
    Reservation& operator=(Reservation&& other) noexcept;
    ~Reservation() { reset(); }

    void reset();
    uint64_t bytes() const { return bytes_; }

   private:
    friend class UploadBudget;
    struct State;
    Reservation(std::shared_ptr<State> state, uint64_t bytes)
        : state_(std::move(state)), bytes_(bytes) {}

    std::shared_ptr<State> state_;
    uint64_t bytes_ = 0;
  };

  // REQUIRES: capacity_bytes > 0.
  explicit UploadBudget(uint64_t capacity_bytes);

  // Reserves `bytes` (at most the whole capacity: an upload larger than the budget may run
  // alone); nullopt when they do not fit beside the reservations held now.
  std::optional<Reservation> TryReserve(uint64_t bytes);

  uint64_t capacity() const { return capacity_; }
  uint64_t reserved() const;

 private:
  const uint64_t capacity_;
  std::shared_ptr<Reservation::State> state_;
};

}  // namespace octoscope::app

#endif  // OCTOSCOPE_APP_UPLOAD_BUDGET_H_
