// SlabIngest: the front door of an octree for slabs of any thickness arriving in any order — a
// file being read, or a live acquisition sending one plane at a time. It stages planes per BRICK
// LAYER (the brick depth's worth of z planes) and inserts a layer into the octree when all its
// planes of all channels have arrived: one multi-channel insert, so every leaf brick of the layer
// is written once and complete (exact statistics, prunable, never rescanned), and the parents
// are updated once per layer instead of once per plane. Flush() inserts what is staged now,
// complete layers or not, so a viewer sees planes soon after they arrive (the owner decides how
// often: a latency budget for live viewing).
//
// Memory: staged planes live in RAM up to `staging_bytes` (buffers of finished layers are kept for
// the next ones within that budget); a layer that does not fit is staged in
// an anonymous scratch file instead (IngestOptions::scratch_dir) and inserted brick row by brick
// row (a row: the layer's depth × one brick height × the full width), so that the RAM needed is
// one row, not one layer. Without a scratch directory such a layer is refused with
// kResourceExhausted.
//
// Semantics: the final octree equals a one-shot build of the same voxels, whatever the slab
// shapes and arrival order (Octree's order independence). A plane that arrives again replaces
// the earlier one (latest wins); after its layer was inserted, it is inserted again at once.
//
// Thread safety: Add and Flush may be called from several threads at once. A thread whose Add
// completes a layer inserts it before returning (back-pressure: producers slow down to the speed
// of construction); other threads meanwhile stage other planes. Inserts are serialised by the
// octree.
#ifndef OCTOSCOPE_OCTREE_SLAB_INGEST_H_
#define OCTOSCOPE_OCTREE_SLAB_INGEST_H_

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <span>
#include <unordered_map>
#include <vector>

#include "octree/octree.h"
#include "util/result.h"
#include "util/scratch_file.h"
#include "util/status.h"
#include "util/worker_pool.h"

namespace octoscope::octree {

struct IngestOptions {
  // RAM for staged planes (stored type) over all layers.
  uint64_t staging_bytes = uint64_t{512} << 20;
  // Where layers that do not fit in RAM are staged; empty = refuse them.
  std::filesystem::path scratch_dir;
  // Threads for the octree's brick writes (not owned); null = the inserting thread alone.
  WorkerPool* workers = nullptr;
  // Planes the octree holds already (a build resumed from a checkpoint): [channel * planes + z],
  // planes = the volume's depth, non-zero = inserted. They count as received and inserted, and a
  // brick layer is inserted once its OTHER planes have arrived; one of them sent again replaces
  // it. Empty = none.
  std::vector<uint8_t> inserted;
};

struct IngestProgress {
  uint64_t planes_total = 0;     // z planes × channels of the volume.
  uint64_t planes_received = 0;  // Distinct (plane, channel) pairs received so far.
  uint64_t planes_inserted = 0;  // Of those, inserted into the octree (visible).
  uint64_t layers_inserted = 0;  // Complete brick layers inserted.
  uint64_t staged_bytes = 0;     // RAM staging in use now.
  uint64_t scratch_layers = 0;   // Layers staged in scratch files so far.
};

class SlabIngest {
 public:
  // REQUIRES: `tree` outlives the ingest.
  static Result<std::unique_ptr<SlabIngest>> Create(Octree* tree, const IngestOptions& options);
  ~SlabIngest();
  SlabIngest(const SlabIngest&) = delete;
  SlabIngest& operator=(const SlabIngest&) = delete;

  // Accepts planes [z0, z0 + nz) of `channel`: data holds nz whole planes in the stored type
  // (bytes_per_sample each, native byte order), x fastest. kInvalidArgument / kOutOfRange for a
  // bad channel, range or size. Inserts every layer this completes; insert and scratch-file
  // errors are returned (the planes stay staged; adding or flushing again retries them).
  Status Add(int channel, int64_t z0, int64_t nz, std::span<const std::byte> data);

  // Inserts every staged plane not inserted yet (complete layers or not).
  Status Flush();

  IngestProgress progress() const;
  // True when every plane of every channel was received and inserted.
  bool complete() const;
  // Planes received but not yet visible (waiting for their layer or a Flush).
  uint64_t pending_planes() const;

 private:
  // Per (channel, plane) state of a layer being staged.
  enum class PlaneState : uint8_t { kEmpty, kWriting, kReceived, kInserting, kInserted };
  struct Layer {
    int64_t z0 = 0;
    int64_t nz = 0;
    std::unique_ptr<std::byte[]> ram;  // [channel][plane][y][x] when staged in RAM.
    uint64_t ram_bytes = 0;
    std::unique_ptr<ScratchFile> file;  // Same layout, when staged on disk.
    std::vector<PlaneState> state;      // [channel * nz + plane].
    // [channel * nz + plane]: bit 0 = counted as received, bit 1 = counted as inserted.
    std::vector<uint8_t> counted;
    int64_t waiting = 0;  // Planes in kEmpty or kWriting.
    bool busy = false;    // A thread is inserting planes of this layer.
  };

  SlabIngest(Octree* tree, const IngestOptions& options);
  // Whether IngestOptions::inserted lists plane z of `channel`.
  bool WasInserted(int channel, int64_t z) const;
  // The layer holding z, created on first use. REQUIRES: lock holds mu_.
  Result<Layer*> LayerLocked(int64_t index, std::unique_lock<std::mutex>& lock);
  // Copies planes [first, first + count) of the layer (layer-relative) of `channel` in.
  Status Stage(Layer& layer, int channel, int64_t first, int64_t count, const std::byte* data);
  // Inserts the layer's planes now in kInserting state, grouped into runs of planes sharing a
  // channel set. Runs without mu_ held. REQUIRES: the caller set layer.busy.
  Status InsertMarked(Layer& layer);
  // Marks the kReceived planes kInserting, inserts them, marks them kInserted (or back to
  // kReceived on error), and removes the layer when it is done. REQUIRES: lock holds mu_ and
  // layer.busy was false; returns with lock held.
  Status InsertPending(int64_t index, std::unique_lock<std::mutex>& lock);
  // Inserts planes of a layer that is already done (a plane that arrived again).
  Status InsertDirect(int channel, int64_t z0, int64_t nz, std::span<const std::byte> data);

  Octree* const tree_;
  const IngestOptions options_;
  const int channels_;
  const int64_t depth_;         // Planes per layer (brick depth).
  const uint64_t plane_bytes_;  // One plane of one channel, stored type.
  const int64_t planes_;        // Volume depth.

  mutable std::mutex mu_;
  std::condition_variable cv_;  // A plane left kWriting/kInserting, or a layer stopped being busy.
  std::unordered_map<int64_t, std::unique_ptr<Layer>> layers_;  // Guarded by mu_.
  std::vector<uint8_t> layer_done_;                             // Guarded by mu_.
  uint64_t staged_bytes_ = 0;                                   // Guarded by mu_.
  // Buffers of finished full-depth layers, reused for the next ones (a fresh buffer costs a page
  // fault per 4 KiB). Counted in staged_bytes_. Guarded by mu_.
  std::vector<std::unique_ptr<std::byte[]>> spare_;
  IngestProgress progress_;  // Guarded by mu_.
};

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_SLAB_INGEST_H_
