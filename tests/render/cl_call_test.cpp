#include "render/cl_call.h"

#include <gtest/gtest.h>

#include <string>

#include "render/cl_handles.h"

namespace octoscope::render {
namespace {

// Stand-ins for OpenCL entry points, so the checked-call machinery is tested without a device.
cl_int FakeBuild(int /*program*/, const char* /*options*/) { return CL_BUILD_PROGRAM_FAILURE; }
cl_int FakeOk(int /*anything*/) { return CL_SUCCESS; }
cl_int FakeOutOfMemory() { return CL_MEM_OBJECT_ALLOCATION_FAILURE; }

TEST(ClCallTest, ErrorNamesOfKnownAndUnknownCodes) {
  EXPECT_EQ(ClErrorName(CL_SUCCESS), "CL_SUCCESS");
  EXPECT_EQ(ClErrorName(CL_BUILD_PROGRAM_FAILURE), "CL_BUILD_PROGRAM_FAILURE");
  EXPECT_EQ(ClErrorName(CL_INVALID_KERNEL_NAME), "CL_INVALID_KERNEL_NAME");
  EXPECT_EQ(ClErrorName(CL_INVALID_DEVICE_PARTITION_COUNT), "CL_INVALID_DEVICE_PARTITION_COUNT");
  EXPECT_EQ(ClErrorName(-1001), "CL_PLATFORM_NOT_FOUND_KHR");
  EXPECT_EQ(ClErrorName(-12345), "CL_UNKNOWN_ERROR");
  EXPECT_EQ(ClErrorName(7), "CL_UNKNOWN_ERROR");
}

TEST(ClCallTest, FailedCallKeepsItsTextAndTheErrorName) {
  const Status status = OCTO_CL(FakeBuild(42, "-cl-std=CL1.2"));
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.code(), StatusCode::kUnsupported);
  EXPECT_EQ(status.message(),
            "FakeBuild(42, \"-cl-std=CL1.2\") failed: CL_BUILD_PROGRAM_FAILURE (-11)");
}

TEST(ClCallTest, SuccessIsOk) {
  EXPECT_TRUE(OCTO_CL(FakeOk(1)).ok());
  EXPECT_TRUE(ClCheck(CL_SUCCESS, "anything").ok());
}

TEST(ClCallTest, WhitespaceOfMultiLineCallsIsCollapsed) {
  // clang-format off
  const Status status = OCTO_CL(FakeBuild(1,
                                          "x"));
  // clang-format on
  EXPECT_EQ(status.message(), "FakeBuild(1, \"x\") failed: CL_BUILD_PROGRAM_FAILURE (-11)");
  EXPECT_EQ(ClCheck(CL_INVALID_VALUE, "  clFoo(a,\n\t  b)  ").message(),
            "clFoo(a, b) failed: CL_INVALID_VALUE (-30)");
}

TEST(ClCallTest, StatusCodesFollowTheKindOfError) {
  EXPECT_EQ(OCTO_CL(FakeOutOfMemory()).code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(ClCheck(CL_OUT_OF_RESOURCES, "f()").code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(ClCheck(CL_OUT_OF_HOST_MEMORY, "f()").code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(ClCheck(CL_DEVICE_NOT_FOUND, "f()").code(), StatusCode::kNotFound);
  EXPECT_EQ(ClCheck(-1001, "f()").code(), StatusCode::kNotFound);
  EXPECT_EQ(ClCheck(CL_COMPILER_NOT_AVAILABLE, "f()").code(), StatusCode::kUnsupported);
  EXPECT_EQ(ClCheck(CL_INVALID_MEM_OBJECT, "f()").code(), StatusCode::kInternal);
  EXPECT_EQ(ClCheck(-9999, "f()").message(), "f() failed: CL_UNKNOWN_ERROR (-9999)");
}

Status ReturnsEarly(bool* reached_end) {
  OCTO_CL_RETURN_IF_ERROR(FakeOk(0));
  OCTO_CL_RETURN_IF_ERROR(FakeOutOfMemory());
  *reached_end = true;
  return Status::Ok();
}

TEST(ClCallTest, ReturnIfErrorStopsAtTheFirstFailure) {
  bool reached_end = false;
  const Status status = ReturnsEarly(&reached_end);
  EXPECT_FALSE(reached_end);
  EXPECT_EQ(status.message(), "FakeOutOfMemory() failed: CL_MEM_OBJECT_ALLOCATION_FAILURE (-4)");
}

TEST(ClCallTest, LogVariantOnlyWritesToStderr) {
  ::testing::internal::CaptureStderr();
  OCTO_CL_LOG(FakeOk(3));
  OCTO_CL_LOG(FakeOutOfMemory());
  const std::string logged = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(logged,
            "octoscope: FakeOutOfMemory() failed: CL_MEM_OBJECT_ALLOCATION_FAILURE (-4) "
            "(ignored)\n");
}

TEST(ClHandlesTest, EmptyHandlesAreFalsyAndReleaseNothing) {
  ClMem mem;
  EXPECT_FALSE(mem);
  EXPECT_EQ(mem.get(), nullptr);
  ClMem moved(std::move(mem));
  EXPECT_FALSE(moved);
  moved.reset();  // Releasing nothing is a no-op (no clRelease call on nullptr).
  EXPECT_EQ(moved.release(), nullptr);
  static_assert(!std::is_copy_constructible_v<ClKernel>);
  static_assert(!std::is_copy_assignable_v<ClProgram>);
  static_assert(std::is_nothrow_move_constructible_v<ClContext>);
  static_assert(std::is_nothrow_move_assignable_v<ClQueue>);
  static_assert(std::is_nothrow_destructible_v<ClEvent>);
}

}  // namespace
}  // namespace octoscope::render
