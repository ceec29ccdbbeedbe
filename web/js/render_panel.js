// Render panel: compositing mode (DVR / MIP / MinIP), projection, quality (level-of-detail
// bias: negative = sharper and slower, positive = coarser and faster; lossless finals) and up to
// three clipping planes, each either axis-aligned (a slider along x, y or z, flip to keep the
// other side) or free (azimuth/elevation of the normal and a distance through the volume).
// A plane keeps samples p with normal · p ≤ distance (docs/render_json.md).

import {dot, normalize} from './camera_math.js';

export const MAX_CLIP_PLANES = 3;

// The clip plane document of a UI plane {kind: 'x'|'y'|'z'|'free', flip, t (0..1 through the
// volume), azimuth, elevation (degrees)}.
export function clipPlaneDocument(plane, extent) {
  let normal;
  if (plane.kind === 'free') {
    const az = plane.azimuth * Math.PI / 180, el = plane.elevation * Math.PI / 180;
    normal = [Math.cos(el) * Math.cos(az), Math.cos(el) * Math.sin(az), Math.sin(el)];
  } else {
    normal = [0, 0, 0];
    normal['xyz'.indexOf(plane.kind)] = 1;
  }
  if (plane.flip) normal = normal.map((v) => -v);
  normal = normalize(normal);
  // The plane sweeps the box along its normal: t = 0 clips everything, t = 1 nothing.
  let lo = 0, hi = 0;
  for (let a = 0; a < 3; ++a) {
    const v = normal[a] * extent[a];
    lo += Math.min(0, v);
    hi += Math.max(0, v);
  }
  const distance = lo + plane.t * (hi - lo);
  return {normal: normal.map((v) => Math.round(v * 1e6) / 1e6 + 0), distance: Math.round(distance * 1e4) / 1e4};
}

// Whether point p is kept by a list of plane documents.
export function keptByClipPlanes(planes, p) {
  return planes.every((pl) => dot(pl.normal, p) <= pl.distance);
}

export class RenderPanel {
  // handlers: onMode(mode), onProjection(p), onLodBias(b, interactive), onLossless(bool),
  //           onClipPlanes(docs, interactive)
  constructor(root, handlers) {
    this.root = root;
    this.h = handlers;
    this.extent = [1, 1, 1];
    this.planes = [];
    root.querySelectorAll('input[name=mode]').forEach((r) =>
      r.addEventListener('change', () => r.checked && handlers.onMode(r.value)));
    root.querySelector('#projection').addEventListener('change', (e) => handlers.onProjection(e.target.value));
    const lod = root.querySelector('#lod-bias');
    lod.addEventListener('input', () => {
      root.querySelector('#lod-bias-out').textContent = Number(lod.value).toFixed(1);
      handlers.onLodBias(Number(lod.value), true);
    });
    lod.addEventListener('change', () => handlers.onLodBias(Number(lod.value), false));
    root.querySelector('#lossless').addEventListener('change', (e) => handlers.onLossless(e.target.checked));
    root.querySelector('#add-clip').addEventListener('click', () => this.addPlane());
    this.list = root.querySelector('#clip-planes');
  }

  setExtent(extent) {
    this.extent = extent;
  }

  setMode(mode) {
    this.root.querySelectorAll('input[name=mode]').forEach((r) => {
      r.checked = r.value === mode;
    });
  }

  setProjection(p) {
    this.root.querySelector('#projection').value = p;
  }

  // The UI planes from a params document's clip planes (a restored or reset state).
  setClipPlanes(docs) {
    const current = this.planes.map((p) => clipPlaneDocument(p, this.extent));
    if (JSON.stringify(current) === JSON.stringify(docs ?? [])) return;
    this.planes = (docs ?? []).map((d) => this.planeFromDocument(d));
    this.render();
  }

  planeFromDocument(d) {
    const n = normalize(d.normal);
    const axis = n.findIndex((v) => Math.abs(Math.abs(v) - 1) < 1e-9);
    const plane = axis >= 0 ? {kind: 'xyz'[axis], flip: n[axis] < 0, azimuth: 0, elevation: 0, t: 1} :
        {kind: 'free', flip: false, azimuth: Math.atan2(n[1], n[0]) * 180 / Math.PI,
          elevation: Math.asin(Math.max(-1, Math.min(1, n[2]))) * 180 / Math.PI, t: 1};
    const probe = clipPlaneDocument({...plane, t: 0}, this.extent);
    const full = clipPlaneDocument({...plane, t: 1}, this.extent);
    const len = Math.hypot(...d.normal) || 1;
    plane.t = full.distance > probe.distance ?
        Math.min(1, Math.max(0, (d.distance / len - probe.distance) / (full.distance - probe.distance))) : 1;
    return plane;
  }

  addPlane() {
    if (this.planes.length >= MAX_CLIP_PLANES) return;
    const used = new Set(this.planes.map((p) => p.kind));
    const kind = ['z', 'x', 'y', 'free'].find((k) => !used.has(k)) ?? 'free';
    this.planes.push({kind, flip: false, t: 0.5, azimuth: 30, elevation: 30});
    this.render();
    this.emit(false);
  }

  emit(interactive) {
    this.h.onClipPlanes(this.planes.map((p) => clipPlaneDocument(p, this.extent)), interactive);
  }

  render() {
    this.list.replaceChildren();
    this.planes.forEach((p, i) => {
      const el = document.createElement('div');
      el.className = 'clip-plane';
      el.innerHTML = `
        <div class="row">
          <select class="kind" title="Plane orientation">
            <option value="x">x</option><option value="y">y</option><option value="z">z</option>
            <option value="free">free</option></select>
          <input type="range" class="t" min="0" max="1" step="0.001" title="Position">
          <label title="Keep the other side"><input type="checkbox" class="flip"> flip</label>
          <button class="remove" title="Remove this plane">✕</button>
        </div>
        <div class="row free-only">
          <label>azimuth <input type="range" class="az" min="-180" max="180" step="1"></label>
          <label>elevation <input type="range" class="el" min="-90" max="90" step="1"></label>
        </div>`;
      const q = (s) => el.querySelector(s);
      q('.kind').value = p.kind;
      q('.t').value = p.t;
      q('.flip').checked = p.flip;
      q('.az').value = p.azimuth;
      q('.el').value = p.elevation;
      q('.free-only').hidden = p.kind !== 'free';
      q('.kind').addEventListener('change', (e) => {
        p.kind = e.target.value;
        q('.free-only').hidden = p.kind !== 'free';
        this.emit(false);
      });
      for (const [sel, key] of [['.t', 't'], ['.az', 'azimuth'], ['.el', 'elevation']]) {
        q(sel).addEventListener('input', (e) => {
          p[key] = Number(e.target.value);
          this.emit(true);
        });
        q(sel).addEventListener('change', () => this.emit(false));
      }
      q('.flip').addEventListener('change', (e) => {
        p.flip = e.target.checked;
        this.emit(false);
      });
      q('.remove').addEventListener('click', () => {
        this.planes.splice(i, 1);
        this.render();
        this.emit(false);
      });
      this.list.appendChild(el);
    });
    this.root.querySelector('#add-clip').disabled = this.planes.length >= MAX_CLIP_PLANES;
  }
}
