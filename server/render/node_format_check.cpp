// Compile-time proof that the device's view of the node buffer (kernels/node_format.h, the header
// every kernel includes) is the layout the host encoder writes (octree/node_encoding.h). Changing
// either side alone fails the build of octoscope_render.
#include <cstddef>
#include <cstdint>

#include "../../kernels/node_format.h"
#include "octree/brick_geometry.h"
#include "octree/node_encoding.h"
#include "render/cell_ranges.h"

namespace octoscope::render {
namespace {

namespace oc = ::octoscope::octree;

static_assert(OCTO_NODE_IN_BUFFER_BIT == oc::kNodeInBufferBit);
static_assert(OCTO_NODE_HAS_BRICK_BIT == oc::kNodeHasBrickBit);
static_assert(OCTO_NODE_CHILD_GROUP_MASK == oc::kNodeChildGroupMask);
static_assert(OCTO_NODE_CHILD_GROUP_MASK == oc::kMaxChildGroup);
static_assert(oc::EncodeWord0(false, false, 0) == 0u);
static_assert(oc::EncodeWord0(true, true, 5) ==
              (OCTO_NODE_IN_BUFFER_BIT | OCTO_NODE_HAS_BRICK_BIT | 5u));
static_assert(OCTO_NODE_SLOT_WORD == 1 && OCTO_NODE_AVERAGE_WORD == 2);
static_assert(OCTO_CHILDREN_PER_GROUP == 8 && oc::ChildNodeId(5, 3) == 8 * 5 + 3);
static_assert((OCTO_OCTANT_X | OCTO_OCTANT_Y | OCTO_OCTANT_Z) == 7 && OCTO_OCTANT_X == 1 &&
              OCTO_OCTANT_Y == 2 && OCTO_OCTANT_Z == 4);

constexpr bool NodeWordsAgree() {
  for (int c = 1; c <= oc::kMaxChannels; ++c) {
    if (OCTO_NODE_WORDS(c) != oc::NodeWords(c)) return false;
    if (OCTO_NODE_RANGE_WORD(c) != oc::NodeRangeWord(c)) return false;
  }
  return true;
}
static_assert(NodeWordsAgree());
static_assert(OCTO_FINE_CELL_SIZE == kCellSize && OCTO_COARSE_CELL_SIZE == kCoarseCellSize);
static_assert(OCTO_CELL_SIZE == OCTO_FINE_CELL_SIZE);  // Unless a program asks for coarse cells.

// The geometry argument is passed by value to kernels: no padding, 32-bit fields only.
static_assert(sizeof(int) == 4);
static_assert(sizeof(OctoTreeGeometry) == 32);
static_assert(offsetof(OctoTreeGeometry, volume_size) == 0);
static_assert(offsetof(OctoTreeGeometry, brick_size) == 12);
static_assert(offsetof(OctoTreeGeometry, root_level) == 24);
static_assert(offsetof(OctoTreeGeometry, channels) == 28);

}  // namespace
}  // namespace octoscope::render
