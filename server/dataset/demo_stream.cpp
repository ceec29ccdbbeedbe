#include "dataset/demo_stream.h"

#include <bit>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <vector>

#include "io/synthetic_embryo.h"

namespace octoscope::dataset {

Result<std::unique_ptr<DemoStream>> DemoStream::Start(DatasetRegistry* registry,
                                                      const DemoOptions& options) {
  if (!(options.planes_per_second > 0)) {
    return InvalidArgumentError("demo: planes per second must be > 0");
  }
  io::SyntheticEmbryoOptions embryo;
  embryo.size = options.size;
  embryo.channels = options.channels;
  embryo.seed = options.seed;
  embryo.spacing_um = {0.5, 0.5, 1.0};
  OCTO_ASSIGN_OR_RETURN(std::unique_ptr<io::SyntheticEmbryo> specimen,
                        io::SyntheticEmbryo::Create(embryo));
  const volume::VolumeInfo& info = specimen->info();
  protocol::StreamRequest request;
  request.name = "demo specimen (synthetic embryo, streamed)";
  request.size = info.size;
  request.channels = info.channel_count();
  request.dtype = info.dtype;
  for (int a = 0; a < 3; ++a) request.spacing_um[a] = info.spacing_um[a].value_or(1.0);
  for (const auto& channel : info.channels) request.channel_names.push_back(channel.name);
  std::unique_ptr<DemoStream> demo(new DemoStream);
  demo->options_ = options;
  demo->id_ = std::string(DemoDatasetId());
  OCTO_ASSIGN_OR_RETURN(demo->dataset_, registry->CreateStreamWithId(request, demo->id_, ""));
  demo->specimen_ = std::move(specimen);
  demo->thread_ = std::jthread([d = demo.get()](std::stop_token stop) { d->Run(stop); });
  return demo;
}

DemoStream::~DemoStream() {
  thread_.request_stop();
  if (thread_.joinable()) thread_.join();
}

void DemoStream::Run(std::stop_token stop) {
  const volume::VolumeInfo& info = specimen_->info();
  const size_t plane_bytes = info.PlaneVoxels() * volume::BytesPerSample(info.dtype);
  std::vector<std::byte> plane(plane_bytes);
  std::mutex mu;
  std::condition_variable_any cv;
  const auto period = std::chrono::duration<double>(1.0 / options_.planes_per_second);
  auto due = std::chrono::steady_clock::now();
  for (int64_t z = 0; z < info.size[2] && !stop.stop_requested(); ++z) {
    for (int c = 0; c < info.channel_count(); ++c) {
      // The generator writes native-endian samples; streams take little-endian ones.
      static_assert(std::endian::native == std::endian::little, "demo: swap samples here");
      if (!specimen_->ReadSlab(c, z, 1, plane).ok()) return;
      if (!dataset_->AddSlab(c, z, 1, plane, /*wait_visible=*/false).ok()) return;
    }
    due += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    std::unique_lock<std::mutex> lock(mu);
    cv.wait_until(lock, stop, due, [] { return false; });
  }
  if (!stop.stop_requested()) (void)dataset_->Finish();
}

}  // namespace octoscope::dataset
