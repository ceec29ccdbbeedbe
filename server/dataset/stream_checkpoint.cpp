#include "dataset/stream_checkpoint.h"

#include <cstring>
#include <string_view>

namespace octoscope::dataset {
namespace {

constexpr char kPlanesMagic[8] = {'O', 'C', 'T', 'O', 'P', 'L', 'N', 'S'};
constexpr uint32_t kPlanesVersion = 1;
constexpr size_t kPlanesHeaderBytes = 24;
constexpr char kPlanesName[] = "planes";
constexpr char kHistogramName[] = "histogram";

void PutLe(std::string& out, uint64_t v, int bytes) {
  for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>(v >> (8 * i)));
}

uint64_t GetLe(std::string_view in, size_t at, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i)
    v |= static_cast<uint64_t>(static_cast<uint8_t>(in[at + i])) << (8 * i);
  return v;
}

}  // namespace

octree::CheckpointAttachments StreamAttachments(const StreamProgress& progress, int channels,
                                                int64_t planes,
                                                const octree::SourceIdentity& source) {
  std::string map(kPlanesMagic, sizeof kPlanesMagic);
  PutLe(map, kPlanesVersion, 4);
  PutLe(map, static_cast<uint32_t>(channels), 4);
  PutLe(map, static_cast<uint64_t>(planes), 8);
  map.append(reinterpret_cast<const char*>(progress.received.data()), progress.received.size());
  octree::CheckpointAttachments attachments;
  attachments.emplace(kPlanesName, std::move(map));
  attachments.emplace(kHistogramName, SerializeHistogram(progress.histogram, source));
  return attachments;
}

Result<StreamProgress> ParseStreamAttachments(const octree::CheckpointAttachments& attachments,
                                              int channels, int64_t planes,
                                              const octree::SourceIdentity& source,
                                              const std::vector<volume::ValueMap>& maps) {
  auto planes_it = attachments.find(kPlanesName);
  auto histogram_it = attachments.find(kHistogramName);
  if (planes_it == attachments.end() || histogram_it == attachments.end()) {
    return CorruptError("the stream's checkpoint lacks its received planes or its histogram");
  }
  const std::string_view map = planes_it->second;
  const uint64_t count = static_cast<uint64_t>(channels) * static_cast<uint64_t>(planes);
  auto bad = [](const std::string& what) {
    return CorruptError("the checkpoint's received planes: " + what);
  };
  if (map.size() < kPlanesHeaderBytes ||
      std::memcmp(map.data(), kPlanesMagic, sizeof kPlanesMagic) != 0) {
    return bad("not a plane map");
  }
  if (GetLe(map, 8, 4) != kPlanesVersion) return bad("version " + std::to_string(GetLe(map, 8, 4)));
  if (GetLe(map, 12, 4) != static_cast<uint64_t>(channels) ||
      GetLe(map, 16, 8) != static_cast<uint64_t>(planes) ||
      map.size() != kPlanesHeaderBytes + count) {
    return bad("made for another shape than " + std::to_string(channels) + " x " +
               std::to_string(planes) + " planes");
  }
  StreamProgress progress;
  progress.received.assign(map.begin() + kPlanesHeaderBytes, map.end());
  for (uint8_t flag : progress.received) {
    if (flag > 1) return bad("a flag is neither 0 nor 1");
  }
  OCTO_ASSIGN_OR_RETURN(progress.histogram, ParseHistogram(histogram_it->second, source, maps));
  return progress;
}

std::string DescribeMissingPlanes(const std::vector<uint8_t>& received, int channels,
                                  int64_t planes, size_t max_ranges) {
  std::string out;
  size_t ranges = 0, more = 0;
  for (int c = 0; c < channels; ++c) {
    std::string list;
    for (int64_t z = 0; z < planes;) {
      const auto at = [&](int64_t k) { return received[static_cast<size_t>(c * planes + k)]; };
      if (at(z)) {
        ++z;
        continue;
      }
      int64_t end = z;
      while (end + 1 < planes && !at(end + 1)) ++end;
      if (ranges < max_ranges) {
        if (!list.empty()) list.append(", ");
        list.append(std::to_string(z));
        if (end > z) list.append("-").append(std::to_string(end));
        ++ranges;
      } else {
        ++more;
      }
      z = end + 1;
    }
    if (list.empty()) continue;
    if (!out.empty()) out.append("; ");
    out.append("channel ").append(std::to_string(c)).append(": z ").append(list);
  }
  if (more > 0) out.append(" … and ").append(std::to_string(more)).append(" more ranges");
  return out.empty() ? "none" : out;
}

}  // namespace octoscope::dataset
