// The OpenCL device shared by the render tests of one binary: one ComputeContext and one
// ProgramCache, created on first use, so every program is compiled once per test binary (PoCL
// takes a second or two per program). Tests that need a device start with
// OCTO_REQUIRE_OPENCL_DEVICE(), which skips them when the machine has no OpenCL device.
// The device is the automatic choice (GPU first, then CPU) unless OCTOSCOPE_TEST_CL_DEVICE holds
// a preference string (render/device.h).
//
// Thread safety: the accessors are thread-safe (function-local statics).
#ifndef OCTOSCOPE_TESTS_RENDER_CL_TEST_ENV_H_
#define OCTOSCOPE_TESTS_RENDER_CL_TEST_ENV_H_

#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "render/device.h"
#include "render/program_cache.h"

namespace octoscope::render::testing {

// Every test builds with these options, so a program is built once however many tests use it;
// -Werror keeps the kernels free of compiler warnings.
inline constexpr const char* kTestBuildOptions = "-Werror";

struct ClTestEnv {
  ComputeContext* context = nullptr;  // nullptr when no device could be opened.
  ProgramCache* programs = nullptr;
  std::string why_not;  // Why there is no context.
};

inline const ClTestEnv& SharedClTestEnv() {
  static const ClTestEnv env = [] {
    ClTestEnv e;
    const char* preference = std::getenv("OCTOSCOPE_TEST_CL_DEVICE");
    Result<DeviceInfo> device = ChooseDevice(preference != nullptr ? preference : "");
    if (!device.ok()) {
      e.why_not = device.status().ToString();
      return e;
    }
    Result<ComputeContext> context = ComputeContext::Create(*device);
    if (!context.ok()) {
      e.why_not = context.status().ToString();
      return e;
    }
    // Deliberately leaked: destroying OpenCL objects from static destructors races the driver's
    // own teardown at exit.
    e.context = new ComputeContext(std::move(*context));
    e.programs = new ProgramCache(e.context);
    return e;
  }();
  return env;
}

}  // namespace octoscope::render::testing

#define OCTO_REQUIRE_OPENCL_DEVICE()                                           \
  do {                                                                         \
    if (::octoscope::render::testing::SharedClTestEnv().context == nullptr) {  \
      GTEST_SKIP() << "no OpenCL device: "                                     \
                   << ::octoscope::render::testing::SharedClTestEnv().why_not; \
    }                                                                          \
  } while (0)

#endif  // OCTOSCOPE_TESTS_RENDER_CL_TEST_ENV_H_
