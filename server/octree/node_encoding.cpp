#include "octree/node_encoding.h"

#include <cmath>
#include <string>

namespace octoscope::octree {
namespace {

// Child groups of a complete tree with root level R (every node at levels 1..R has children,
// plus the root's pseudo-group): 1 + sum_{k=0}^{R-1} 8^k = 1 + (8^R - 1) / 7.
constexpr uint64_t CompleteTreeChildGroups(int root_level) {
  uint64_t groups = 1;
  for (int k = 0; k < root_level; ++k) groups += uint64_t{1} << (3 * k);
  return groups;
}

// The design point (docs/octree_format.md, "Device node buffer"): a full 65536^3 volume with
// 64^3 bricks has root level 10 (64 * 2^10 = 65536) and needs
// (65536/64)^3 * 8/7 / 8 ~= 153,391,690 child groups, below 2^29 = 536,870,912.
static_assert(CompleteTreeChildGroups(10) == 153'391'690);
static_assert(CompleteTreeChildGroups(10) <= kChildGroupCapacity);
// One level deeper (32^3 bricks for 65536^3) would not fit: 1,227,133,514 > 2^29.
static_assert(CompleteTreeChildGroups(11) > kChildGroupCapacity);
static_assert(NodeWords(1) == 4 && NodeWords(2) == 5 && NodeWords(3) == 7 && NodeWords(4) == 8);

}  // namespace

uint64_t MaxChildGroups(const BrickGeometry& geometry) {
  uint64_t groups = 1;  // The root's pseudo-group.
  for (int level = 1; level <= geometry.root_level(); ++level) {
    groups += geometry.NonVirtualNodes(level).VoxelCount();
  }
  return groups;
}

bool FitsDeviceEncoding(const BrickGeometry& geometry) {
  return MaxChildGroups(geometry) <= kChildGroupCapacity;
}

uint16_t QuantizeAverage(double average, int bytes_per_sample) {
  const double max = bytes_per_sample == 1 ? 255.0 : 65535.0;
  // NaN fails both comparisons below; map it to 0 explicitly so the result is defined.
  if (std::isnan(average) || average <= 0.0) return 0;
  if (average >= max) return static_cast<uint16_t>(max);
  return static_cast<uint16_t>(std::floor(average + 0.5));
}

Status EncodeNode(const DeviceNode& node, std::span<uint32_t> out) {
  if (node.averages.empty()) {
    return InvalidArgumentError("device node: no channel averages");
  }
  const int channels = static_cast<int>(node.averages.size());
  if (out.size() != static_cast<size_t>(NodeWords(channels))) {
    return InvalidArgumentError("device node: " + std::to_string(channels) + " channels need " +
                                std::to_string(NodeWords(channels)) + " words, got " +
                                std::to_string(out.size()));
  }
  if (node.child_group > kMaxChildGroup) {
    return OutOfRangeError("device node: child group " + std::to_string(node.child_group) +
                           " exceeds the 30-bit limit " + std::to_string(kMaxChildGroup));
  }
  if (node.in_buffer && !node.has_brick) {
    return InvalidArgumentError("device node: in_buffer set on a node without a brick");
  }
  const bool ranges = !node.range_min.empty() || !node.range_max.empty();
  if (ranges) {
    if (node.range_min.size() != node.averages.size() ||
        node.range_max.size() != node.averages.size()) {
      return InvalidArgumentError("device node: value ranges need one min and max per channel");
    }
    for (size_t c = 0; c < node.averages.size(); ++c) {
      if (node.range_min[c] > node.range_max[c]) {
        return InvalidArgumentError("device node: channel " + std::to_string(c) +
                                    " range min exceeds max");
      }
    }
  }
  out[0] = EncodeWord0(node.in_buffer, node.has_brick, node.child_group);
  out[1] = node.in_buffer ? node.brick_slot : 0;
  for (int k = 0; 2 * k < channels; ++k) {
    const uint32_t lo = node.averages[2 * k];
    const uint32_t hi = 2 * k + 1 < channels ? node.averages[2 * k + 1] : 0;
    out[2 + k] = lo | (hi << 16);
  }
  const int range_word = NodeRangeWord(channels);
  for (int c = 0; c < channels; ++c) {
    const uint32_t lo = ranges ? node.range_min[c] : 0u;
    const uint32_t hi = ranges ? node.range_max[c] : 0xffffu;
    out[range_word + c] = lo | (hi << 16);
  }
  return Status::Ok();
}

DeviceNode DecodeNode(std::span<const uint32_t> words, int channels) {
  DeviceNode node;
  node.in_buffer = Word0InBuffer(words[0]);
  node.has_brick = Word0HasBrick(words[0]);
  node.child_group = Word0ChildGroup(words[0]);
  node.brick_slot = words[1];
  node.averages.resize(static_cast<size_t>(channels));
  for (int c = 0; c < channels; ++c) {
    const uint32_t word = words[2 + c / 2];
    node.averages[c] = static_cast<uint16_t>(c % 2 == 0 ? word & 0xffffu : word >> 16);
  }
  node.range_min.resize(static_cast<size_t>(channels));
  node.range_max.resize(static_cast<size_t>(channels));
  for (int c = 0; c < channels; ++c) {
    const uint32_t word = words[NodeRangeWord(channels) + c];
    node.range_min[c] = static_cast<uint16_t>(word & 0xffffu);
    node.range_max[c] = static_cast<uint16_t>(word >> 16);
  }
  return node;
}

namespace {

// The node's word range inside a buffer of `buffer_words` words, or an error.
Result<uint64_t> NodeRange(size_t buffer_words, uint64_t node_id, int channels) {
  const uint64_t words = static_cast<uint64_t>(NodeWords(channels));
  // node_id < 2^33 for any encodable tree, but a caller's id is not trusted: divide, not multiply.
  if (node_id >= buffer_words / words) {
    return OutOfRangeError("device node buffer: node " + std::to_string(node_id) +
                           " lies beyond the " + std::to_string(buffer_words / words) +
                           " nodes of the buffer");
  }
  return node_id * words;
}

}  // namespace

Status WriteNode(std::span<uint32_t> buffer, uint64_t node_id, const DeviceNode& node) {
  if (node.averages.empty()) return InvalidArgumentError("device node: no channel averages");
  const int channels = static_cast<int>(node.averages.size());
  OCTO_ASSIGN_OR_RETURN(const uint64_t first, NodeRange(buffer.size(), node_id, channels));
  return EncodeNode(node, buffer.subspan(first, static_cast<size_t>(NodeWords(channels))));
}

Result<DeviceNode> ReadNode(std::span<const uint32_t> buffer, uint64_t node_id, int channels) {
  if (channels < 1) {
    return InvalidArgumentError("device node: " + std::to_string(channels) + " channels");
  }
  OCTO_ASSIGN_OR_RETURN(const uint64_t first, NodeRange(buffer.size(), node_id, channels));
  return DecodeNode(buffer.subspan(first, static_cast<size_t>(NodeWords(channels))), channels);
}

}  // namespace octoscope::octree
