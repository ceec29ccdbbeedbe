/* Device side of the DeviceOctree protocol (server/render/device_octree.h): brick slots split over
 * several allocations, the request list through which kernels ask for missing bricks, and the
 * per-slot "last used" stamps the host's LRU reads back.
 *
 * Request protocol: request_flags holds one uint per node id, the stamp of the last frame that
 * requested it; the first work item of a frame to request a node (atomic_xchg returns another
 * stamp) appends it to request_list, whose word 0 counts appends (it may exceed the capacity;
 * appends past the capacity are dropped and asked for again next frame) and words 1..capacity
 * hold node ids. slot_used[s] = frame marks slot s as sampled by the frame (plain stores: racing
 * work items write the same value).
 */
#ifndef OCTOSCOPE_KERNELS_FEEDBACK_H_
#define OCTOSCOPE_KERNELS_FEEDBACK_H_

#ifdef __OPENCL_VERSION__

/* The brick buffers of a DeviceOctree (kMaxBrickAllocations == 4), passed as four kernel
 * arguments; unused ones alias allocation 0. */
#define OCTO_BRICK_BUFFER_PARAMS                                                           \
  __global const ushort *bricks0, __global const ushort *bricks1,                          \
      __global const ushort *bricks2, __global const ushort *bricks3, uint slots_per_alloc
#define OCTO_BRICK_BUFFER_ARGS bricks0, bricks1, bricks2, bricks3, slots_per_alloc

/* The allocation holding `slot`; *local_slot receives the slot's index inside it. */
__global const ushort* OctoBrickAllocation(__global const ushort* bricks0,
                                           __global const ushort* bricks1,
                                           __global const ushort* bricks2,
                                           __global const ushort* bricks3, uint slots_per_alloc,
                                           uint slot, uint* local_slot) {
  const uint a = slot / slots_per_alloc;
  *local_slot = slot - a * slots_per_alloc;
  return a == 0u ? bricks0 : a == 1u ? bricks1 : a == 2u ? bricks2 : bricks3;
}

/* Asks the host for node `node`'s brick (once per frame per node). */
void OctoRequestNode(volatile __global uint* request_flags, volatile __global uint* request_list,
                     uint capacity, ulong node, uint frame) {
  if (atomic_xchg(&request_flags[node], frame) != frame) {
    const uint at = atomic_inc(&request_list[0]);
    if (at < capacity) request_list[1 + at] = (uint)node;
  }
}

/* Records that the frame sampled the brick in `slot`. */
void OctoMarkSlotUsed(__global uint* slot_used, uint slot, uint frame) {
  if (slot_used[slot] != frame) slot_used[slot] = frame;
}

#endif /* __OPENCL_VERSION__ */

#endif /* OCTOSCOPE_KERNELS_FEEDBACK_H_ */
