#include "render/cl_call.h"

#include <cstdio>
#include <string>

namespace octoscope::render {
namespace {

// "a,\n    b" -> "a, b": macro-stringified calls keep the source's line breaks.
std::string CollapseWhitespace(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  bool pending_space = false;
  for (const char ch : text) {
    if (ch == ' ' || ch == '\n' || ch == '\t' || ch == '\r') {
      pending_space = !out.empty();
      continue;
    }
    if (pending_space) out.push_back(' ');
    pending_space = false;
    out.push_back(ch);
  }
  return out;
}

std::string Describe(cl_int code, std::string_view call_text) {
  return CollapseWhitespace(call_text) + " failed: " + std::string(ClErrorName(code)) + " (" +
         std::to_string(code) + ")";
}

}  // namespace

std::string_view ClErrorName(cl_int code) {
  switch (code) {
#define OCTO_CL_ERROR_CASE_(name) \
  case name:                      \
    return #name;
    OCTO_CL_ERROR_CASE_(CL_SUCCESS)
    OCTO_CL_ERROR_CASE_(CL_DEVICE_NOT_FOUND)
    OCTO_CL_ERROR_CASE_(CL_DEVICE_NOT_AVAILABLE)
    OCTO_CL_ERROR_CASE_(CL_COMPILER_NOT_AVAILABLE)
    OCTO_CL_ERROR_CASE_(CL_MEM_OBJECT_ALLOCATION_FAILURE)
    OCTO_CL_ERROR_CASE_(CL_OUT_OF_RESOURCES)
    OCTO_CL_ERROR_CASE_(CL_OUT_OF_HOST_MEMORY)
    OCTO_CL_ERROR_CASE_(CL_PROFILING_INFO_NOT_AVAILABLE)
    OCTO_CL_ERROR_CASE_(CL_MEM_COPY_OVERLAP)
    OCTO_CL_ERROR_CASE_(CL_IMAGE_FORMAT_MISMATCH)
    OCTO_CL_ERROR_CASE_(CL_IMAGE_FORMAT_NOT_SUPPORTED)
    OCTO_CL_ERROR_CASE_(CL_BUILD_PROGRAM_FAILURE)
    OCTO_CL_ERROR_CASE_(CL_MAP_FAILURE)
    OCTO_CL_ERROR_CASE_(CL_MISALIGNED_SUB_BUFFER_OFFSET)
    OCTO_CL_ERROR_CASE_(CL_EXEC_STATUS_ERROR_FOR_EVENTS_IN_WAIT_LIST)
    OCTO_CL_ERROR_CASE_(CL_COMPILE_PROGRAM_FAILURE)
    OCTO_CL_ERROR_CASE_(CL_LINKER_NOT_AVAILABLE)
    OCTO_CL_ERROR_CASE_(CL_LINK_PROGRAM_FAILURE)
    OCTO_CL_ERROR_CASE_(CL_DEVICE_PARTITION_FAILED)
    OCTO_CL_ERROR_CASE_(CL_KERNEL_ARG_INFO_NOT_AVAILABLE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_VALUE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_DEVICE_TYPE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_PLATFORM)
    OCTO_CL_ERROR_CASE_(CL_INVALID_DEVICE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_CONTEXT)
    OCTO_CL_ERROR_CASE_(CL_INVALID_QUEUE_PROPERTIES)
    OCTO_CL_ERROR_CASE_(CL_INVALID_COMMAND_QUEUE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_HOST_PTR)
    OCTO_CL_ERROR_CASE_(CL_INVALID_MEM_OBJECT)
    OCTO_CL_ERROR_CASE_(CL_INVALID_IMAGE_FORMAT_DESCRIPTOR)
    OCTO_CL_ERROR_CASE_(CL_INVALID_IMAGE_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_SAMPLER)
    OCTO_CL_ERROR_CASE_(CL_INVALID_BINARY)
    OCTO_CL_ERROR_CASE_(CL_INVALID_BUILD_OPTIONS)
    OCTO_CL_ERROR_CASE_(CL_INVALID_PROGRAM)
    OCTO_CL_ERROR_CASE_(CL_INVALID_PROGRAM_EXECUTABLE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_KERNEL_NAME)
    OCTO_CL_ERROR_CASE_(CL_INVALID_KERNEL_DEFINITION)
    OCTO_CL_ERROR_CASE_(CL_INVALID_KERNEL)
    OCTO_CL_ERROR_CASE_(CL_INVALID_ARG_INDEX)
    OCTO_CL_ERROR_CASE_(CL_INVALID_ARG_VALUE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_ARG_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_KERNEL_ARGS)
    OCTO_CL_ERROR_CASE_(CL_INVALID_WORK_DIMENSION)
    OCTO_CL_ERROR_CASE_(CL_INVALID_WORK_GROUP_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_WORK_ITEM_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_GLOBAL_OFFSET)
    OCTO_CL_ERROR_CASE_(CL_INVALID_EVENT_WAIT_LIST)
    OCTO_CL_ERROR_CASE_(CL_INVALID_EVENT)
    OCTO_CL_ERROR_CASE_(CL_INVALID_OPERATION)
    OCTO_CL_ERROR_CASE_(CL_INVALID_GL_OBJECT)
    OCTO_CL_ERROR_CASE_(CL_INVALID_BUFFER_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_MIP_LEVEL)
    OCTO_CL_ERROR_CASE_(CL_INVALID_GLOBAL_WORK_SIZE)
    OCTO_CL_ERROR_CASE_(CL_INVALID_PROPERTY)
    OCTO_CL_ERROR_CASE_(CL_INVALID_IMAGE_DESCRIPTOR)
    OCTO_CL_ERROR_CASE_(CL_INVALID_COMPILER_OPTIONS)
    OCTO_CL_ERROR_CASE_(CL_INVALID_LINKER_OPTIONS)
    OCTO_CL_ERROR_CASE_(CL_INVALID_DEVICE_PARTITION_COUNT)
#undef OCTO_CL_ERROR_CASE_
    case -1001:  // CL_PLATFORM_NOT_FOUND_KHR (cl_khr_icd): the ICD loader found no platform.
      return "CL_PLATFORM_NOT_FOUND_KHR";
    default:
      return "CL_UNKNOWN_ERROR";
  }
}

StatusCode ClErrorStatusCode(cl_int code) {
  switch (code) {
    case CL_SUCCESS:
      return StatusCode::kOk;
    case CL_MEM_OBJECT_ALLOCATION_FAILURE:
    case CL_OUT_OF_RESOURCES:
    case CL_OUT_OF_HOST_MEMORY:
    case CL_INVALID_BUFFER_SIZE:
      return StatusCode::kResourceExhausted;
    case CL_DEVICE_NOT_FOUND:
    case CL_DEVICE_NOT_AVAILABLE:
    case -1001:  // CL_PLATFORM_NOT_FOUND_KHR
      return StatusCode::kNotFound;
    case CL_COMPILER_NOT_AVAILABLE:
    case CL_BUILD_PROGRAM_FAILURE:
    case CL_COMPILE_PROGRAM_FAILURE:
    case CL_LINKER_NOT_AVAILABLE:
    case CL_LINK_PROGRAM_FAILURE:
      return StatusCode::kUnsupported;
    default:
      return StatusCode::kInternal;
  }
}

Status ClCheck(cl_int code, std::string_view call_text) {
  if (code == CL_SUCCESS) return Status::Ok();
  return Status(ClErrorStatusCode(code), Describe(code, call_text));
}

void ClLogError(cl_int code, std::string_view call_text) noexcept {
  if (code == CL_SUCCESS) return;
  try {
    std::fprintf(stderr, "octoscope: %s (ignored)\n", Describe(code, call_text).c_str());
  } catch (...) {
    // Out of memory while formatting: nothing sensible left to report.
  }
}

}  // namespace octoscope::render
