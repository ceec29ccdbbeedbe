#include "render/device.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <numeric>
#include <utility>
#include <vector>

#include "cl_test_env.h"
#include "render/cl_handles.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::SharedClTestEnv;

DeviceInfo Fake(int flat, int platform, int device, DeviceType type, uint64_t memory,
                const char* platform_name, const char* name) {
  DeviceInfo d;
  d.flat_index = flat;
  d.platform_index = platform;
  d.device_index = device;
  d.type = type;
  d.global_memory_bytes = memory;
  d.max_alloc_bytes = memory / 4;
  d.platform_name = platform_name;
  d.name = name;
  d.available = true;
  d.compiler_available = true;
  return d;
}

// Two platforms: a CPU runtime first, then a vendor GPU platform with a small and a big GPU.
std::vector<DeviceInfo> FakeDevices() {
  return {
      Fake(0, 0, 0, DeviceType::kCpu, 64ull << 30, "Portable Computing Language", "pthread-x86"),
      Fake(1, 1, 0, DeviceType::kGpu, 8ull << 30, "NVIDIA CUDA", "Small GPU"),
      Fake(2, 1, 1, DeviceType::kGpu, 80ull << 30, "NVIDIA CUDA", "Big GPU"),
      Fake(3, 1, 2, DeviceType::kAccelerator, 128ull << 30, "NVIDIA CUDA", "Accel")};
}

TEST(ChooseDeviceTest, AutomaticChoicePrefersGpusThenMemory) {
  const auto devices = FakeDevices();
  for (const char* pref : {"", "auto", "AUTO", "gpu", "GPU"}) {
    auto chosen = ChooseDevice(devices, pref);
    ASSERT_TRUE(chosen.ok()) << pref << ": " << chosen.status().ToString();
    EXPECT_EQ(chosen->name, "Big GPU") << pref;
  }
  auto cpu = ChooseDevice(devices, "cpu");
  ASSERT_TRUE(cpu.ok());
  EXPECT_EQ(cpu->name, "pthread-x86");
}

TEST(ChooseDeviceTest, FallsBackToCpuAndSkipsUnusableDevices) {
  auto devices = FakeDevices();
  devices[1].available = false;
  devices[2].compiler_available = false;
  auto chosen = ChooseDevice(devices, "");
  ASSERT_TRUE(chosen.ok());
  EXPECT_EQ(chosen->name, "pthread-x86");
  auto gpu = ChooseDevice(devices, "gpu");
  EXPECT_EQ(gpu.status().code(), StatusCode::kNotFound);
  EXPECT_NE(gpu.status().message().find("no usable GPU device"), std::string::npos)
      << gpu.status().message();
  // Without a CPU either, only the accelerator is left: automatic choice still finds it.
  devices.erase(devices.begin());
  chosen = ChooseDevice(devices, "auto");
  ASSERT_TRUE(chosen.ok());
  EXPECT_EQ(chosen->name, "Accel");
}

TEST(ChooseDeviceTest, EqualDevicesKeepEnumerationOrder) {
  std::vector<DeviceInfo> devices = {Fake(0, 0, 0, DeviceType::kGpu, 16ull << 30, "P", "first"),
                                     Fake(1, 0, 1, DeviceType::kGpu, 16ull << 30, "P", "second")};
  EXPECT_EQ(ChooseDevice(devices, "")->name, "first");
}

TEST(ChooseDeviceTest, OverridesByIndexPlatformDeviceAndName) {
  const auto devices = FakeDevices();
  EXPECT_EQ(ChooseDevice(devices, "0")->name, "pthread-x86");
  EXPECT_EQ(ChooseDevice(devices, "1")->name, "Small GPU");
  EXPECT_EQ(ChooseDevice(devices, "1:2")->name, "Accel");
  EXPECT_EQ(ChooseDevice(devices, "0:0")->name, "pthread-x86");
  EXPECT_EQ(ChooseDevice(devices, "small")->name, "Small GPU");
  EXPECT_EQ(ChooseDevice(devices, "portable computing")->name, "pthread-x86");
  // Platform names match too: the first device of that platform.
  EXPECT_EQ(ChooseDevice(devices, "nvidia")->name, "Small GPU");
  // An explicit override may pick a device the automatic choice would skip.
  auto unavailable = FakeDevices();
  unavailable[0].available = false;
  EXPECT_EQ(ChooseDevice(unavailable, "0")->name, "pthread-x86");
}

TEST(ChooseDeviceTest, UnmatchedOverridesAreNotFoundAndListTheDevices) {
  const auto devices = FakeDevices();
  for (const char* pref : {"4", "2:0", "0:1", "radeon"}) {
    auto chosen = ChooseDevice(devices, pref);
    ASSERT_FALSE(chosen.ok()) << pref;
    EXPECT_EQ(chosen.status().code(), StatusCode::kNotFound) << pref;
    EXPECT_NE(chosen.status().message().find(pref), std::string::npos) << chosen.status().message();
    EXPECT_NE(chosen.status().message().find("[2] 1:1 GPU Big GPU (NVIDIA CUDA)"),
              std::string::npos)
        << chosen.status().message();
  }
  auto none = ChooseDevice(std::vector<DeviceInfo>{}, "");
  EXPECT_EQ(none.status().code(), StatusCode::kNotFound);
  EXPECT_NE(none.status().message().find("no OpenCL device is installed"), std::string::npos);
}

// Eight-sample steps where the device prefers float vectors of 8 or more, else four.
TEST(DeviceTest, RunLanesFollowThePreferredFloatVectorWidth) {
  DeviceInfo d = FakeDevices()[0];
  for (const auto& [width, lanes] :
       std::vector<std::pair<uint32_t, int>>{{1, 4}, {2, 4}, {4, 4}, {8, 8}, {16, 8}}) {
    d.preferred_float_width = width;
    EXPECT_EQ(RunLanes(d), lanes) << width;
  }
}

TEST(DeviceTest, ListedDevicesHavePlausibleProperties) {
  auto devices = ListDevices();
  ASSERT_TRUE(devices.ok()) << devices.status().ToString();
  if (devices->empty()) GTEST_SKIP() << "no OpenCL device";
  for (size_t i = 0; i < devices->size(); ++i) {
    const DeviceInfo& d = (*devices)[i];
    SCOPED_TRACE(d.ToString());
    EXPECT_EQ(d.flat_index, static_cast<int>(i));
    EXPECT_NE(d.device, nullptr);
    EXPECT_NE(d.platform, nullptr);
    EXPECT_FALSE(d.name.empty());
    EXPECT_FALSE(d.platform_name.empty());
    EXPECT_EQ(d.version.rfind("OpenCL ", 0), 0u);
    EXPECT_GT(d.global_memory_bytes, 0u);
    EXPECT_GT(d.max_alloc_bytes, 0u);
    EXPECT_LE(d.max_alloc_bytes, d.global_memory_bytes);
    EXPECT_GT(d.compute_units, 0u);
    EXPECT_GT(d.max_work_group_size, 0u);
    EXPECT_GE(d.preferred_float_width, 1u);
    EXPECT_LE(d.preferred_float_width, 16u);
    // Overriding by index and by "platform:device" finds the same device.
    EXPECT_EQ(ChooseDevice(*devices, std::to_string(i))->device, d.device);
    EXPECT_EQ(ChooseDevice(*devices,
                           std::to_string(d.platform_index) + ":" + std::to_string(d.device_index))
                  ->device,
              d.device);
  }
}

TEST(DeviceTest, BufferRoundTripThroughTheDevice) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ComputeContext& cc = *SharedClTestEnv().context;
  std::vector<uint32_t> data(1000);
  std::iota(data.begin(), data.end(), 0xabc00000u);
  auto buffer = cc.CreateBuffer(CL_MEM_READ_WRITE, data.size() * 4, data.data());
  ASSERT_TRUE(buffer.ok()) << buffer.status().ToString();
  const uint32_t patch[3] = {1, 2, 3};
  ASSERT_TRUE(cc.WriteBuffer(*buffer, 40, sizeof(patch), patch).ok());
  std::vector<uint32_t> back(data.size());
  ASSERT_TRUE(cc.ReadBuffer(*buffer, 0, back.size() * 4, back.data()).ok());
  data[10] = 1;
  data[11] = 2;
  data[12] = 3;
  EXPECT_EQ(back, data);
  // Reading past the end is the driver's CL_INVALID_VALUE, reported with the call's text.
  const Status past = cc.ReadBuffer(*buffer, 4000, 4, back.data());
  EXPECT_EQ(past.code(), StatusCode::kInternal);
  EXPECT_NE(past.message().find("clEnqueueReadBuffer("), std::string::npos) << past.message();
  EXPECT_NE(past.message().find("CL_INVALID_VALUE"), std::string::npos) << past.message();
}

TEST(DeviceTest, OversizedAndEmptyBuffersAreRefusedBeforeTheDriver) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ComputeContext& cc = *SharedClTestEnv().context;
  auto huge =
      cc.CreateBuffer(CL_MEM_READ_ONLY, static_cast<size_t>(cc.device().max_alloc_bytes) + 1);
  EXPECT_EQ(huge.status().code(), StatusCode::kResourceExhausted);
  EXPECT_EQ(cc.CreateBuffer(CL_MEM_READ_ONLY, 0).status().code(), StatusCode::kInvalidArgument);
}

TEST(DeviceTest, HandlesOwnExactlyOneReference) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const ComputeContext& cc = *SharedClTestEnv().context;
  auto buffer = cc.CreateBuffer(CL_MEM_READ_WRITE, 64);
  ASSERT_TRUE(buffer.ok());
  auto refs = [&](cl_mem mem) {
    cl_uint count = 0;
    EXPECT_EQ(clGetMemObjectInfo(mem, CL_MEM_REFERENCE_COUNT, sizeof(count), &count, nullptr),
              CL_SUCCESS);
    return count;
  };
  const cl_mem raw = buffer->get();
  EXPECT_EQ(refs(raw), 1u);
  {
    ClMem shared = ClMem::Retain(raw);
    EXPECT_EQ(refs(raw), 2u);
    ClMem moved(std::move(shared));
    EXPECT_EQ(refs(raw), 2u);  // A move transfers the reference.
    EXPECT_FALSE(shared);      // NOLINT(bugprone-use-after-move): moved-from is empty.
  }
  EXPECT_EQ(refs(raw), 1u);
  ClMem other;
  other = std::move(*buffer);
  EXPECT_EQ(other.get(), raw);
  EXPECT_EQ(refs(raw), 1u);
}

TEST(DeviceTest, ContextNeedsADevice) {
  EXPECT_EQ(ComputeContext::Create(DeviceInfo{}).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace octoscope::render
