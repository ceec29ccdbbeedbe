// Channels panel: one row per channel — visibility, colour, name, window/level over the
// channel's histogram (file units; drag the edges or the middle, or type the bounds), one-click
// auto-contrast (0.1–99.9 % percentiles), gamma, DVR opacity (scale and curve editor) and the
// chromatic-aberration correction (per-channel shift in µm and scale). Every edit calls
// onChange(index, partial channel document, interactive).

import {autoContrast, drawHistogram, formatValue, rangeFromWindow, valueMap, windowFromRange} from './histogram.js';
import {buildLut, isDefault, pointsFromLut, TransferFunctionEditor} from './transfer_function_editor.js';

const hex = (rgb) => '#' + rgb.map((c) => Math.round(Math.min(Math.max(c, 0), 1) * 255)
    .toString(16).padStart(2, '0')).join('');
const fromHex = (s) => [1, 3, 5].map((i) => parseInt(s.slice(i, i + 2), 16) / 255);

export class ChannelsPanel {
  constructor(container, onChange) {
    this.container = container;
    this.onChange = onChange;
    this.rows = [];
    this.dataset = null;
    this.histogram = null;
    this.params = null;
  }

  setDataset(dataset, histogram, params) {
    this.dataset = dataset;
    this.histogram = histogram;
    this.params = params;
    this.container.replaceChildren();
    this.rows = params.channels.map((ch, i) => this.buildRow(i));
    this.update(params);
  }

  setHistogram(histogram) {
    this.histogram = histogram;
    if (this.params) this.update(this.params);
  }

  histChannel(i) {
    return this.histogram?.channels?.[i] ?? null;
  }

  map(i) {
    return valueMap(this.dataset, i, this.histChannel(i));
  }

  buildRow(i) {
    const name = this.dataset.channel_names?.[i] || `channel ${i + 1}`;
    const row = document.createElement('section');
    row.className = 'channel';
    row.dataset.channel = String(i);
    row.innerHTML = `
      <header>
        <input type="checkbox" class="visible" title="Show this channel (${i + 1})">
        <input type="color" class="color" title="Colour">
        <span class="name"></span>
        <button class="auto" title="Auto-contrast: 0.1–99.9 % of the channel's voxels">Auto</button>
      </header>
      <canvas class="hist" width="256" height="56" title="Window: drag an edge or the middle"></canvas>
      <div class="range">
        <label>min <input type="number" class="lo" step="any"></label>
        <label>max <input type="number" class="hi" step="any"></label>
        <span class="stats"></span>
      </div>
      <label class="slider">gamma <input type="range" class="gamma" min="-1.3" max="1.3" step="0.01"><output class="gamma-out"></output></label>
      <div class="dvr-only">
        <label class="slider">opacity <input type="range" class="opacity" min="-2" max="2" step="0.01"><output class="opacity-out"></output></label>
        <canvas class="tf" width="256" height="48" title="Opacity curve (DVR): drag points, click to add, double-click to remove"></canvas>
        <button class="tf-reset" title="Linear opacity">reset curve</button>
      </div>
      <details class="transform"><summary>Chromatic correction</summary>
        <div class="grid3">
          <span>shift µm</span><input type="number" step="0.01" class="tx"><input type="number" step="0.01" class="ty"><input type="number" step="0.01" class="tz">
          <span>scale</span><input type="number" step="0.0005" class="sx"><input type="number" step="0.0005" class="sy"><input type="number" step="0.0005" class="sz">
        </div>
        <button class="transform-reset">reset</button>
      </details>`;
    row.querySelector('.name').textContent = name;
    this.container.appendChild(row);
    const q = (s) => row.querySelector(s);
    const send = (doc, interactive = false) => this.onChange(i, doc, interactive);
    q('.visible').addEventListener('change', (e) => send({enabled: e.target.checked}));
    q('.color').addEventListener('input', (e) => {
      const color = fromHex(e.target.value);
      const doc = {color};
      if (this.params.channels[i].lut) doc.lut = buildLut(this.editors[i].points, color);
      send(doc, true);
    });
    q('.auto').addEventListener('click', () => this.autoContrast(i));
    const rangeInput = () => {
      const lo = Number(q('.lo').value), hi = Number(q('.hi').value);
      if (Number.isFinite(lo) && Number.isFinite(hi) && hi > lo) {
        send(windowFromRange(this.map(i), lo, hi));
      }
    };
    q('.lo').addEventListener('change', rangeInput);
    q('.hi').addEventListener('change', rangeInput);
    q('.gamma').addEventListener('input', (e) => send({gamma: round4(Math.pow(10, Number(e.target.value)))}, true));
    q('.gamma').addEventListener('change', (e) => send({gamma: round4(Math.pow(10, Number(e.target.value)))}));
    q('.opacity').addEventListener('input', (e) => send({opacity_scale: round4(Math.pow(10, Number(e.target.value)))}, true));
    q('.opacity').addEventListener('change', (e) => send({opacity_scale: round4(Math.pow(10, Number(e.target.value)))}));
    this.editors ??= [];
    this.editors[i] = new TransferFunctionEditor(q('.tf'), (points, interactive) => {
      const color = this.params.channels[i].color;
      send({lut: isDefault(points) ? null : buildLut(points, color)}, interactive);
    });
    q('.tf-reset').addEventListener('click', () => send({lut: null}));
    const transformInput = () => {
      const v = (s, d) => (Number.isFinite(Number(q(s).value)) && q(s).value !== '' ? Number(q(s).value) : d);
      send({transform: {translate: [v('.tx', 0), v('.ty', 0), v('.tz', 0)],
        scale: [v('.sx', 1), v('.sy', 1), v('.sz', 1)]}});
    };
    for (const s of ['.tx', '.ty', '.tz', '.sx', '.sy', '.sz']) q(s).addEventListener('input', transformInput);
    q('.transform-reset').addEventListener('click', () => {
      send({transform: {translate: [0, 0, 0], scale: [1, 1, 1]}});
    });
    this.bindHistogramDrag(i, q('.hist'));
    return row;
  }

  bindHistogramDrag(i, canvas) {
    let drag = null;
    canvas.style.touchAction = 'none';
    const valueAt = (e) => {
      const h = this.histChannel(i);
      const r = canvas.getBoundingClientRect();
      const f = (e.clientX - r.left) / r.width;
      return h ? h.lo + f * (h.hi - h.lo) : 0;
    };
    canvas.addEventListener('pointerdown', (e) => {
      const h = this.histChannel(i);
      if (!h) return;
      canvas.setPointerCapture?.(e.pointerId);
      const ch = this.params.channels[i];
      const [lo, hi] = rangeFromWindow(this.map(i), ch.window, ch.level);
      const v = valueAt(e);
      const tol = (h.hi - h.lo) * 0.04;
      const part = Math.abs(v - lo) < tol ? 'lo' : Math.abs(v - hi) < tol ? 'hi' : 'move';
      drag = {part, v0: v, lo, hi};
    });
    canvas.addEventListener('pointermove', (e) => {
      if (!drag) return;
      const d = valueAt(e) - drag.v0;
      let {lo, hi} = drag;
      if (drag.part === 'lo') lo = Math.min(lo + d, hi - 1e-6);
      else if (drag.part === 'hi') hi = Math.max(hi + d, lo + 1e-6);
      else {
        lo += d;
        hi += d;
      }
      this.onChange(i, windowFromRange(this.map(i), lo, hi), true);
    });
    const end = () => {
      if (!drag) return;
      drag = null;
      const ch = this.params.channels[i];
      this.onChange(i, {window: ch.window, level: ch.level}, false);
    };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
  }

  // Auto-contrast channel i from its histogram (all voxels counted so far).
  autoContrast(i) {
    const h = this.histChannel(i);
    const w = h && h.count !== 0 ? autoContrast(h, this.map(i)) : null;
    if (!w) {
      this.onNotice?.(`Auto-contrast: no voxels of channel ${i + 1} counted yet`);
      return false;
    }
    this.onChange(i, {window: round4(w.window), level: round4(w.level)}, false);
    return true;
  }

  autoContrastAll() {
    this.params?.channels.forEach((_, i) => this.autoContrast(i));
  }

  // Shows `params` (the server's state).
  update(params) {
    this.params = params;
    const mode = params.mode;
    params.channels.forEach((ch, i) => {
      const row = this.rows[i];
      if (!row) return;
      const q = (s) => row.querySelector(s);
      const active = document.activeElement;
      const setValue = (el, v) => {
        if (el !== active) el.value = v;
      };
      q('.visible').checked = ch.enabled !== false;
      row.classList.toggle('disabled', ch.enabled === false);
      setValue(q('.color'), hex(ch.color ?? [1, 1, 1]));
      const map = this.map(i);
      const [lo, hi] = rangeFromWindow(map, ch.window, ch.level);
      setValue(q('.lo'), formatValue(lo));
      setValue(q('.hi'), formatValue(hi));
      const gamma = ch.gamma ?? 1;
      setValue(q('.gamma'), Math.log10(gamma));
      q('.gamma-out').textContent = gamma.toFixed(2);
      const op = ch.opacity_scale ?? 1;
      setValue(q('.opacity'), Math.log10(Math.max(op, 0.01)));
      q('.opacity-out').textContent = op.toFixed(2);
      row.querySelector('.dvr-only').hidden = mode !== 'dvr';
      const h = this.histChannel(i);
      q('.stats').textContent = h && h.count !== 0 ?
          `data ${formatValue(h.min)} … ${formatValue(h.max)}` : 'no voxels yet';
      drawHistogram(q('.hist'), h, [lo, hi], ch.color ?? [1, 1, 1], gamma);
      if (this.editors[i].drag < 0) this.editors[i].set(pointsFromLut(ch.lut), ch.color ?? [1, 1, 1]);
      const t = ch.transform;
      if (Array.isArray(t) && t.length === 16) {
        setValue(q('.tx'), round4(t[3]));
        setValue(q('.ty'), round4(t[7]));
        setValue(q('.tz'), round4(t[11]));
        setValue(q('.sx'), round4(t[0]));
        setValue(q('.sy'), round4(t[5]));
        setValue(q('.sz'), round4(t[10]));
      }
    });
  }
}

function round4(v) {
  return Math.round(v * 1e4) / 1e4;
}
