// Slice geometry (docs/slices.md): the in-plane axes of the x, y and z slice views and the
// mapping between a slice view's pixels and physical µm. The server fits the box's
// cross-section into the image (smallest µm per pixel that fits), centred on the box. Pure.

export const SLICE_AXES = {
  z: {axis: 2, u: 0, v: 1},  // image x = +x, rows = +y
  y: {axis: 1, u: 0, v: 2},  // image x = +x, rows = +z
  x: {axis: 0, u: 1, v: 2},  // image x = +y, rows = +z
};

// µm per image pixel of a w × h slice image of `view`.
export function sliceUmPerPixel(view, extent, w, h) {
  const {u, v} = SLICE_AXES[view];
  return Math.max(extent[u] / w, extent[v] / h);
}

// Image point (x, y) of a w × h slice view → physical [u, v] µm.
export function slicePixelToUm(view, extent, w, h, x, y) {
  const {u, v} = SLICE_AXES[view];
  const s = sliceUmPerPixel(view, extent, w, h);
  return [extent[u] / 2 + (x - w / 2) * s, extent[v] / 2 + (y - h / 2) * s];
}

// Physical in-plane [u, v] µm → image point (x, y) of a w × h slice view.
export function sliceUmToPixel(view, extent, w, h, uUm, vUm) {
  const {u, v} = SLICE_AXES[view];
  const s = sliceUmPerPixel(view, extent, w, h);
  return [w / 2 + (uUm - extent[u] / 2) / s, h / 2 + (vUm - extent[v] / 2) / s];
}

// New slice positions after a click at image point (x, y) of `view`: the other two planes move
// there, clamped to the volume; this view's plane stays.
export function clickToPositions(view, extent, w, h, x, y, positions) {
  const {u, v} = SLICE_AXES[view];
  const [pu, pv] = slicePixelToUm(view, extent, w, h, x, y);
  const next = positions.slice();
  next[u] = clamp(pu, 0, extent[u]);
  next[v] = clamp(pv, 0, extent[v]);
  return next;
}

// Moves the plane of `view` by `steps` voxels (the axis' spacing), clamped to voxel centres.
export function stepSlice(view, positions, extent, spacing, steps) {
  const {axis} = SLICE_AXES[view];
  const s = spacing[axis] || 1;
  const next = positions.slice();
  const lo = s / 2, hi = Math.max(lo, extent[axis] - s / 2);
  // Snap to the voxel centre grid, then step.
  const index = Math.round((positions[axis] - lo) / s) + steps;
  next[axis] = clamp(lo + index * s, lo, hi);
  return next;
}

export function clamp(x, lo, hi) {
  return Math.min(Math.max(x, lo), hi);
}
