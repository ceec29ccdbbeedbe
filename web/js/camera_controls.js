// Camera controls of the 3-D view: orbit (left drag / one finger), pan (right or middle drag,
// shift + left drag, two-finger drag), zoom (wheel, pinch), roll (ctrl + left drag). Each change
// goes through onCamera(next orbit camera); onInteraction(true/false) brackets a gesture so the
// server renders interactive frames while it lasts (a wheel gesture ends 250 ms after its last
// notch).

import {orbit, pan, roll, umPerPixel, zoom} from './camera_math.js';

const ORBIT_RADIANS_PER_PIXEL = Math.PI / 360;
const WHEEL_IDLE_MS = 250;

export class CameraControls {
  // getCamera() → orbit camera; onCamera(cam); onInteraction(active).
  constructor(element, getCamera, onCamera, onInteraction) {
    this.el = element;
    this.getCamera = getCamera;
    this.onCamera = onCamera;
    this.onInteraction = onInteraction;
    this.pointers = new Map();  // pointerId → {x, y}
    this.mode = null;
    this.wheelTimer = null;
    this.active = false;
    element.addEventListener('pointerdown', (e) => this.down(e));
    element.addEventListener('pointermove', (e) => this.move(e));
    element.addEventListener('pointerup', (e) => this.up(e));
    element.addEventListener('pointercancel', (e) => this.up(e));
    element.addEventListener('wheel', (e) => this.wheel(e), {passive: false});
    element.addEventListener('contextmenu', (e) => e.preventDefault());
    element.style.touchAction = 'none';
  }

  setActive(active) {
    if (active === this.active) return;
    this.active = active;
    this.onInteraction(active);
  }

  down(e) {
    this.el.setPointerCapture?.(e.pointerId);
    this.pointers.set(e.pointerId, {x: e.clientX, y: e.clientY});
    if (this.pointers.size === 1) {
      if (e.button === 1 || e.button === 2 || e.shiftKey) this.mode = 'pan';
      else if (e.ctrlKey || e.metaKey) this.mode = 'roll';
      else this.mode = 'orbit';
    } else {
      this.mode = 'pinch';
      this.pinch = this.pinchState();
    }
    this.setActive(true);
    e.preventDefault();
  }

  pinchState() {
    const [a, b] = [...this.pointers.values()];
    return {dist: Math.hypot(a.x - b.x, a.y - b.y), cx: (a.x + b.x) / 2, cy: (a.y + b.y) / 2};
  }

  move(e) {
    const p = this.pointers.get(e.pointerId);
    if (!p) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y;
    p.x = e.clientX;
    p.y = e.clientY;
    let cam = this.getCamera();
    if (!cam) return;
    const height = this.el.clientHeight || 1;
    if (this.mode === 'orbit') {
      cam = orbit(cam, dx * ORBIT_RADIANS_PER_PIXEL, dy * ORBIT_RADIANS_PER_PIXEL);
    } else if (this.mode === 'pan') {
      const s = umPerPixel(cam, height);
      cam = pan(cam, dx * s, dy * s);
    } else if (this.mode === 'roll') {
      cam = roll(cam, dx * ORBIT_RADIANS_PER_PIXEL);
    } else if (this.mode === 'pinch' && this.pointers.size >= 2) {
      const next = this.pinchState();
      if (this.pinch.dist > 0 && next.dist > 0) cam = zoom(cam, next.dist / this.pinch.dist);
      const s = umPerPixel(cam, height);
      cam = pan(cam, (next.cx - this.pinch.cx) * s, (next.cy - this.pinch.cy) * s);
      this.pinch = next;
    } else {
      return;
    }
    this.onCamera(cam);
  }

  up(e) {
    this.pointers.delete(e.pointerId);
    if (this.pointers.size === 1) {
      this.mode = 'orbit';
    } else if (this.pointers.size === 0) {
      this.mode = null;
      this.setActive(false);
    }
  }

  wheel(e) {
    e.preventDefault();
    const cam = this.getCamera();
    if (!cam) return;
    const lines = e.deltaMode === 1 ? e.deltaY * 16 : e.deltaMode === 2 ? e.deltaY * 400 : e.deltaY;
    this.setActive(true);
    this.onCamera(zoom(cam, Math.exp(-lines * 0.0015)));
    clearTimeout(this.wheelTimer);
    this.wheelTimer = setTimeout(() => this.setActive(false), WHEEL_IDLE_MS);
  }
}
