#include "render/slice_renderer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "../../kernels/node_format.h"
#include "render/cl_call.h"
#include "render/cl_handles.h"

namespace octoscope::render {
namespace {

// Mirrors of kernels/slice.cl's constants and argument struct.
constexpr int kChannelFloats = 24;
constexpr int kEnabled = 0;
constexpr int kLo = 1;
constexpr int kWindow = 2;
constexpr int kGamma = 3;
constexpr int kHasLut = 4;
constexpr int kIdentity = 5;
constexpr int kColor = 6;
constexpr int kTransform = 9;

struct SliceSetup {
  float origin[3];
  float du[3];
  float dv[3];
  float box_hi[3];
  float inv_spacing[3];
  float background[4];
  int32_t width;
  int32_t height;
  int32_t level;
};
static_assert(sizeof(SliceSetup) == 88, "must match OctoSliceSetup in kernels/slice.cl");
static_assert(sizeof(OctoTreeGeometry) == 32);

double MillisSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

Status ValidateView(const SliceView& view) {
  if (view.axis < 0 || view.axis > 2) {
    return InvalidArgumentError("slice axis must be 0 (x), 1 (y) or 2 (z), got " +
                                std::to_string(view.axis));
  }
  if (view.width < 1 || view.width > kMaxImageSize || view.height < 1 ||
      view.height > kMaxImageSize) {
    return InvalidArgumentError("slice image size must lie in [1, " +
                                std::to_string(kMaxImageSize) + "], got " +
                                std::to_string(view.width) + "x" + std::to_string(view.height));
  }
  if (!std::isfinite(view.position_um)) {
    return InvalidArgumentError("slice position must be finite");
  }
  if (view.center_um &&
      (!std::isfinite((*view.center_um)[0]) || !std::isfinite((*view.center_um)[1]))) {
    return InvalidArgumentError("slice centre must be finite");
  }
  if (view.um_per_pixel && !(std::isfinite(*view.um_per_pixel) && *view.um_per_pixel > 0)) {
    return InvalidArgumentError("slice um_per_pixel must be finite and > 0");
  }
  return Status::Ok();
}

OctoTreeGeometry DeviceGeometry(const octree::BrickGeometry& geometry) {
  OctoTreeGeometry g{};
  for (int a = 0; a < 3; ++a) {
    g.volume_size[a] = static_cast<int>(geometry.volume_size()[a]);
    g.brick_size[a] = static_cast<int>(geometry.brick_size()[a]);
  }
  g.root_level = geometry.root_level();
  g.channels = geometry.channels();
  return g;
}

// The channel parameter buffer and the LUTs (straight RGBA / 255) of kernels/slice.cl.
void PackChannels(const RenderParams& params, std::vector<float>* channel_floats,
                  std::vector<float>* luts) {
  const size_t count = params.channels.size();
  channel_floats->assign(count * kChannelFloats, 0.0f);
  luts->assign(count * kLutEntries * 4, 0.0f);
  for (size_t c = 0; c < count; ++c) {
    const ChannelParams& ch = params.channels[c];
    float* f = channel_floats->data() + c * kChannelFloats;
    f[kEnabled] = ch.enabled ? 1.0f : 0.0f;
    f[kLo] = static_cast<float>(ch.level - ch.window / 2);
    f[kWindow] = static_cast<float>(ch.window);
    f[kGamma] = static_cast<float>(ch.gamma);
    f[kHasLut] = ch.lut ? 1.0f : 0.0f;
    f[kIdentity] = ch.transform.IsIdentity() ? 1.0f : 0.0f;
    for (int k = 0; k < 3; ++k) f[kColor + k] = static_cast<float>(ch.color[k]);
    for (int k = 0; k < 12; ++k) f[kTransform + k] = static_cast<float>(ch.transform.m[k]);
    if (ch.lut) {
      float* l = luts->data() + c * kLutEntries * 4;
      for (int i = 0; i < kLutEntries; ++i) {
        const volume::Rgba& e = (*ch.lut)[i];
        l[4 * i + 0] = static_cast<float>(e.r / 255.0);
        l[4 * i + 1] = static_cast<float>(e.g / 255.0);
        l[4 * i + 2] = static_cast<float>(e.b / 255.0);
        l[4 * i + 3] = static_cast<float>(e.a / 255.0);
      }
    }
  }
}

}  // namespace

std::array<int, 2> SliceInPlaneAxes(int axis) {
  switch (axis) {
    case 0:
      return {1, 2};
    case 1:
      return {0, 2};
    default:
      return {0, 1};
  }
}

SliceFrame ResolveSliceFrame(const SliceView& view, const Box3& bounds) {
  const auto [ua, va] = SliceInPlaneAxes(view.axis);
  const Vec3 extent = bounds.Extent();
  const Vec3 centre = bounds.Center();
  SliceFrame f;
  // Default scale: the whole cross-section visible, the tighter axis filling the image.
  f.um_per_pixel = view.um_per_pixel ? *view.um_per_pixel
                                     : std::max(extent[ua] / view.width, extent[va] / view.height);
  const double cu = view.center_um ? (*view.center_um)[0] : centre[ua];
  const double cv = view.center_um ? (*view.center_um)[1] : centre[va];
  f.origin[view.axis] = view.position_um;
  f.origin[ua] = cu - view.width / 2.0 * f.um_per_pixel;
  f.origin[va] = cv - view.height / 2.0 * f.um_per_pixel;
  f.du[ua] = f.um_per_pixel;
  f.dv[va] = f.um_per_pixel;
  return f;
}

int SliceLevel(double um_per_pixel, const Vec3& spacing_um, int axis, double lod_bias,
               int root_level) {
  const auto [ua, va] = SliceInPlaneAxes(axis);
  const double in_plane = std::max(spacing_um[ua], spacing_um[va]);
  const double level = std::floor(std::log2(um_per_pixel / in_plane) + lod_bias);
  // Clamp in double first: a huge or tiny footprint must not overflow the int conversion.
  return static_cast<int>(std::clamp(level, 0.0, static_cast<double>(root_level)));
}

struct SliceRenderer::Impl {
  const ComputeContext* context = nullptr;
  ClKernel kernel;
  std::unique_ptr<FrameBuffers> own_buffers;  // For callers that pass none.
};

FrameBufferSizes SliceRenderer::BufferSizes(const SliceView& view, const RenderParams& params) {
  const uint64_t pixels =
      std::max<uint64_t>(uint64_t(std::max(view.width, 0)) * uint64_t(std::max(view.height, 0)), 1);
  const uint64_t channels = std::max<uint64_t>(params.channels.size(), 1);
  FrameBufferSizes sizes{};
  sizes[static_cast<size_t>(FrameBuffer::kImage)] = pixels * 4 * sizeof(float);
  sizes[static_cast<size_t>(FrameBuffer::kChannels)] = channels * kChannelFloats * sizeof(float);
  sizes[static_cast<size_t>(FrameBuffer::kLut)] = channels * kLutEntries * 4 * sizeof(float);
  sizes[static_cast<size_t>(FrameBuffer::kCounter)] = sizeof(uint32_t);
  return sizes;
}

SliceRenderer::~SliceRenderer() = default;

Result<std::unique_ptr<SliceRenderer>> SliceRenderer::Create(const ComputeContext* context,
                                                             ProgramCache* programs,
                                                             DeviceOctree* device_octree,
                                                             const Vec3& spacing_um,
                                                             std::string_view build_options) {
  if (!IsFinite(spacing_um) || spacing_um.x <= 0 || spacing_um.y <= 0 || spacing_um.z <= 0) {
    return InvalidArgumentError("slice renderer: spacing must be finite and > 0");
  }
  std::unique_ptr<SliceRenderer> r(new SliceRenderer());
  r->impl_ = std::make_unique<Impl>();
  r->impl_->context = context;
  r->impl_->own_buffers = std::make_unique<FrameBuffers>(context);
  OCTO_ASSIGN_OR_RETURN(r->impl_->kernel,
                        programs->CreateKernel("slice.cl", "RenderSlice", build_options));
  r->device_octree_ = device_octree;
  r->spacing_ = spacing_um;
  return r;
}

Box3 SliceRenderer::bounds() const {
  const octree::Vec3& n = device_octree_->geometry().volume_size();
  return PhysicalBounds({n[0], n[1], n[2]}, spacing_);
}

Result<RenderImage> SliceRenderer::Render(const SliceView& view, const RenderParams& params,
                                          const SliceOptions& options, SliceStats* stats,
                                          FrameBuffers* buffers) {
  const auto start = std::chrono::steady_clock::now();
  const octree::BrickGeometry& geometry = device_octree_->geometry();
  OCTO_RETURN_IF_ERROR(ValidateView(view));
  OCTO_RETURN_IF_ERROR(ValidateRenderParams(params, geometry.channels()));
  if (options.max_frames < 1 || !std::isfinite(options.lod_bias)) {
    return InvalidArgumentError("slice options: max_frames must be >= 1 and lod_bias finite");
  }
  const ComputeContext& cx = *impl_->context;
  const cl_kernel kernel = impl_->kernel.get();

  // Plane, box and level, resolved once for all frames.
  const Box3 box = bounds();
  const SliceFrame frame_geometry = ResolveSliceFrame(view, box);
  const int level = SliceLevel(frame_geometry.um_per_pixel, spacing_, view.axis, options.lod_bias,
                               geometry.root_level());
  SliceSetup setup{};
  for (int a = 0; a < 3; ++a) {
    setup.origin[a] = static_cast<float>(frame_geometry.origin[a]);
    setup.du[a] = static_cast<float>(frame_geometry.du[a]);
    setup.dv[a] = static_cast<float>(frame_geometry.dv[a]);
    setup.box_hi[a] = static_cast<float>(box.hi[a]);
    setup.inv_spacing[a] = static_cast<float>(1.0 / spacing_[a]);
  }
  // Output pixels are premultiplied (render_params.h's background is straight RGBA).
  const double background_alpha = params.background[3];
  for (int k = 0; k < 3; ++k) {
    setup.background[k] = static_cast<float>(params.background[k] * background_alpha);
  }
  setup.background[3] = static_cast<float>(background_alpha);
  setup.width = view.width;
  setup.height = view.height;
  setup.level = level;

  // Device buffers (the caller's, reused from frame to frame, or the renderer's own): channel
  // parameters, LUTs, the image and the sample counter.
  std::vector<float> channel_floats, luts;
  PackChannels(params, &channel_floats, &luts);
  FrameBuffers& frame_buffers = buffers != nullptr ? *buffers : *impl_->own_buffers;
  OCTO_RETURN_IF_ERROR(frame_buffers.Reserve(BufferSizes(view, params)));
  const ClMem& channel_buffer = frame_buffers.handle(FrameBuffer::kChannels);
  const ClMem& lut_buffer = frame_buffers.handle(FrameBuffer::kLut);
  const ClMem& image_buffer = frame_buffers.handle(FrameBuffer::kImage);
  const ClMem& counter_buffer = frame_buffers.handle(FrameBuffer::kCounter);
  OCTO_RETURN_IF_ERROR(cx.WriteBuffer(channel_buffer, 0, channel_floats.size() * sizeof(float),
                                      channel_floats.data()));
  OCTO_RETURN_IF_ERROR(cx.WriteBuffer(lut_buffer, 0, luts.size() * sizeof(float), luts.data()));
  const size_t pixels = static_cast<size_t>(view.width) * static_cast<size_t>(view.height);
  const uint32_t zero = 0;

  SliceStats s;
  s.level = level;
  const OctoTreeGeometry g = DeviceGeometry(geometry);
  while (true) {
    // Construction may be ongoing: bring the node buffer up to date (it may be reallocated).
    OCTO_RETURN_IF_ERROR(device_octree_->Sync());
    OCTO_ASSIGN_OR_RETURN(const uint32_t frame, device_octree_->BeginFrame());
    OCTO_RETURN_IF_ERROR(cx.WriteBuffer(counter_buffer, 0, sizeof(uint32_t), &zero));
    const std::array<cl_mem, kMaxBrickAllocations> bricks = device_octree_->brick_buffers();
    static_assert(kMaxBrickAllocations == 4, "kernels/feedback.h passes four brick buffers");
    OCTO_RETURN_IF_ERROR(SetKernelArgs(
        kernel, device_octree_->node_buffer(), bricks[0], bricks[1], bricks[2], bricks[3],
        device_octree_->slots_per_allocation(), g, device_octree_->request_flags(),
        device_octree_->request_list(), device_octree_->request_capacity(),
        device_octree_->slot_used(), frame, setup, channel_buffer.get(), lut_buffer.get(),
        image_buffer.get(), counter_buffer.get()));
    OCTO_RETURN_IF_ERROR(cx.EnqueueKernel1D(kernel, pixels));
    uint32_t samples = 0;
    OCTO_RETURN_IF_ERROR(cx.ReadBuffer(counter_buffer, 0, sizeof(uint32_t), &samples));
    ++s.frames;
    s.samples += samples;
    s.last_samples = samples;

    // Feedback: what the frame wanted but could not have, then the uploads for the next frame.
    OCTO_ASSIGN_OR_RETURN(std::vector<uint32_t> requests, device_octree_->ReadFeedback());
    s.requests += requests.size();
    s.last_requests = requests.size();
    if (requests.empty()) {
      s.converged = true;
      break;
    }
    UploadBudget budget = options.upload;
    budget.protect_frame = frame;
    UploadStats upload;
    OCTO_RETURN_IF_ERROR(device_octree_->Upload(requests, budget, &upload));
    s.bricks_uploaded += upload.uploaded;
    s.bricks_unavailable += upload.unavailable;
    if (!options.converge || s.frames >= options.max_frames) break;
  }

  RenderImage image;
  image.width = view.width;
  image.height = view.height;
  image.rgba.resize(pixels * 4);
  OCTO_RETURN_IF_ERROR(
      cx.ReadBuffer(image_buffer, 0, image.rgba.size() * sizeof(float), image.rgba.data()));
  s.ms = MillisSince(start);
  if (stats != nullptr) *stats = s;
  return image;
}

}  // namespace octoscope::render
