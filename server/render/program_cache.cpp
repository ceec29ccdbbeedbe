#include "render/program_cache.h"

#include <optional>
#include <set>
#include <vector>

#include "render/cl_call.h"
#include "render/embedded_kernels.h"

namespace octoscope::render {
namespace {

constexpr int kMaxIncludeDepth = 16;

// The quoted file name of a `#include "x"` line; "" for any other line (including <system>
// includes). Sets *malformed when the line starts like an include but names no file properly.
std::string_view IncludedName(std::string_view line, bool* malformed) {
  *malformed = false;
  size_t i = line.find_first_not_of(" \t");
  if (i == std::string_view::npos || line[i] != '#') return {};
  i = line.find_first_not_of(" \t", i + 1);
  if (i == std::string_view::npos || line.substr(i, 7) != "include") return {};
  i = line.find_first_not_of(" \t", i + 7);
  // <system> includes are left to the device compiler.
  if (i == std::string_view::npos || line[i] != '"') {
    *malformed = i == std::string_view::npos;
    return {};
  }
  const size_t end = line.find('"', i + 1);
  if (end == std::string_view::npos || end == i + 1) {
    *malformed = true;
    return {};
  }
  return line.substr(i + 1, end - i - 1);
}

Status Expand(std::string_view name, std::string_view source, int depth,
              std::set<std::string, std::less<>>* included, std::string* out) {
  if (depth > kMaxIncludeDepth) {
    return InvalidArgumentError("kernel " + std::string(name) + ": includes nest deeper than " +
                                std::to_string(kMaxIncludeDepth) + " files");
  }
  *out += "#line 1 \"" + std::string(name) + "\"\n";
  size_t line_number = 0;
  size_t pos = 0;
  while (pos < source.size()) {
    size_t end = source.find('\n', pos);
    if (end == std::string_view::npos) end = source.size();
    const std::string_view line = source.substr(pos, end - pos);
    pos = end + 1;
    ++line_number;
    bool malformed = false;
    const std::string_view included_name = IncludedName(line, &malformed);
    if (malformed) {
      return InvalidArgumentError("kernel " + std::string(name) + ":" +
                                  std::to_string(line_number) + ": malformed #include");
    }
    if (included_name.empty()) {
      *out += line;
      *out += '\n';
      continue;
    }
    // Each file at most once per program (include guards are then a formality).
    if (included->insert(std::string(included_name)).second) {
      const std::optional<std::string_view> text = FindEmbeddedKernel(included_name);
      if (!text) {
        return NotFoundError("kernel " + std::string(name) + ":" + std::to_string(line_number) +
                             ": #include \"" + std::string(included_name) +
                             "\" is not an embedded kernel file (kernels/ is embedded by "
                             "cmake/embed_kernels.cmake)");
      }
      OCTO_RETURN_IF_ERROR(Expand(included_name, *text, depth + 1, included, out));
    }
    // Back in this file: the next line is line_number + 1.
    *out += "#line " + std::to_string(line_number + 1) + " \"" + std::string(name) + "\"\n";
  }
  return Status::Ok();
}

}  // namespace

Result<std::string> ResolveKernelIncludes(std::string_view name, std::string_view source) {
  std::set<std::string, std::less<>> included{std::string(name)};
  std::string out;
  out.reserve(source.size() * 2);
  OCTO_RETURN_IF_ERROR(Expand(name, source, 0, &included, &out));
  return out;
}

std::string ProgramBuildLog(cl_program program, cl_device_id device) {
  size_t bytes = 0;
  if (clGetProgramBuildInfo(program, device, CL_PROGRAM_BUILD_LOG, 0, nullptr, &bytes) !=
          CL_SUCCESS ||
      bytes == 0) {
    return {};
  }
  std::string log(bytes, '\0');
  if (clGetProgramBuildInfo(program, device, CL_PROGRAM_BUILD_LOG, bytes, log.data(), nullptr) !=
      CL_SUCCESS) {
    return {};
  }
  while (!log.empty() && (log.back() == '\0' || log.back() == '\n')) log.pop_back();
  return log;
}

Result<ClProgram> BuildProgram(const ComputeContext& context, std::string_view name,
                               std::string_view source, std::string_view options) {
  OCTO_ASSIGN_OR_RETURN(const std::string text, ResolveKernelIncludes(name, source));
  const char* text_ptr = text.c_str();
  const size_t text_size = text.size();
  cl_int err = CL_SUCCESS;
  ClProgram program(clCreateProgramWithSource(context.context(), 1, &text_ptr, &text_size, &err));
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateProgramWithSource").WithContext(name));
  std::string all_options(kDefaultBuildOptions);
  if (!options.empty()) all_options += " " + std::string(options);
  const cl_device_id device = context.device_id();
  const cl_program handle = program.get();
  const char* options_ptr = all_options.c_str();
  Status status = OCTO_CL(clBuildProgram(handle, 1, &device, options_ptr, nullptr, nullptr));
  if (!status.ok()) {
    // The log is the only useful part of a compile error: keep all of it.
    const std::string log = ProgramBuildLog(handle, device);
    return Status(status.code(), std::string(name) + " (options \"" + all_options +
                                     "\"): " + status.message() + "; build log:\n" +
                                     (log.empty() ? "(empty)" : log));
  }
  return program;
}

Result<cl_program> ProgramCache::Get(std::string_view file, std::string_view options) {
  std::shared_ptr<Entry> entry;
  {
    std::lock_guard lock(mu_);
    auto& slot = entries_[{std::string(file), std::string(options)}];
    if (!slot) slot = std::make_shared<Entry>();
    entry = slot;
  }
  std::lock_guard lock(entry->mu);
  if (!entry->done) {
    const std::optional<std::string_view> source = FindEmbeddedKernel(file);
    if (!source) {
      entry->status = NotFoundError("kernel file " + std::string(file) + " is not embedded");
    } else {
      Result<ClProgram> program = BuildProgram(*context_, file, *source, options);
      if (program.ok()) {
        entry->program = std::move(*program);
      } else {
        entry->status = program.status();
      }
    }
    entry->done = true;
  }
  if (!entry->status.ok()) return entry->status;
  return entry->program.get();
}

Result<ClKernel> ProgramCache::CreateKernel(std::string_view file, std::string_view kernel_name,
                                            std::string_view options) {
  OCTO_ASSIGN_OR_RETURN(const cl_program program, Get(file, options));
  const std::string kernel(kernel_name);
  cl_int err = CL_SUCCESS;
  ClKernel result(clCreateKernel(program, kernel.c_str(), &err));
  OCTO_RETURN_IF_ERROR(ClCheck(err, "clCreateKernel(" + kernel + ")").WithContext(file));
  return result;
}

size_t ProgramCache::size() const {
  std::lock_guard lock(mu_);
  return entries_.size();
}

}  // namespace octoscope::render
