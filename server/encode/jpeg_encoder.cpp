#include "encode/jpeg_encoder.h"

#include <turbojpeg.h>

#include <string>

namespace octoscope::encode {

Result<std::unique_ptr<JpegEncoder>> JpegEncoder::Create() {
  std::unique_ptr<JpegEncoder> encoder(new JpegEncoder);
  encoder->handle_ = tjInitCompress();
  if (encoder->handle_ == nullptr) {
    return InternalError(std::string("JPEG: tjInitCompress: ") + tjGetErrorStr());
  }
  return encoder;
}

JpegEncoder::~JpegEncoder() {
  if (buffer_ != nullptr) tjFree(buffer_);
  if (handle_ != nullptr) tjDestroy(static_cast<tjhandle>(handle_));
}

Result<std::span<const uint8_t>> JpegEncoder::Encode(const float* rgba, int width, int height,
                                                     int quality, bool accurate) {
  if (quality < 1 || quality > 100) {
    return InvalidArgumentError("JPEG quality " + std::to_string(quality) + " is not in 1..100");
  }
  ToRgba8Into(rgba, width, height, AlphaMode::kOverBlack, &scratch_);
  OCTO_RETURN_IF_ERROR(ValidateImage(scratch_));
  // The worst case for 4:4:4 bounds the output, so the buffer never needs reallocating.
  const unsigned long needed = tjBufSize(width, height, TJSAMP_444);
  if (needed > capacity_) {
    if (buffer_ != nullptr) tjFree(buffer_);
    buffer_ = tjAlloc(static_cast<int>(needed));
    capacity_ = buffer_ != nullptr ? needed : 0;
    if (buffer_ == nullptr) return ResourceExhaustedError("JPEG: tjAlloc failed");
  }
  unsigned long size = capacity_;
  // RGBX: the alpha byte is skipped, i.e. the premultiplied colour over black is encoded.
  const int flags = TJFLAG_NOREALLOC | (accurate ? TJFLAG_ACCURATEDCT : TJFLAG_FASTDCT);
  if (tjCompress2(static_cast<tjhandle>(handle_), scratch_.pixels.data(), width, width * 4, height,
                  TJPF_RGBX, &buffer_, &size, TJSAMP_444, quality, flags) != 0) {
    return InternalError(std::string("JPEG: tjCompress2: ") +
                         tjGetErrorStr2(static_cast<tjhandle>(handle_)));
  }
  return std::span<const uint8_t>(buffer_, size);
}

Result<JpegEncoderPool::Lease> JpegEncoderPool::Acquire() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (!idle_.empty()) {
      auto encoder = std::move(idle_.back());
      idle_.pop_back();
      return Lease(this, std::move(encoder));
    }
  }
  auto created = JpegEncoder::Create();
  if (!created.ok()) return created.status();
  return Lease(this, std::move(*created));
}

void JpegEncoderPool::Return(std::unique_ptr<JpegEncoder> encoder) {
  std::lock_guard<std::mutex> lock(mu_);
  idle_.push_back(std::move(encoder));
}

}  // namespace octoscope::encode
