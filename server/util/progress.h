// ProgressBar: a one-line progress display on a terminal ("slices 120/512  23% 410 MB/s ETA 0:14").
// It draws only when its stream is a terminal, and at most ten times per second, so callers
// may call Update() as often as they like.
//
// Thread safety: not thread-safe; one thread owns a ProgressBar.
#ifndef OCTOSCOPE_UTIL_PROGRESS_H_
#define OCTOSCOPE_UTIL_PROGRESS_H_

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>

namespace octoscope {

class ProgressBar {
 public:
  // `unit` names what `done`/`total` count ("slices"); `bytes_per_unit` (0: none) turns the rate
  // into MB/s. Draws only when `stream` is a terminal and `enabled`.
  ProgressBar(std::FILE* stream, std::string unit, uint64_t total, double bytes_per_unit,
              bool enabled = true);
  ~ProgressBar();
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  void Update(uint64_t done);
  // Draws the final state and ends the line.
  void Finish();

  bool drawing() const { return drawing_; }

 private:
  void Draw(bool final_draw);

  std::FILE* stream_;
  std::string unit_;
  uint64_t total_;
  double bytes_per_unit_;
  bool drawing_;
  bool finished_ = false;
  uint64_t done_ = 0;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_PROGRESS_H_
