// The OpenCL C sources of kernels/*.cl (and the headers kernels/*.h they include), compiled into
// the binary at build time (cmake/embed_kernels.cmake), so programs can be built without files at
// run time and the kernels stay plain .cl files that editors and offline compilers understand.
//
// Thread safety: immutable data.
#ifndef OCTOSCOPE_RENDER_EMBEDDED_KERNELS_H_
#define OCTOSCOPE_RENDER_EMBEDDED_KERNELS_H_

#include <optional>
#include <span>
#include <string_view>

namespace octoscope::render {

struct EmbeddedKernel {
  std::string_view name;    // File name, e.g. "octree_sampling.cl".
  std::string_view source;  // Its complete text.
};

// Every kernel file, sorted by name.
std::span<const EmbeddedKernel> EmbeddedKernels();

// The source of `name`, or nullopt.
inline std::optional<std::string_view> FindEmbeddedKernel(std::string_view name) {
  for (const EmbeddedKernel& k : EmbeddedKernels()) {
    if (k.name == name) return k.source;
  }
  return std::nullopt;
}

}  // namespace octoscope::render

#endif  // OCTOSCOPE_RENDER_EMBEDDED_KERNELS_H_
