/* The ray caster's per-frame arguments, shared by kernels/raycast.cl and
 * server/render/volume_renderer.cpp (which static_asserts the layout: only 32-bit fields, no
 * padding, so OpenCL C and C++ agree byte for byte).
 *
 * Coordinates: everything positional is in LEVEL-0 VOXEL coordinates (p_vox = p_phys / spacing;
 * voxel v covers [v, v + 1)); the ray parameter t stays the PHYSICAL one (µm along a unit
 * physical direction), so the clipping interval and segment lengths equal the reference's.
 *
 * OctoRenderFrame (one per frame, passed by value):
 *   origin, forward, right, up: the camera in voxel space (the physical unit vectors divided by
 *     the spacing). Ortho: origin is the camera position moved along forward to the volume's
 *     centre plane and t_min = -(that shift), so rays keep starting on the camera plane.
 *   pixel_scale: ortho: µm per pixel; perspective: 2 tan(fov_y / 2) / height.
 *   lod_scale: footprint in finest-spacing voxels per unit: ortho: the footprint itself;
 *     perspective: per µm of distance along forward. Includes 2^lod_bias.
 *   clip: up to OCTO_MAX_CLIP_PLANES planes n . p_vox <= d (n = n_phys * spacing).
 *   background: premultiplied rgb, alpha.
 *   volume: level-0 size per axis (float); step in voxels.
 *   inv_reference: 1 / the smallest spacing (µm), for DVR opacity correction.
 *   lod_spacing: each axis's spacing / the smallest (1 exactly on the finest axes), for the
 *     level of detail of anisotropic voxels (raycast.cl: OctoLodSpacing).
 *   flags: all_identity (no enabled channel has a transform: one traversal per sample, empty
 *     space skipping allowed), skip_empty.
 * OctoChannelParams (one per ENABLED channel, in channel order):
 *   transform: 3x4 row-major, voxel space (S^-1 T S); identity = 1 when it is the identity.
 *   window_lo, inv_window, gamma, opacity_scale, color: the transfer function
 *   (render_params.h); lut: index of its 256 float4 entries in the LUT buffer (entries / 255),
 *   -1 for none; channel: the volume channel; visible_lo / visible_hi: outside (visible_lo,
 *   visible_hi) the channel's opacity is exactly 0 (value-range skipping).
 */
#ifndef OCTOSCOPE_KERNELS_RENDER_FORMAT_H_
#define OCTOSCOPE_KERNELS_RENDER_FORMAT_H_

#define OCTO_MAX_CLIP_PLANES 3
#define OCTO_LUT_ENTRIES 256
#define OCTO_MAX_ACTIVE_CHANNELS 64

#define OCTO_MODE_DVR 0
#define OCTO_MODE_MIP 1
#define OCTO_MODE_MINIP 2

#define OCTO_PROJECTION_ORTHO 0
#define OCTO_PROJECTION_PERSPECTIVE 1

/* Ray state of a refinement: next sample index, or this when the ray is finished. */
#define OCTO_RAY_DONE 0xffffffffu

/* Counters buffer (uint words). */
#define OCTO_COUNTER_FINISHED 0
#define OCTO_COUNTER_SAMPLES_LO 1
#define OCTO_COUNTER_SAMPLES_HI 2
/* Distinct brick slots the pass sampled (its working set; counted once per slot per frame). */
#define OCTO_COUNTER_SLOTS_USED 3
/* Channel samples skipped by empty-space skipping (64-bit as two words, like the samples). */
#define OCTO_COUNTER_SKIPPED_LO 4
#define OCTO_COUNTER_SKIPPED_HI 5
/* Refinement: tiles appended to the next pass's tile list. */
#define OCTO_COUNTER_NEXT_TILES 6
#define OCTO_COUNTER_WORDS 7

/* Work shape: rays in square tiles of OCTO_TILE x OCTO_TILE pixels (one work group each). */
#define OCTO_TILE 8

typedef struct OctoRenderFrame {
  float origin[3];
  int projection;
  float forward[3];
  float pixel_scale;
  float right[3];
  float t_min;
  float up[3];
  float lod_scale;
  float clip[OCTO_MAX_CLIP_PLANES][4];
  float background[4];
  float volume[3];
  float step;
  int clip_count;
  int width;
  int height;
  int active_channels;
  int all_identity;
  int skip_empty;
  float inv_reference;
  float lod_spacing[3];
  int pad0;
  int pad1;
} OctoRenderFrame;

typedef struct OctoChannelParams {
  float transform[12];
  float color[4];
  float window_lo;
  float inv_window;
  float gamma;
  float opacity_scale;
  int channel;
  int lut;
  int identity;
  /* DVR value-range skipping: stored values v <= visible_lo or v >= visible_hi give opacity 0
   * (conservative bounds of the transfer function's support; +-INFINITY when there is none). */
  float visible_lo;
  float visible_hi;
  int pad0;
} OctoChannelParams;

#endif /* OCTOSCOPE_KERNELS_RENDER_FORMAT_H_ */
