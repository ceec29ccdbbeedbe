// DemoStream: `octoscope serve --demo` — the built-in synthetic specimen (io::SyntheticEmbryo: a
// fluorescent embryo with nuclei, membranes and spots; deterministic for a size and seed) streamed
// into a streaming dataset plane by plane, paced like an acquisition, then finished. A new user
// sees streaming, interaction and refinement at once. Each run streams afresh (the demo's cache
// folder is replaced; the demo has no stream record). An idle release never stops or finishes
// it: it only suspends the stream while it is quiet, and the next plane resumes it.
//
// Thread safety: Start and the destructor from one thread; the stream runs on its own thread.
#ifndef OCTOSCOPE_DATASET_DEMO_STREAM_H_
#define OCTOSCOPE_DATASET_DEMO_STREAM_H_

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>

#include "dataset/dataset_registry.h"
#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::dataset {

struct DemoOptions {
  std::array<int64_t, 3> size{256, 256, 160};
  int channels = 3;
  uint64_t seed = 42;
  double planes_per_second = 5;  // z planes (all channels) per second; > 0.
};

class DemoStream {
 public:
  // Creates the demo dataset in `registry` (which must outlive the stream) and starts streaming.
  static Result<std::unique_ptr<DemoStream>> Start(DatasetRegistry* registry,
                                                   const DemoOptions& options);
  // Stops streaming (planes sent so far stay) and joins.
  ~DemoStream();
  DemoStream(const DemoStream&) = delete;
  DemoStream& operator=(const DemoStream&) = delete;

  const std::string& dataset_id() const { return id_; }

 private:
  DemoStream() = default;
  void Run(std::stop_token stop);

  DemoOptions options_;
  std::string id_;
  std::shared_ptr<Dataset> dataset_;
  std::unique_ptr<io::VolumeSource> specimen_;
  std::jthread thread_;  // Last: started when the rest exists.
};

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_DEMO_STREAM_H_
