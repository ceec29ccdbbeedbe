// TokenBucket: a rate limit — on average `rate` events per second, bursts of up to `burst`.
// Take() spends one token when one is there; tokens refill continuously at `rate` per second up
// to `burst`. A bucket with rate 0 admits `burst` events in all.
//
// Thread safety: none; the owner serialises the calls (e.g. under its own mutex).
#ifndef OCTOSCOPE_UTIL_TOKEN_BUCKET_H_
#define OCTOSCOPE_UTIL_TOKEN_BUCKET_H_

#include <algorithm>
#include <chrono>

namespace octoscope {

class TokenBucket {
 public:
  using Clock = std::chrono::steady_clock;

  // REQUIRES: rate >= 0, burst >= 1. Starts full.
  TokenBucket(double rate, double burst) : rate_(rate), burst_(burst), tokens_(burst) {}

  // Spends a token at `now`; false (nothing spent) when none is left.
  bool Take(Clock::time_point now = Clock::now()) {
    Refill(now);
    if (tokens_ < 1) return false;
    tokens_ -= 1;
    return true;
  }

  // Tokens available at `now`.
  double Available(Clock::time_point now = Clock::now()) {
    Refill(now);
    return tokens_;
  }

 private:
  void Refill(Clock::time_point now) {
    if (last_ != Clock::time_point{} && now > last_) {
      tokens_ = std::min(burst_, tokens_ + rate_ * std::chrono::duration<double>(now - last_).count());
    }
    if (now > last_) last_ = now;
  }

  double rate_;
  double burst_;
  double tokens_;
  Clock::time_point last_{};
};

}  // namespace octoscope

#endif  // OCTOSCOPE_UTIL_TOKEN_BUCKET_H_
