// Move-only RAII owners of OpenCL handles (cl_context, cl_command_queue, cl_program, cl_kernel,
// cl_mem, cl_event). Each owns ONE reference: the destructor (or reset) calls the matching
// clRelease* and only logs a failure (OCTO_CL_LOG), so no wrapper ever throws or aborts. Our own
// small types instead of the Khronos C++ bindings: no exceptions, Status-based errors.
//
// Invariant: get() is either nullptr or a handle holding one reference this object owns.
//
//   ClMem buffer(clCreateBuffer(context, flags, bytes, nullptr, &err));  // adopts
//   ClKernel copy = ClKernel::Retain(kernel);                            // shares (+1 ref)
//
// Thread safety: like std::unique_ptr — one object must not be mutated concurrently. The handles
// themselves follow OpenCL's rules (all API calls are thread-safe except clSetKernelArg on the same
// cl_kernel: give each thread its own kernel object).
#ifndef OCTOSCOPE_RENDER_CL_HANDLES_H_
#define OCTOSCOPE_RENDER_CL_HANDLES_H_

#include <CL/cl.h>

#include <cstddef>
#include <string>
#include <type_traits>
#include <utility>

#include "render/cl_call.h"
#include "util/status.h"

namespace octoscope::render {

template <typename Traits>
class ClHandle {
 public:
  using Handle = typename Traits::Handle;

  ClHandle() noexcept = default;
  // Adopts one reference of `handle` (as returned by a clCreate* call); nullptr gives an empty one.
  explicit ClHandle(Handle handle) noexcept : handle_(handle) {}
  // Takes an ADDITIONAL reference (clRetain*), for a handle owned elsewhere.
  static ClHandle Retain(Handle handle) noexcept {
    if (handle != nullptr) OCTO_CL_LOG(Traits::Retain(handle));
    return ClHandle(handle);
  }

  ~ClHandle() { reset(); }
  ClHandle(ClHandle&& other) noexcept : handle_(std::exchange(other.handle_, nullptr)) {}
  ClHandle& operator=(ClHandle&& other) noexcept {
    if (this != &other) reset(std::exchange(other.handle_, nullptr));
    return *this;
  }
  ClHandle(const ClHandle&) = delete;
  ClHandle& operator=(const ClHandle&) = delete;

  Handle get() const noexcept { return handle_; }
  explicit operator bool() const noexcept { return handle_ != nullptr; }
  // Gives up ownership without releasing.
  [[nodiscard]] Handle release() noexcept { return std::exchange(handle_, nullptr); }
  // Releases the owned reference (if any) and adopts `handle`.
  void reset(Handle handle = nullptr) noexcept {
    Handle old = std::exchange(handle_, handle);
    if (old != nullptr) ClLogError(Traits::Release(old), Traits::kReleaseCall);
  }

 private:
  Handle handle_ = nullptr;
};

namespace cl_traits {
#define OCTO_CL_HANDLE_TRAITS_(TraitsName, HandleType, RetainFn, ReleaseFn)         \
  struct TraitsName {                                                               \
    using Handle = HandleType;                                                      \
    static constexpr const char* kReleaseCall = #ReleaseFn "(handle)";              \
    static cl_int Retain(HandleType handle) noexcept { return RetainFn(handle); }   \
    static cl_int Release(HandleType handle) noexcept { return ReleaseFn(handle); } \
  };
OCTO_CL_HANDLE_TRAITS_(Context, cl_context, clRetainContext, clReleaseContext)
OCTO_CL_HANDLE_TRAITS_(Queue, cl_command_queue, clRetainCommandQueue, clReleaseCommandQueue)
OCTO_CL_HANDLE_TRAITS_(Program, cl_program, clRetainProgram, clReleaseProgram)
OCTO_CL_HANDLE_TRAITS_(Kernel, cl_kernel, clRetainKernel, clReleaseKernel)
OCTO_CL_HANDLE_TRAITS_(Mem, cl_mem, clRetainMemObject, clReleaseMemObject)
OCTO_CL_HANDLE_TRAITS_(Event, cl_event, clRetainEvent, clReleaseEvent)
#undef OCTO_CL_HANDLE_TRAITS_
}  // namespace cl_traits

using ClContext = ClHandle<cl_traits::Context>;
using ClQueue = ClHandle<cl_traits::Queue>;
using ClProgram = ClHandle<cl_traits::Program>;
using ClKernel = ClHandle<cl_traits::Kernel>;
using ClMem = ClHandle<cl_traits::Mem>;
using ClEvent = ClHandle<cl_traits::Event>;

// Kernel arguments: a ClMem passes its cl_mem; anything else (a scalar, a cl_mem, a
// standard-layout struct mirrored in OpenCL C) is passed by value with its size.
inline Status SetKernelArg(cl_kernel kernel, cl_uint index, const ClMem& mem) {
  const cl_mem handle = mem.get();
  return OCTO_CL(clSetKernelArg(kernel, index, sizeof(cl_mem), &handle));
}
template <typename T>
Status SetKernelArg(cl_kernel kernel, cl_uint index, const T& value) {
  static_assert(std::is_trivially_copyable_v<T> && std::is_standard_layout_v<T>,
                "kernel arguments are passed by value: plain data only");
  return OCTO_CL(clSetKernelArg(kernel, index, sizeof(T), &value));
}
// Sets arguments 0, 1, … in order; stops at the first failure (the Status names the call).
template <typename... Args>
Status SetKernelArgs(cl_kernel kernel, const Args&... args) {
  Status status;
  cl_uint index = 0;
  // Left-to-right fold that stops once a call failed.
  ((status.ok() ? (void)(status = SetKernelArg(kernel, index++, args)) : (void)0), ...);
  if (!status.ok()) {
    return status.WithContext("kernel argument " + std::to_string(index - 1));
  }
  return status;
}

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_CL_HANDLES_H_
