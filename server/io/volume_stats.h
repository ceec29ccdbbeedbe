// VolumeStats: per-channel minimum, maximum and mean of every voxel of a VolumeSource, in the
// file's own units. When the file stores the planes as they are read (VolumeSource::
// FindStoredPlane), a few threads each read their share of the (z, c) planes piece by piece into a
// small buffer that stays in the CPU cache while it is summed (as `cat` copies through one small
// buffer), into their own per-channel sums, merged at the end. Otherwise (compressed or chunked
// files: OME-Zarr, Imaris, compressed TIFF) the source is streamed slab by slab (memory: two
// slabs; whole chunk depths for sources stored in chunks along z), one thread reading while the
// calling thread sums. Files are read, never mapped: a file truncated meanwhile gives an error
// naming it, not SIGBUS.
// Integer means are exact (integer sums, one division); float means use compensated (Neumaier)
// summation, accurate to a few units in the last place of a double. NaNs are counted, not summed.
//
// Thread safety: ComputeVolumeStats reads the source from helper threads as well as the calling
// thread; the source must be thread-safe (all VolumeSources are). The progress callback is only
// ever called from the calling thread.
#ifndef OCTOSCOPE_IO_VOLUME_STATS_H_
#define OCTOSCOPE_IO_VOLUME_STATS_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "io/volume_source.h"
#include "util/result.h"

namespace octoscope::io {

struct ChannelStats {
  double min = 0;
  double max = 0;
  double mean = 0;
  uint64_t count = 0;      // Voxels that entered min/max/mean.
  uint64_t nan_count = 0;  // Float NaNs (excluded from the above).
};

struct VolumeStats {
  std::vector<ChannelStats> channels;
};

struct StatsOptions {
  // Target bytes per slab read (rounded to whole planes, at least one plane).
  uint64_t slab_bytes = uint64_t{4} << 20;
  // Sources stored in chunks along z (VolumeSource::PreferredSlabPlanes() > 1) are read in slabs
  // of whole chunk depths when one such slab is at most this large (else the source's chunk
  // cache serves the thinner slabs).
  uint64_t max_aligned_slab_bytes = uint64_t{256} << 20;
  // Called after each slab with (planes done, planes total) over all channels.
  std::function<void(uint64_t, uint64_t)> progress;
  // Threads of the direct path, the calling thread included; 0: the hardware's concurrency, at
  // most 4 (a couple of cores already outrun the memory bus).
  int threads = 0;
  // Bytes per read of the direct path (rounded down to whole samples): small enough to stay in
  // the L2 cache while summed.
  uint64_t piece_bytes = uint64_t{128} << 10;
  // Read stored planes directly when the source locates them; false forces the streaming path.
  bool direct = true;
};

Result<VolumeStats> ComputeVolumeStats(VolumeSource& source, const StatsOptions& options);

}  // namespace octoscope::io

#endif  // OCTOSCOPE_IO_VOLUME_STATS_H_
