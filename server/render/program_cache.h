// ProgramCache: builds each OpenCL program from the embedded kernels/*.cl sources
// (embedded_kernels.h) at most once per (file, build options) for one ComputeContext, and hands
// out kernels of it. A failed build is remembered too (a kernel does not start compiling on a
// retry) and its Status carries the device compiler's complete build log.
//
// Includes: `#include "name"` lines of a kernel source are resolved against the other embedded
// kernel files (kernels/node_format.h, kernels/octree_sampling.cl, …), textually and at most once
// per program, with #line directives so the build log names the right file and line. The binary
// thus needs no files at run time and the device compiler never sees a file system path.
//
// Build options: kDefaultBuildOptions ("-cl-std=CL1.2") plus the caller's, e.g. defines that
// configure a kernel ("-DSTEPS=4"), like CLBlast's WGS/VW parameters.
//
// Thread safety: all methods are thread-safe. Concurrent requests for the same program wait for
// one build; different programs build concurrently. Returned cl_program handles stay owned by
// the cache (valid while it lives); each CreateKernel call returns a fresh cl_kernel, so threads
// never share a kernel's argument state.
#ifndef OCTOSCOPE_RENDER_PROGRAM_CACHE_H_
#define OCTOSCOPE_RENDER_PROGRAM_CACHE_H_

#include <CL/cl.h>

#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>

#include "render/cl_handles.h"
#include "render/device.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::render {

inline constexpr std::string_view kDefaultBuildOptions = "-cl-std=CL1.2";

// `source` (named `name` in messages) with every `#include "x"` replaced by the embedded file x.
// kNotFound naming the including file and line when x is not embedded; kInvalidArgument for an
// include cycle deeper than 16 files or a malformed include line.
Result<std::string> ResolveKernelIncludes(std::string_view name, std::string_view source);

// Builds `source` (after ResolveKernelIncludes) for `context`'s device with kDefaultBuildOptions
// plus `options`. On a compile error: kUnsupported "<name>: clBuildProgram(...) failed:
// CL_BUILD_PROGRAM_FAILURE (-11); build log:\n<log>". Not cached.
Result<ClProgram> BuildProgram(const ComputeContext& context, std::string_view name,
                               std::string_view source, std::string_view options = "");

// The device compiler's log for `program` on `device` (empty when none).
std::string ProgramBuildLog(cl_program program, cl_device_id device);

class ProgramCache {
 public:
  // `context` must outlive the cache.
  explicit ProgramCache(const ComputeContext* context) : context_(context) {}
  ProgramCache(const ProgramCache&) = delete;
  ProgramCache& operator=(const ProgramCache&) = delete;

  // The program built from embedded file `file` (e.g. "sample_points.cl") with `options`; built
  // on the first request. kNotFound when no such file is embedded.
  Result<cl_program> Get(std::string_view file, std::string_view options = "");
  // A new kernel object `kernel_name` of that program (the caller owns it).
  Result<ClKernel> CreateKernel(std::string_view file, std::string_view kernel_name,
                                std::string_view options = "");

  const ComputeContext& context() const { return *context_; }
  // Programs built or attempted so far (successful or not).
  size_t size() const;

 private:
  // One (file, options) program. `done`, `status` and `program` are guarded by `mu`, held for the
  // whole build, so a second requester waits for the first one's outcome.
  struct Entry {
    std::mutex mu;
    bool done = false;
    Status status;
    ClProgram program;
  };

  const ComputeContext* const context_;
  mutable std::mutex mu_;  // Guards entries_ (the map only; not the entries' builds).
  std::map<std::pair<std::string, std::string>, std::shared_ptr<Entry>> entries_;
};

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_PROGRAM_CACHE_H_
