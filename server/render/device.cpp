#include "render/device.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cstdio>
#include <utility>

#include "render/cl_call.h"

namespace octoscope::render {
namespace {

// A string-valued clGetPlatformInfo / clGetDeviceInfo: size query, then the text without the NUL.
template <typename Object, typename Query>
Result<std::string> InfoString(Query query, Object object, cl_uint param, const char* call) {
  size_t bytes = 0;
  OCTO_RETURN_IF_ERROR(ClCheck(query(object, param, 0, nullptr, &bytes), call));
  std::string text(bytes, '\0');
  if (bytes > 0) {
    OCTO_RETURN_IF_ERROR(ClCheck(query(object, param, bytes, text.data(), nullptr), call));
  }
  while (!text.empty() && (text.back() == '\0' || text.back() == ' ')) text.pop_back();
  return text;
}

template <typename T>
Status DeviceValue(cl_device_id device, cl_device_info param, T* out) {
  return OCTO_CL(clGetDeviceInfo(device, param, sizeof(T), out, nullptr));
}

Result<DeviceInfo> QueryDevice(cl_platform_id platform, cl_device_id device) {
  DeviceInfo info;
  info.platform = platform;
  info.device = device;
  OCTO_ASSIGN_OR_RETURN(
      info.platform_name,
      InfoString(clGetPlatformInfo, platform, CL_PLATFORM_NAME, "clGetPlatformInfo(NAME)"));
  OCTO_ASSIGN_OR_RETURN(
      info.name, InfoString(clGetDeviceInfo, device, CL_DEVICE_NAME, "clGetDeviceInfo(NAME)"));
  OCTO_ASSIGN_OR_RETURN(info.vendor, InfoString(clGetDeviceInfo, device, CL_DEVICE_VENDOR,
                                                "clGetDeviceInfo(VENDOR)"));
  OCTO_ASSIGN_OR_RETURN(info.version, InfoString(clGetDeviceInfo, device, CL_DEVICE_VERSION,
                                                 "clGetDeviceInfo(VERSION)"));
  OCTO_ASSIGN_OR_RETURN(info.driver_version, InfoString(clGetDeviceInfo, device, CL_DRIVER_VERSION,
                                                        "clGetDeviceInfo(DRIVER_VERSION)"));
  cl_device_type type = 0;
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_TYPE, &type));
  // A device may report several bits (e.g. CPU | DEFAULT): GPU wins, then CPU, then accelerator.
  info.type = (type & CL_DEVICE_TYPE_GPU)           ? DeviceType::kGpu
              : (type & CL_DEVICE_TYPE_CPU)         ? DeviceType::kCpu
              : (type & CL_DEVICE_TYPE_ACCELERATOR) ? DeviceType::kAccelerator
                                                    : DeviceType::kOther;
  cl_ulong global = 0, max_alloc = 0;
  cl_uint units = 0, float_width = 1;
  size_t group = 0;
  cl_bool available = CL_FALSE, compiler = CL_FALSE;
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_GLOBAL_MEM_SIZE, &global));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_MAX_MEM_ALLOC_SIZE, &max_alloc));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_MAX_COMPUTE_UNITS, &units));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_MAX_WORK_GROUP_SIZE, &group));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_AVAILABLE, &available));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_COMPILER_AVAILABLE, &compiler));
  OCTO_RETURN_IF_ERROR(DeviceValue(device, CL_DEVICE_PREFERRED_VECTOR_WIDTH_FLOAT, &float_width));
  info.global_memory_bytes = global;
  info.max_alloc_bytes = max_alloc;
  info.compute_units = units;
  info.max_work_group_size = group;
  info.available = available == CL_TRUE;
  info.compiler_available = compiler == CL_TRUE;
  info.preferred_float_width = float_width;
  return info;
}

std::string Lower(std::string_view text) {
  std::string out(text);
  for (char& ch : out) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return out;
}

std::string FormatGiB(uint64_t bytes) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f GiB", static_cast<double>(bytes) / (1u << 30));
  return text;
}

bool ParseIndex(std::string_view text, int* out) {
  if (text.empty()) return false;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), *out);
  return ec == std::errc() && end == text.data() + text.size() && *out >= 0;
}

std::string DeviceList(std::span<const DeviceInfo> devices) {
  if (devices.empty()) return "no OpenCL device is installed";
  std::string list = "devices:";
  for (const DeviceInfo& d : devices)
    list += " [" + std::to_string(d.flat_index) + "] " + d.ToString() + ";";
  list.pop_back();
  return list;
}

int TypeRank(DeviceType type) {
  switch (type) {
    case DeviceType::kGpu:
      return 0;
    case DeviceType::kCpu:
      return 1;
    case DeviceType::kAccelerator:
      return 2;
    case DeviceType::kOther:
      break;
  }
  return 3;
}

// The best usable device, optionally of one type only.
const DeviceInfo* Best(std::span<const DeviceInfo> devices, const DeviceType* only) {
  const DeviceInfo* best = nullptr;
  for (const DeviceInfo& d : devices) {
    if (!d.available || !d.compiler_available) continue;
    if (only != nullptr && d.type != *only) continue;
    // Strictly better only, so ties keep the earlier device.
    if (best == nullptr || TypeRank(d.type) < TypeRank(best->type) ||
        (TypeRank(d.type) == TypeRank(best->type) &&
         d.global_memory_bytes > best->global_memory_bytes)) {
      best = &d;
    }
  }
  return best;
}

}  // namespace

std::string_view DeviceTypeName(DeviceType type) {
  switch (type) {
    case DeviceType::kGpu:
      return "GPU";
    case DeviceType::kCpu:
      return "CPU";
    case DeviceType::kAccelerator:
      return "accelerator";
    case DeviceType::kOther:
      break;
  }
  return "other";
}

std::string DeviceInfo::ToString() const {
  std::string text = std::to_string(platform_index) + ":" + std::to_string(device_index) + " " +
                     std::string(DeviceTypeName(type)) + " " + name + " (" + platform_name + "), " +
                     std::to_string(compute_units) + " CUs, " + FormatGiB(global_memory_bytes) +
                     " (max buffer " + FormatGiB(max_alloc_bytes) + ")";
  if (!available) text += ", unavailable";
  if (!compiler_available) text += ", no compiler";
  return text;
}

int RunLanes(const DeviceInfo& device) { return device.preferred_float_width >= 8 ? 8 : 4; }

Result<std::vector<DeviceInfo>> ListDevices() {
  cl_uint platform_count = 0;
  const cl_int err = clGetPlatformIDs(0, nullptr, &platform_count);
  // The ICD loader reports "no platform" as CL_PLATFORM_NOT_FOUND_KHR (-1001).
  if (err == -1001 || (err == CL_SUCCESS && platform_count == 0)) return std::vector<DeviceInfo>{};
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clGetPlatformIDs(0, nullptr, &platform_count)"));
  std::vector<cl_platform_id> platforms(platform_count);
  OCTO_CL_RETURN_IF_ERROR(clGetPlatformIDs(platform_count, platforms.data(), nullptr));

  std::vector<DeviceInfo> devices;
  for (cl_uint p = 0; p < platform_count; ++p) {
    cl_uint device_count = 0;
    // A platform without devices answers CL_DEVICE_NOT_FOUND; a broken one is skipped as well, so
    // one bad driver does not hide the others.
    if (clGetDeviceIDs(platforms[p], CL_DEVICE_TYPE_ALL, 0, nullptr, &device_count) != CL_SUCCESS ||
        device_count == 0) {
      continue;
    }
    std::vector<cl_device_id> ids(device_count);
    if (clGetDeviceIDs(platforms[p], CL_DEVICE_TYPE_ALL, device_count, ids.data(), nullptr) !=
        CL_SUCCESS) {
      continue;
    }
    for (cl_uint d = 0; d < device_count; ++d) {
      Result<DeviceInfo> info = QueryDevice(platforms[p], ids[d]);
      if (!info.ok()) {
        return info.status().WithContext("OpenCL platform " + std::to_string(p) + " device " +
                                         std::to_string(d));
      }
      info->platform_index = static_cast<int>(p);
      info->device_index = static_cast<int>(d);
      info->flat_index = static_cast<int>(devices.size());
      devices.push_back(std::move(*info));
    }
  }
  return devices;
}

Result<DeviceInfo> ChooseDevice(std::span<const DeviceInfo> devices, std::string_view preference) {
  const std::string pref = Lower(preference);
  if (pref.empty() || pref == "auto" || pref == "gpu" || pref == "cpu") {
    DeviceType type = pref == "cpu" ? DeviceType::kCpu : DeviceType::kGpu;
    const bool typed = pref == "gpu" || pref == "cpu";
    const DeviceInfo* best = Best(devices, typed ? &type : nullptr);
    if (best == nullptr) {
      return NotFoundError("OpenCL: no usable " +
                           (typed ? std::string(DeviceTypeName(type)) + " " : "") +
                           "device (available, with a compiler); " + DeviceList(devices));
    }
    return *best;
  }
  int index = 0;
  if (ParseIndex(pref, &index)) {
    if (index < static_cast<int>(devices.size())) return devices[static_cast<size_t>(index)];
    return NotFoundError("OpenCL: device index " + std::string(preference) + " does not exist; " +
                         DeviceList(devices));
  }
  const size_t colon = pref.find(':');
  int platform = 0;
  if (colon != std::string::npos &&
      ParseIndex(std::string_view(pref).substr(0, colon), &platform) &&
      ParseIndex(std::string_view(pref).substr(colon + 1), &index)) {
    for (const DeviceInfo& d : devices) {
      if (d.platform_index == platform && d.device_index == index) return d;
    }
    return NotFoundError("OpenCL: no device " + std::string(preference) + "; " +
                         DeviceList(devices));
  }
  for (const DeviceInfo& d : devices) {
    if (Lower(d.platform_name + " / " + d.name).find(pref) != std::string::npos) return d;
  }
  return NotFoundError("OpenCL: no device matches \"" + std::string(preference) + "\"; " +
                       DeviceList(devices));
}

Result<DeviceInfo> ChooseDevice(std::string_view preference) {
  OCTO_ASSIGN_OR_RETURN(const std::vector<DeviceInfo> devices, ListDevices());
  return ChooseDevice(devices, preference);
}

Result<ComputeContext> ComputeContext::Create(const DeviceInfo& device) {
  if (device.device == nullptr) return InvalidArgumentError("OpenCL: no device given");
  const cl_context_properties properties[] = {
      CL_CONTEXT_PLATFORM, reinterpret_cast<cl_context_properties>(device.platform), 0};
  cl_int err = CL_SUCCESS;
  ClContext context(clCreateContext(properties, 1, &device.device, nullptr, nullptr, &err));
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateContext(" + device.name + ")"));
  // clCreateCommandQueue is the OpenCL 1.2 entry point (CL_TARGET_OPENCL_VERSION=120); in-order.
  ClQueue queue(clCreateCommandQueue(context.get(), device.device, 0, &err));
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateCommandQueue(" + device.name + ")"));
  return ComputeContext(device, std::move(context), std::move(queue));
}

Result<ClMem> ComputeContext::CreateBuffer(cl_mem_flags flags, size_t bytes,
                                           const void* host_data) const {
  if (bytes == 0) return InvalidArgumentError("OpenCL: buffer of 0 bytes");
  if (bytes > device_.max_alloc_bytes) {
    return ResourceExhaustedError("OpenCL: a buffer of " + std::to_string(bytes) +
                                  " bytes exceeds the device's largest allocation of " +
                                  std::to_string(device_.max_alloc_bytes) + " bytes (" +
                                  device_.name + ")");
  }
  if (host_data != nullptr) flags |= CL_MEM_COPY_HOST_PTR;
  cl_int err = CL_SUCCESS;
  // The API takes void* even for COPY_HOST_PTR, which only reads it.
  ClMem buffer(clCreateBuffer(context_.get(), flags, bytes, const_cast<void*>(host_data), &err));
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateBuffer(" + std::to_string(bytes) + " bytes)"));
  return buffer;
}

Status ComputeContext::WriteBuffer(const ClMem& buffer, size_t offset, size_t bytes,
                                   const void* data) const {
  return OCTO_CL(clEnqueueWriteBuffer(queue_.get(), buffer.get(), CL_TRUE, offset, bytes, data, 0,
                                      nullptr, nullptr));
}

Status ComputeContext::ReadBuffer(const ClMem& buffer, size_t offset, size_t bytes,
                                  void* data) const {
  return OCTO_CL(clEnqueueReadBuffer(queue_.get(), buffer.get(), CL_TRUE, offset, bytes, data, 0,
                                     nullptr, nullptr));
}

Status ComputeContext::EnqueueKernel1D(cl_kernel kernel, size_t global) const {
  if (global == 0) return Status::Ok();
  return OCTO_CL(clEnqueueNDRangeKernel(queue_.get(), kernel, 1, nullptr, &global, nullptr, 0,
                                        nullptr, nullptr));
}

Status ComputeContext::Finish() const { return OCTO_CL(clFinish(queue_.get())); }

}  // namespace octoscope::render
