// OpenCL devices: enumeration of every platform's devices, the choice of the device to render on,
// and a ComputeContext (context + in-order command queue on that one device).
//
// Choice (ChooseDevice): with an empty preference or "auto", the best AVAILABLE device that has a
// compiler — GPUs first, then CPUs, then accelerators/others; within a type the one with the most
// global memory, ties in enumeration order. A user preference (config / CLI) overrides it:
//   "gpu" | "cpu"   the best available device of that type;
//   "N"             the N-th device of ListDevices() (0-based, the order `clinfo -l` shows);
//   "P:D"           device D of platform P;
//   anything else   the first device whose "platform name / device name" contains the text,
//                   case-insensitively (e.g. "nvidia", "pthread", "Portable Computing").
// An override that matches nothing is kNotFound naming the devices that exist.
//
// Thread safety: the functions are thread-safe (the OpenCL API is). ComputeContext is immutable
// after creation; its handles may be used from any thread (OpenCL contexts and queues are
// thread-safe; enqueues from several threads interleave on the one queue).
#ifndef OCTOSCOPE_RENDER_DEVICE_H_
#define OCTOSCOPE_RENDER_DEVICE_H_

#include <CL/cl.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "render/cl_handles.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::render {

enum class DeviceType { kGpu, kCpu, kAccelerator, kOther };
std::string_view DeviceTypeName(DeviceType type);  // "GPU", "CPU", "accelerator", "other".

struct DeviceInfo {
  cl_platform_id platform = nullptr;
  cl_device_id device = nullptr;
  int platform_index = 0;  // Position in clGetPlatformIDs' list.
  int device_index = 0;    // Position in the platform's clGetDeviceIDs(CL_DEVICE_TYPE_ALL) list.
  int flat_index = 0;      // Position in ListDevices().
  std::string platform_name;
  std::string name;
  std::string vendor;
  std::string version;         // CL_DEVICE_VERSION, e.g. "OpenCL 3.0 CUDA".
  std::string driver_version;  // CL_DRIVER_VERSION.
  DeviceType type = DeviceType::kOther;
  uint64_t global_memory_bytes = 0;  // CL_DEVICE_GLOBAL_MEM_SIZE.
  uint64_t max_alloc_bytes = 0;      // CL_DEVICE_MAX_MEM_ALLOC_SIZE: the largest single buffer.
  uint32_t compute_units = 0;
  size_t max_work_group_size = 0;
  bool available = false;              // CL_DEVICE_AVAILABLE.
  bool compiler_available = false;     // CL_DEVICE_COMPILER_AVAILABLE: can build from source.
  uint32_t preferred_float_width = 1;  // CL_DEVICE_PREFERRED_VECTOR_WIDTH_FLOAT.

  // "0:0 CPU pthread-skylake… (Portable Computing Language), 16 CUs, 62.5 GiB (max buffer 16 GiB)".
  std::string ToString() const;
};

// The widest step of the ray casters' brick runs (kernels' OCTO_RUN_LANES): 8 samples at a time
// where the device prefers float vectors of 8 or more (CPUs with AVX: one step fills a register),
// else 4 (GPUs prefer scalars: each work item's lanes are registers of its own).
int RunLanes(const DeviceInfo& device);

// Every device of every platform, platforms in order, devices in order. No platform (no ICD
// installed) is an empty list, not an error. A platform whose device query fails is skipped;
// a failing query on a listed device is an error naming it.
Result<std::vector<DeviceInfo>> ListDevices();

// Picks a device from `devices` by `preference` (see the file comment). kNotFound when nothing
// suitable exists (the message lists `devices`).
Result<DeviceInfo> ChooseDevice(std::span<const DeviceInfo> devices, std::string_view preference);
// ListDevices() + ChooseDevice().
Result<DeviceInfo> ChooseDevice(std::string_view preference);

// A context and an in-order command queue on one device.
// Invariant: context() and queue() are valid handles on device().
class ComputeContext {
 public:
  static Result<ComputeContext> Create(const DeviceInfo& device);

  ComputeContext(ComputeContext&&) noexcept = default;
  ComputeContext& operator=(ComputeContext&&) noexcept = default;

  const DeviceInfo& device() const { return device_; }
  cl_device_id device_id() const { return device_.device; }
  cl_context context() const { return context_.get(); }
  cl_command_queue queue() const { return queue_.get(); }

  // A device buffer of `bytes` (> 0); with `host_data` (bytes long) initialised from it
  // (CL_MEM_COPY_HOST_PTR is added to `flags`). kResourceExhausted when bytes exceeds
  // device().max_alloc_bytes or the device is out of memory.
  Result<ClMem> CreateBuffer(cl_mem_flags flags, size_t bytes,
                             const void* host_data = nullptr) const;
  // Blocking copies between host memory and `buffer` (offset and size in bytes).
  Status WriteBuffer(const ClMem& buffer, size_t offset, size_t bytes, const void* data) const;
  Status ReadBuffer(const ClMem& buffer, size_t offset, size_t bytes, void* data) const;
  // Enqueues a 1-D range of `global` work items, local size chosen by the driver (nothing for 0).
  // Does not wait: Finish() or a blocking read does.
  Status EnqueueKernel1D(cl_kernel kernel, size_t global) const;
  // Waits until every queued command finished.
  Status Finish() const;

 private:
  ComputeContext(DeviceInfo device, ClContext context, ClQueue queue)
      : device_(std::move(device)), context_(std::move(context)), queue_(std::move(queue)) {}

  DeviceInfo device_;
  ClContext context_;
  ClQueue queue_;  // Destroyed before the context (reverse member order).
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_DEVICE_H_
