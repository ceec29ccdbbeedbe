// Checked OpenCL calls: every OpenCL C API call of the renderer goes through OCTO_CL (for calls
// that return a cl_int) or ClCheck (for clCreate* calls that report through errcode_ret), which
// turn an error code into a Status whose message keeps the failing call's source text and the
// error's name, e.g.
//   "clBuildProgram(program, 1, &device, options, nullptr, nullptr) failed:
//   CL_BUILD_PROGRAM_FAILURE (-11)".
// Destructors use OCTO_CL_LOG, which only reports to stderr: a release never fails the caller
// (the pattern of CLBlast's CheckError / CheckErrorDtor, without exceptions).
//
// Usage:
//   OCTO_RETURN_IF_ERROR(OCTO_CL(clFinish(queue)));
//   cl_int err = CL_SUCCESS;
//   cl_mem mem = clCreateBuffer(context, flags, bytes, nullptr, &err);
//   OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateBuffer"));
//
// Thread safety: pure functions (ClLogError writes one line to stderr at a time).
#ifndef OCTOSCOPE_RENDER_CL_CALL_H_
#define OCTOSCOPE_RENDER_CL_CALL_H_

#include <CL/cl.h>

#include <string>
#include <string_view>

#include "util/status.h"

namespace octoscope::render {

// "CL_OUT_OF_RESOURCES" etc.; "CL_UNKNOWN_ERROR" for a code OpenCL 1.2 (plus the ICD loader's
// CL_PLATFORM_NOT_FOUND_KHR) does not define.
std::string_view ClErrorName(cl_int code);

// The StatusCode an OpenCL error maps to: memory errors are kResourceExhausted, a missing
// platform/device kNotFound, a failed compile or an absent compiler kUnsupported, anything else
// (invalid arguments, objects: bugs of ours) kInternal.
StatusCode ClErrorStatusCode(cl_int code);

// OK for CL_SUCCESS, else "<call_text> failed: <name> (<code>)" with whitespace runs in the call
// text collapsed to one space.
Status ClCheck(cl_int code, std::string_view call_text);

// For destructors and other places that cannot report: writes
// "octoscope: <call_text> failed: <name> (<code>) (ignored)" to stderr unless code is CL_SUCCESS.
// Never throws.
void ClLogError(cl_int code, std::string_view call_text) noexcept;

}  // namespace octoscope::render

// Evaluates an OpenCL call returning cl_int; yields a Status naming the call on failure.
#define OCTO_CL(call) ::octoscope::render::ClCheck((call), #call)
// The same, returning the Status from the enclosing function on failure.
#define OCTO_CL_RETURN_IF_ERROR(call) OCTO_RETURN_IF_ERROR(OCTO_CL(call))
// For destructors: logs a failure and carries on.
#define OCTO_CL_LOG(call) ::octoscope::render::ClLogError((call), #call)

#endif  // OCTOSCOPE_RENDER_CL_CALL_H_
