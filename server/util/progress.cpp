#include "util/progress.h"

#include <unistd.h>

#include <algorithm>

namespace octoscope {

ProgressBar::ProgressBar(std::FILE* stream, std::string unit, uint64_t total, double bytes_per_unit,
                         bool enabled)
    : stream_(stream),
      unit_(std::move(unit)),
      total_(total),
      bytes_per_unit_(bytes_per_unit),
      drawing_(enabled && stream != nullptr && isatty(fileno(stream))),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_ - std::chrono::seconds(1)) {}

ProgressBar::~ProgressBar() {
  if (drawing_ && !finished_) std::fputc('\n', stream_);
}

void ProgressBar::Update(uint64_t done) {
  done_ = done;
  if (!drawing_) return;
  auto now = std::chrono::steady_clock::now();
  // Redraw at most 10 times a second: drawing must never cost measurable time.
  if (now - last_draw_ < std::chrono::milliseconds(100)) return;
  last_draw_ = now;
  Draw(false);
}

void ProgressBar::Finish() {
  if (drawing_ && !finished_) {
    Draw(true);
    std::fputc('\n', stream_);
  }
  finished_ = true;
}

void ProgressBar::Draw(bool final_draw) {
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  double fraction = total_ ? std::min(1.0, static_cast<double>(done_) / total_) : 1.0;
  constexpr int kWidth = 30;
  int filled = static_cast<int>(fraction * kWidth);
  std::string bar(filled, '#');
  bar.append(kWidth - filled, '.');
  std::fprintf(stream_, "\r[%s] %s %llu/%llu %3.0f%%", bar.c_str(), unit_.c_str(),
               static_cast<unsigned long long>(done_), static_cast<unsigned long long>(total_),
               fraction * 100.0);
  if (bytes_per_unit_ > 0 && seconds > 0) {
    std::fprintf(stream_, " %.0f MB/s", done_ * bytes_per_unit_ / seconds / 1e6);
  }
  if (!final_draw && fraction > 0 && fraction < 1) {
    int eta = static_cast<int>(seconds / fraction * (1 - fraction));
    std::fprintf(stream_, " ETA %d:%02d", eta / 60, eta % 60);
  } else if (final_draw) {
    std::fprintf(stream_, " in %.1f s", seconds);
  }
  std::fputs("\x1b[K", stream_);  // Clear the rest of the line.
  std::fflush(stream_);
}

}  // namespace octoscope
