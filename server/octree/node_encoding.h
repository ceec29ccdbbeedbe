// Device node encoding: the compact format in which octree nodes are mirrored into the GPU's
// NODE BUFFER (paper, "GPU Data Structure"; our layout is specified in docs/octree_format.md,
// section "Device node buffer"). Nodes are stored in child groups of 8 consecutive entries;
// node id n occupies words [n * NodeWords(C), (n + 1) * NodeWords(C)) of a uint32 buffer.
//
// One node = NodeWords(C) = 2 + ceil(C / 2) + C uint32 words (7 words for 3 channels):
//   word 0: bit 31 in_buffer (the node's brick is resident in the device brick buffer),
//           bit 30 has_brick (the node is not homogeneous and owns a brick),
//           bits 0..29 child group index (0 = no children; group g holds nodes 8g..8g+7;
//           group 0 is the root's pseudo-group: the root is node 0, nodes 1..7 are unused).
//   word 1: brick-buffer slot; meaningful only when in_buffer, encoded as 0 otherwise.
//   words 2..: per-channel averages as uint16, two per word: channel 2k in bits 0..15 of word
//           2 + k, channel 2k + 1 in bits 16..31 (0 when C is odd and 2k + 1 == C).
//   words 2 + ceil(C / 2) + c: channel c's value range over the node's subtree (every stored
//           voxel of the node and its descendants, Octree's subtree_min / subtree_max): min in
//           bits 0..15, max in bits 16..31. The kernels skip nodes whose range cannot contribute.
// Averages are the node's mean rounded to nearest (ties up) in the STORED sample type, so the
// encoding is lossless for uint8 and uint16 stored values (a uint16 average is exact to 1/65535
// of the range, a uint8 one to 1/255).
//
// Invariants of a node the encoder accepts: child_group <= kMaxChildGroup; in_buffer implies
// has_brick (a homogeneous node has no brick to be resident); averages.size() == channels.
//
// Thread safety: pure functions and plain value types.
#ifndef OCTOSCOPE_OCTREE_NODE_ENCODING_H_
#define OCTOSCOPE_OCTREE_NODE_ENCODING_H_

#include <cstdint>
#include <span>
#include <vector>

#include "octree/brick_geometry.h"
#include "util/result.h"
#include "util/status.h"

namespace octoscope::octree {

inline constexpr uint32_t kNodeInBufferBit = uint32_t{1} << 31;
inline constexpr uint32_t kNodeHasBrickBit = uint32_t{1} << 30;
inline constexpr uint32_t kNodeChildGroupMask = (uint32_t{1} << 30) - 1;
// The largest child-group index the 30-bit field can encode.
inline constexpr uint32_t kMaxChildGroup = kNodeChildGroupMask;
// How many child groups a tree may use: node ids (8 * group + octant) are 32-bit on the host and
// in the kernels, so groups are limited to 2^29 (ids < 2^32), below the field's 2^30.
inline constexpr uint64_t kChildGroupCapacity = uint64_t{1} << 29;

// Words per node for `channels` channels: 2 + ceil(channels / 2) + channels. REQUIRES:
// channels >= 1.
constexpr int NodeWords(int channels) { return 2 + (channels + 1) / 2 + channels; }
// The word of channel 0's value range inside a node's entry.
constexpr int NodeRangeWord(int channels) { return 2 + (channels + 1) / 2; }

// Node ids in the device buffer: the root is node 0; the 8 children in child group g >= 1 are
// nodes 8g + octant.
constexpr uint64_t ChildNodeId(uint32_t group, int octant) {
  return uint64_t{8} * group + static_cast<uint64_t>(octant);
}
// The first word of node `node_id` in a buffer of nodes with `channels` channels.
constexpr uint64_t NodeWordOffset(uint64_t node_id, int channels) {
  return node_id * static_cast<uint64_t>(NodeWords(channels));
}

// Child groups a tree of `geometry` can ever need at once: the root's pseudo-group plus one group
// per node at levels 1..R that is not virtual (virtual nodes hold no data and so never get
// children). Exact for a complete tree; pruning only lowers it. Because groups are reused
// lowest-first, every live group index is < this count.
uint64_t MaxChildGroups(const BrickGeometry& geometry);
// True when every possible tree of `geometry` is addressable: MaxChildGroups <=
// kChildGroupCapacity (2^29). (False e.g. for 65536^3 with 32^3 bricks; true for 65536^3 with
// 64^3 bricks.)
bool FitsDeviceEncoding(const BrickGeometry& geometry);

// A node's device entry, decoded.
struct DeviceNode {
  bool in_buffer = false;
  bool has_brick = false;
  uint32_t child_group = 0;  // 0 = no children.
  uint32_t brick_slot = 0;   // Device brick-buffer slot; 0 unless in_buffer.
  // Per channel, the subtree's value range; empty = the whole stored range [0, 65535] (nothing
  // can be skipped). When given, both have one entry per channel and min <= max.
  std::vector<uint16_t> range_min = {};
  std::vector<uint16_t> range_max = {};
  std::vector<uint16_t> averages;  // One per channel, in stored-type units.

  bool operator==(const DeviceNode&) const = default;
};

// Word 0 pieces. EncodeWord0 REQUIRES child_group <= kMaxChildGroup.
constexpr uint32_t EncodeWord0(bool in_buffer, bool has_brick, uint32_t child_group) {
  return (in_buffer ? kNodeInBufferBit : 0u) | (has_brick ? kNodeHasBrickBit : 0u) |
         (child_group & kNodeChildGroupMask);
}
constexpr bool Word0InBuffer(uint32_t word0) { return (word0 & kNodeInBufferBit) != 0; }
constexpr bool Word0HasBrick(uint32_t word0) { return (word0 & kNodeHasBrickBit) != 0; }
constexpr uint32_t Word0ChildGroup(uint32_t word0) { return word0 & kNodeChildGroupMask; }

// Rounds a node average (a mean of stored samples) to nearest, ties up, clamped to the stored
// type's range [0, 255] or [0, 65535]; NaN gives 0. REQUIRES: bytes_per_sample is 1 or 2.
uint16_t QuantizeAverage(double average, int bytes_per_sample);

// Writes `node` into `out` (exactly NodeWords(averages.size()) words). InvalidArgument when
// `out` has the wrong size, there are no averages, the ranges are malformed, or in_buffer is set
// without has_brick;
// OutOfRange when child_group > kMaxChildGroup. Nothing is written on error. brick_slot is
// written as 0 unless in_buffer.
Status EncodeNode(const DeviceNode& node, std::span<uint32_t> out);
// Decodes a node entry. REQUIRES: words.size() == NodeWords(channels), channels >= 1.
DeviceNode DecodeNode(std::span<const uint32_t> words, int channels);

// The same, addressed by node id inside a whole node buffer. OutOfRange when the node's words do
// not lie inside `buffer` (the buffer is never resized here).
Status WriteNode(std::span<uint32_t> buffer, uint64_t node_id, const DeviceNode& node);
Result<DeviceNode> ReadNode(std::span<const uint32_t> buffer, uint64_t node_id, int channels);

}  // namespace octoscope::octree

#endif  // OCTOSCOPE_OCTREE_NODE_ENCODING_H_
