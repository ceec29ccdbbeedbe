// Transfer-function (DVR opacity) editor: a piecewise-linear opacity curve over the windowed
// value t ∈ [0, 1], edited by dragging control points on a small canvas (click adds a point,
// double-click or right-click removes one; the end points stay at t = 0 and t = 1). The curve
// becomes the channel's 256-entry LUT (docs/render_json.md): rgb = colour · t (the ramp the
// channel shows without a LUT), alpha = opacity(t). The default curve (alpha = t) is the
// renderer's own default, so no LUT is sent for it.

export const DEFAULT_POINTS = [[0, 0], [1, 1]];

// Opacity at t of a sorted list of [t, alpha] points.
export function evaluate(points, t) {
  if (t <= points[0][0]) return points[0][1];
  for (let i = 1; i < points.length; ++i) {
    const [t0, a0] = points[i - 1], [t1, a1] = points[i];
    if (t <= t1) return t1 > t0 ? a0 + (a1 - a0) * (t - t0) / (t1 - t0) : a1;
  }
  return points[points.length - 1][1];
}

export function isDefault(points) {
  return points.every(([t, a]) => Math.abs(t - a) < 1e-6);
}

// The LUT for `points` and `color` ([r, g, b] in 0..1): 256 × [r, g, b, a] integers 0..255.
export function buildLut(points, color) {
  const lut = [];
  for (let i = 0; i < 256; ++i) {
    const t = i / 255;
    lut.push([...color.map((c) => Math.round(c * t * 255)), Math.round(evaluate(points, t) * 255)]);
  }
  return lut;
}

// Points recovered from a LUT's alpha column (a state restored from the server): greedy
// piecewise-linear fit, each segment as long as it stays within 1.5 levels of every entry.
export function pointsFromLut(lut) {
  if (!Array.isArray(lut) || lut.length !== 256) return DEFAULT_POINTS.map((p) => p.slice());
  const a = lut.map((e) => e[3]);
  const pts = [[0, a[0] / 255]];
  let start = 0;
  while (start < 255) {
    let end = start + 1;
    while (end < 255 && fits(a, start, end + 1)) ++end;
    pts.push([end / 255, a[end] / 255]);
    start = end;
  }
  return pts.length > 32 ? [pts[0], pts[pts.length - 1]] : pts;
}

function fits(a, i, j) {
  for (let k = i + 1; k < j; ++k) {
    if (Math.abs(a[i] + (a[j] - a[i]) * (k - i) / (j - i) - a[k]) > 1.5) return false;
  }
  return true;
}

export class TransferFunctionEditor {
  constructor(canvas, onChange) {
    this.canvas = canvas;
    this.onChange = onChange;
    this.points = DEFAULT_POINTS.map((p) => p.slice());
    this.color = [1, 1, 1];
    this.drag = -1;
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    canvas.addEventListener('pointermove', (e) => this.move(e));
    canvas.addEventListener('pointerup', () => this.up());
    canvas.addEventListener('dblclick', (e) => this.remove(e));
    canvas.addEventListener('contextmenu', (e) => {
      e.preventDefault();
      this.remove(e);
    });
    canvas.style.touchAction = 'none';
  }

  set(points, color) {
    this.points = points.map((p) => p.slice());
    this.color = color;
    this.draw();
  }

  pos(e) {
    const r = this.canvas.getBoundingClientRect();
    return [Math.min(Math.max((e.clientX - r.left) / r.width, 0), 1),
      Math.min(Math.max(1 - (e.clientY - r.top) / r.height, 0), 1)];
  }

  nearest(e) {
    const r = this.canvas.getBoundingClientRect();
    const [t, a] = this.pos(e);
    let best = -1, bestD = 8;
    this.points.forEach(([pt, pa], i) => {
      const d = Math.hypot((pt - t) * r.width, (pa - a) * r.height);
      if (d < bestD) {
        best = i;
        bestD = d;
      }
    });
    return best;
  }

  down(e) {
    if (e.button !== 0) return;
    this.canvas.setPointerCapture?.(e.pointerId);
    let i = this.nearest(e);
    if (i < 0) {
      const [t, a] = this.pos(e);
      this.points.push([t, a]);
      this.points.sort((p, q) => p[0] - q[0]);
      i = this.points.findIndex((p) => p[0] === t && p[1] === a);
    }
    this.drag = i;
    this.move(e);
  }

  move(e) {
    if (this.drag < 0) return;
    const [t, a] = this.pos(e);
    const i = this.drag, n = this.points.length;
    // End points keep their t; inner points stay between their neighbours.
    const tt = i === 0 ? 0 : i === n - 1 ? 1 :
        Math.min(Math.max(t, this.points[i - 1][0] + 1e-3), this.points[i + 1][0] - 1e-3);
    this.points[i] = [tt, a];
    this.draw();
    this.onChange(this.points, true);
  }

  up() {
    if (this.drag < 0) return;
    this.drag = -1;
    this.onChange(this.points, false);
  }

  remove(e) {
    const i = this.nearest(e);
    if (i > 0 && i < this.points.length - 1) {
      this.points.splice(i, 1);
      this.draw();
      this.onChange(this.points, false);
    }
  }

  draw() {
    const c = this.canvas, ctx = c.getContext('2d');
    const w = c.width, h = c.height;
    const grad = ctx.createLinearGradient(0, 0, w, 0);
    const rgb = (t) => this.color.map((v) => Math.round(v * t * 255)).join(',');
    grad.addColorStop(0, `rgb(${rgb(0)})`);
    grad.addColorStop(1, `rgb(${rgb(1)})`);
    ctx.fillStyle = '#101216';
    ctx.fillRect(0, 0, w, h);
    ctx.globalAlpha = 0.35;
    ctx.fillStyle = grad;
    ctx.fillRect(0, 0, w, h);
    ctx.globalAlpha = 1;
    ctx.strokeStyle = '#fff';
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    this.points.forEach(([t, a], i) => {
      const x = t * (w - 1), y = (1 - a) * (h - 1);
      if (i === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
    });
    ctx.stroke();
    ctx.fillStyle = '#fff';
    for (const [t, a] of this.points) {
      ctx.beginPath();
      ctx.arc(t * (w - 1), (1 - a) * (h - 1), 3.5, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
}
