/* Test kernels for tests/render/device_octree_test.cpp: they exercise the device side of the
 * DeviceOctree protocol (kernels/feedback.h) exactly as the renderer's kernels use it, so the
 * host side can be checked against independent CPU data. */
#include "feedback.h"

/* Copies the brick in `slot` (samples uint16 samples) out of the split brick buffer. One work
 * item per sample. */
__kernel void CopyBrick(OCTO_BRICK_BUFFER_PARAMS, uint slot, ulong samples,
                        __global ushort* out) {
  const ulong i = get_global_id(0);
  if (i >= samples) return;
  uint local_slot = 0;
  __global const ushort* bricks =
      OctoBrickAllocation(OCTO_BRICK_BUFFER_ARGS, slot, &local_slot);
  out[i] = bricks[(ulong)local_slot * samples + i];
}

/* Work item i asks for node ids[i] (ids may repeat: the flags deduplicate them). */
__kernel void RequestNodes(__global const uint* ids, uint count, __global uint* request_flags,
                           __global uint* request_list, uint capacity, uint frame) {
  const uint i = get_global_id(0);
  if (i >= count) return;
  OctoRequestNode(request_flags, request_list, capacity, ids[i], frame);
}

/* Work item i marks slot slots[i] as used by `frame`. */
__kernel void MarkSlots(__global const uint* slots, uint count, __global uint* slot_used,
                        uint frame) {
  const uint i = get_global_id(0);
  if (i >= count) return;
  OctoMarkSlotUsed(slot_used, slots[i], frame);
}
