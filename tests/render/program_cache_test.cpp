#include "render/program_cache.h"

#include <gtest/gtest.h>

#include <string>
#include <thread>
#include <vector>

#include "cl_test_env.h"
#include "render/embedded_kernels.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::kTestBuildOptions;
using ::octoscope::render::testing::SharedClTestEnv;

bool EndsWith(std::string_view text, std::string_view suffix) {
  return text.size() >= suffix.size() && text.substr(text.size() - suffix.size()) == suffix;
}

size_t Count(std::string_view text, std::string_view what) {
  size_t n = 0;
  for (size_t pos = text.find(what); pos != std::string_view::npos;
       pos = text.find(what, pos + 1)) {
    ++n;
  }
  return n;
}

TEST(ResolveKernelIncludesTest, InlinesEmbeddedFilesOnceWithLineDirectives) {
  const auto source = FindEmbeddedKernel("sample_points.cl");
  ASSERT_TRUE(source.has_value());
  auto resolved = ResolveKernelIncludes("sample_points.cl", *source);
  ASSERT_TRUE(resolved.ok()) << resolved.status().ToString();
  // sample_points.cl includes octree_sampling.cl, which includes node_format.h.
  EXPECT_EQ(Count(*resolved, "#define OCTO_NODE_IN_BUFFER_BIT"), 1u);
  EXPECT_EQ(Count(*resolved, "OctoNodeHit OctoFindNode("), 1u);
  EXPECT_EQ(Count(*resolved, "__kernel void SamplePoints("), 1u);
  EXPECT_EQ(Count(*resolved, "#include \""), 0u);
  EXPECT_EQ(resolved->rfind("#line 1 \"sample_points.cl\"\n", 0), 0u);
  EXPECT_NE(resolved->find("#line 1 \"node_format.h\"\n"), std::string::npos);
}

TEST(ResolveKernelIncludesTest, SecondIncludeOfAFileIsDropped) {
  auto resolved = ResolveKernelIncludes(
      "twice.cl", "#include \"node_format.h\"\n  #  include \"node_format.h\"\nint x;\n");
  ASSERT_TRUE(resolved.ok()) << resolved.status().ToString();
  EXPECT_EQ(Count(*resolved, "#define OCTO_NODE_WORDS"), 1u);
  // Line numbers resume correctly after each include.
  EXPECT_NE(resolved->find("#line 3 \"twice.cl\"\nint x;\n"), std::string::npos) << *resolved;
}

TEST(ResolveKernelIncludesTest, MissingAndMalformedIncludesAreErrors) {
  auto missing = ResolveKernelIncludes("a.cl", "int x;\n#include \"no_such_file.h\"\n");
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("a.cl:2: #include \"no_such_file.h\""),
            std::string::npos)
      << missing.status().message();
  auto malformed = ResolveKernelIncludes("b.cl", "#include \"unterminated\n");
  EXPECT_EQ(malformed.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(malformed.status().message().find("b.cl:1"), std::string::npos);
  // System includes are left to the device compiler.
  auto system = ResolveKernelIncludes("c.cl", "#include <stdint.h>\n");
  ASSERT_TRUE(system.ok());
  EXPECT_NE(system->find("#include <stdint.h>"), std::string::npos);
}

TEST(ProgramCacheTest, EveryEmbeddedKernelFileBuilds) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  ProgramCache& cache = *SharedClTestEnv().programs;
  int built = 0;
  for (const EmbeddedKernel& kernel : EmbeddedKernels()) {
    if (!EndsWith(kernel.name, ".cl")) continue;  // Headers are only included.
    auto program = cache.Get(kernel.name, kTestBuildOptions);
    EXPECT_TRUE(program.ok()) << program.status().ToString();
    ++built;
  }
  EXPECT_GE(built, 2);  // At least octree_sampling.cl and sample_points.cl.
}

TEST(ProgramCacheTest, ProgramsAreBuiltOnceAndShared) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  ProgramCache& cache = *SharedClTestEnv().programs;
  auto first = cache.Get("sample_points.cl", kTestBuildOptions);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  const size_t entries = cache.size();
  std::vector<cl_program> seen(4, nullptr);
  std::vector<std::thread> threads;
  for (size_t t = 0; t < seen.size(); ++t) {
    threads.emplace_back([&, t] {
      auto program = cache.Get("sample_points.cl", kTestBuildOptions);
      if (program.ok()) seen[t] = *program;
    });
  }
  for (std::thread& t : threads) t.join();
  for (cl_program p : seen) EXPECT_EQ(p, *first);
  EXPECT_EQ(cache.size(), entries);
  // Each CreateKernel gives a separate kernel object of the one program.
  auto a = cache.CreateKernel("sample_points.cl", "SamplePoints", kTestBuildOptions);
  auto b = cache.CreateKernel("sample_points.cl", "SamplePoints", kTestBuildOptions);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_TRUE(b.ok());
  EXPECT_NE(a->get(), b->get());
  EXPECT_EQ(cache.size(), entries);
}

TEST(ProgramCacheTest, UnknownFilesAndKernelsAreReported) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  ProgramCache& cache = *SharedClTestEnv().programs;
  auto missing = cache.Get("no_such_kernel.cl");
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("no_such_kernel.cl"), std::string::npos);
  auto kernel = cache.CreateKernel("sample_points.cl", "NoSuchKernel", kTestBuildOptions);
  ASSERT_FALSE(kernel.ok());
  EXPECT_NE(kernel.status().message().find("clCreateKernel(NoSuchKernel) failed: "
                                           "CL_INVALID_KERNEL_NAME"),
            std::string::npos)
      << kernel.status().message();
}

TEST(ProgramCacheTest, BrokenSourceFailsWithTheBuildLog) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ComputeContext& cc = *SharedClTestEnv().context;
  const char* broken =
      "#include \"node_format.h\"\n"
      "__kernel void Broken(__global uint* out) {\n"
      "  out[0] = OctoNodeChildGroup(out[1]) + undeclared_identifier_xyz;\n"
      "}\n";
  auto program = BuildProgram(cc, "broken.cl", broken, kTestBuildOptions);
  ASSERT_FALSE(program.ok());
  const std::string message = program.status().message();
  EXPECT_EQ(program.status().code(), StatusCode::kUnsupported);
  EXPECT_NE(message.find("broken.cl"), std::string::npos) << message;
  EXPECT_NE(message.find("clBuildProgram("), std::string::npos) << message;
  EXPECT_NE(message.find("CL_BUILD_PROGRAM_FAILURE"), std::string::npos) << message;
  EXPECT_NE(message.find("build log:\n"), std::string::npos) << message;
  // The compiler's own diagnostic, pointing at the identifier.
  EXPECT_NE(message.find("undeclared_identifier_xyz"), std::string::npos) << message;
  // The same source without the error builds: the failure was the identifier, not the include.
  std::string fixed = broken;
  const std::string error_term = " + undeclared_identifier_xyz";
  fixed.replace(fixed.find(error_term), error_term.size(), "");
  auto good = BuildProgram(cc, "fixed.cl", fixed, kTestBuildOptions);
  EXPECT_TRUE(good.ok()) << good.status().ToString();
}

}  // namespace
}  // namespace octoscope::render
