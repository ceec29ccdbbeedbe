// Slice view controls: the wheel (or PageUp/PageDown) moves the view's own plane voxel by voxel
// (shift: 10 voxels); a left click or drag moves the other two planes to the point under the
// pointer (the crosshair); a right or middle drag moves the view's own plane continuously
// (dragging up moves it towards higher coordinates). Touch: one finger moves the crosshair.

import {clickToPositions, sliceUmPerPixel, SLICE_AXES, stepSlice, clamp} from './slice_geometry.js';

const WHEEL_IDLE_MS = 250;

export class SliceControls {
  // ctx: {view (View), getGeometry() → {extent, spacing, positions} | null,
  //       onPositions(positions), onInteraction(active)}
  constructor(view, ctx) {
    this.view = view;
    this.ctx = ctx;
    this.dragging = null;
    this.wheelAccum = 0;
    const el = view.el.querySelector('.canvas-box');
    this.el = el;
    el.style.touchAction = 'none';
    el.addEventListener('pointerdown', (e) => this.down(e));
    el.addEventListener('pointermove', (e) => this.move(e));
    el.addEventListener('pointerup', (e) => this.up(e));
    el.addEventListener('pointercancel', (e) => this.up(e));
    el.addEventListener('wheel', (e) => this.wheel(e), {passive: false});
    el.addEventListener('contextmenu', (e) => e.preventDefault());
  }

  local(e) {
    const r = this.el.getBoundingClientRect();
    return [e.clientX - r.left, e.clientY - r.top];
  }

  down(e) {
    const g = this.ctx.getGeometry();
    if (!g) return;
    this.el.setPointerCapture?.(e.pointerId);
    this.dragging = {mode: e.button === 0 && !e.shiftKey ? 'cross' : 'depth', y: e.clientY,
      start: g.positions.slice()};
    this.ctx.onInteraction(true);
    if (this.dragging.mode === 'cross') this.moveCross(e, g);
    e.preventDefault();
  }

  moveCross(e, g) {
    const [x, y] = this.local(e);
    this.ctx.onPositions(clickToPositions(this.view.id, g.extent, this.view.cssWidth,
        this.view.cssHeight, x, y, g.positions));
  }

  move(e) {
    if (!this.dragging) return;
    const g = this.ctx.getGeometry();
    if (!g) return;
    if (this.dragging.mode === 'cross') {
      this.moveCross(e, g);
      return;
    }
    // Depth drag: one CSS pixel moves the plane by one screen pixel's worth of µm.
    const {axis} = SLICE_AXES[this.view.id];
    const s = sliceUmPerPixel(this.view.id, g.extent, this.view.cssWidth, this.view.cssHeight);
    const next = g.positions.slice();
    next[axis] = clamp(this.dragging.start[axis] + (this.dragging.y - e.clientY) * s, 0,
        g.extent[axis]);
    this.ctx.onPositions(next);
  }

  up() {
    if (!this.dragging) return;
    this.dragging = null;
    this.ctx.onInteraction(false);
  }

  wheel(e) {
    e.preventDefault();
    const g = this.ctx.getGeometry();
    if (!g) return;
    // One notch (or 100 px of smooth scrolling) is one voxel.
    this.wheelAccum += e.deltaMode === 0 ? e.deltaY / 100 : e.deltaY / 3;
    const steps = Math.trunc(this.wheelAccum);
    if (steps === 0) return;
    this.wheelAccum -= steps;
    this.ctx.onInteraction(true);
    this.ctx.onPositions(stepSlice(this.view.id, g.positions, g.extent, g.spacing,
        -steps * (e.shiftKey ? 10 : 1)));
    clearTimeout(this.wheelTimer);
    this.wheelTimer = setTimeout(() => this.ctx.onInteraction(false), WHEEL_IDLE_MS);
  }
}
