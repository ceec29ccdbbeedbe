// StreamCheckpoint: a stream's own part of its cache checkpoint (octree::OctreeCache::Checkpoint
// attachments, docs/octree_format.md "Checkpoints"): "planes" — which planes of which channel were
// received — and "histogram" — the counts of every voxel received (histogram.bin's format). With
// the checkpoint's octree they are the stream exactly as it stood: planes_received, missing
// planes, replacements and the histogram resume from them.
//
// "planes", integers little-endian: the 8 bytes "OCTOPLNS", u32 version (1), u32 channels, u64
// planes per channel (the volume's depth), then one byte per (channel, z), channel-major: 1 =
// received, 0 = not. Parsed strictly (size, magic, version, shape, byte values).
//
// Thread safety: pure functions.
#ifndef OCTOSCOPE_DATASET_STREAM_CHECKPOINT_H_
#define OCTOSCOPE_DATASET_STREAM_CHECKPOINT_H_

#include <cstdint>
#include <string>
#include <vector>

#include "dataset/histogram.h"
#include "octree/octree_cache.h"
#include "util/result.h"
#include "volume/value_map.h"

namespace octoscope::dataset {

// The received planes and the histogram of a stream at one moment.
struct StreamProgress {
  std::vector<uint8_t> received;  // [channel * planes + z]: 1 = received.
  Histogram histogram;
};

// The checkpoint attachments of `progress` (a stream of `channels` x `planes` planes whose cache
// is identified by `source`). REQUIRES: progress.received.size() == channels * planes.
octree::CheckpointAttachments StreamAttachments(const StreamProgress& progress, int channels,
                                                int64_t planes,
                                                const octree::SourceIdentity& source);
// Reads them back for a stream of that shape whose channels are stored as `maps`. kCorrupt
// naming the attachment when one is missing or does not fit.
Result<StreamProgress> ParseStreamAttachments(const octree::CheckpointAttachments& attachments,
                                              int channels, int64_t planes,
                                              const octree::SourceIdentity& source,
                                              const std::vector<volume::ValueMap>& maps);

// The planes not received, per channel, as ranges: "channel 0: z 3-9, 12; channel 1: z 0-22"
// (channels with every plane received are left out; "none" when nothing is missing). At most
// `max_ranges` ranges are listed, then "…" and how many more.
std::string DescribeMissingPlanes(const std::vector<uint8_t>& received, int channels,
                                  int64_t planes, size_t max_ranges = 64);

}  // namespace octoscope::dataset

#endif  // OCTOSCOPE_DATASET_STREAM_CHECKPOINT_H_
