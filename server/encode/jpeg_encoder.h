// JpegEncoder: JPEG encoding for a stream of frames — one TurboJPEG handle, one 8-bit scratch
// image and one output buffer, all reused from frame to frame (no allocation once they have
// grown to the frame size). The images are the renderer's premultiplied RGBA floats, encoded as
// the colour over black (4:4:4, like EncodeJpeg). JpegEncoderPool lends encoders to the threads
// that encode, one at a time each.
//
// Thread safety: a JpegEncoder is used by one thread at a time; JpegEncoderPool is thread-safe.
#ifndef OCTOSCOPE_ENCODE_JPEG_ENCODER_H_
#define OCTOSCOPE_ENCODE_JPEG_ENCODER_H_

#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <vector>

#include "encode/image_encoder.h"
#include "util/result.h"

namespace octoscope::encode {

class JpegEncoder {
 public:
  static Result<std::unique_ptr<JpegEncoder>> Create();
  ~JpegEncoder();
  JpegEncoder(const JpegEncoder&) = delete;
  JpegEncoder& operator=(const JpegEncoder&) = delete;

  // Encodes width x height premultiplied RGBA floats at `quality` (1..100). `accurate` picks the
  // slow exact DCT (final frames) over the fast one (interactive frames). The bytes stay valid
  // until the next call. REQUIRES: rgba holds width * height * 4 floats.
  Result<std::span<const uint8_t>> Encode(const float* rgba, int width, int height, int quality,
                                          bool accurate);

 private:
  JpegEncoder() = default;

  void* handle_ = nullptr;  // tjhandle.
  unsigned char* buffer_ = nullptr;
  unsigned long capacity_ = 0;
  Rgba8Image scratch_;
};

class JpegEncoderPool {
 public:
  // An encoder returned to the pool when the lease is destroyed.
  class Lease {
   public:
    Lease(JpegEncoderPool* pool, std::unique_ptr<JpegEncoder> encoder)
        : pool_(pool), encoder_(std::move(encoder)) {}
    Lease(Lease&&) = default;
    ~Lease() {
      if (encoder_) pool_->Return(std::move(encoder_));
    }
    JpegEncoder* operator->() const { return encoder_.get(); }

   private:
    JpegEncoderPool* pool_;
    std::unique_ptr<JpegEncoder> encoder_;
  };

  // An idle encoder, or a new one.
  Result<Lease> Acquire();

 private:
  void Return(std::unique_ptr<JpegEncoder> encoder);

  std::mutex mu_;
  std::vector<std::unique_ptr<JpegEncoder>> idle_;
};

}  // namespace octoscope::encode

#endif  // OCTOSCOPE_ENCODE_JPEG_ENCODER_H_
