import {test} from 'node:test';
import assert from 'node:assert/strict';
import * as sg from '../../../web/js/slice_geometry.js';
import * as hist from '../../../web/js/histogram.js';
import {formatLength, niceScaleBar} from '../../../web/js/scale_bar.js';
import * as tf from '../../../web/js/transfer_function_editor.js';
import {clipPlaneDocument, keptByClipPlanes} from '../../../web/js/render_panel.js';
import {actionFor, SHORTCUTS} from '../../../web/js/shortcuts.js';

const extent = [100, 50, 20];

test('slice pixels and µm are inverse, the box fitted and centred (docs/slices.md)', () => {
  for (const view of ['x', 'y', 'z']) {
    const [w, h] = [320, 200];
    const [u, v] = sg.slicePixelToUm(view, extent, w, h, 33.5, 150.25);
    const [x, y] = sg.sliceUmToPixel(view, extent, w, h, u, v);
    assert.ok(Math.abs(x - 33.5) < 1e-9 && Math.abs(y - 150.25) < 1e-9);
    const {u: ua, v: va} = sg.SLICE_AXES[view];
    const [cx, cy] = sg.sliceUmToPixel(view, extent, w, h, extent[ua] / 2, extent[va] / 2);
    assert.deepEqual([cx, cy], [w / 2, h / 2]);
    const [x0, y0] = sg.sliceUmToPixel(view, extent, w, h, 0, 0);
    const [x1, y1] = sg.sliceUmToPixel(view, extent, w, h, extent[ua], extent[va]);
    assert.ok(x0 >= -1e-9 && y0 >= -1e-9 && x1 <= w + 1e-9 && y1 <= h + 1e-9);
    assert.ok(Math.abs(x1 - x0 - w) < 1e-9 || Math.abs(y1 - y0 - h) < 1e-9);
  }
});

test('a click moves the other two planes; a step snaps to voxel centres', () => {
  const pos = [50, 25, 10];
  const next = sg.clickToPositions('z', extent, 200, 100, 0, 0, pos);
  assert.deepEqual(next, [0, 0, 10]);  // top-left corner of the z view is x = 0, y = 0
  assert.deepEqual(sg.clickToPositions('x', extent, 100, 40, 50, 20, pos), [50, 25, 10]);
  // Centres at 1, 3, 5, …: 10.2 snaps to 11, one step on is 13.
  assert.deepEqual(sg.stepSlice('z', [0, 0, 10.2], extent, [1, 1, 2], 1), [0, 0, 13]);
  assert.deepEqual(sg.stepSlice('z', [0, 0, 10], extent, [1, 1, 2], -100), [0, 0, 1]);
  assert.deepEqual(sg.stepSlice('z', [0, 0, 10], extent, [1, 1, 2], 100), [0, 0, 19]);
});

// A reference histogram: exact values, binned as the server documents it.
function makeHistogram(values, lo, hi) {
  const bins = new Array(256).fill(0);
  for (const v of values) bins[Math.min(255, Math.floor((v - lo) / (hi - lo) * 256))]++;
  const sorted = [...values].sort((a, b) => a - b);
  return {channel: {count: values.length, min: sorted[0], max: sorted.at(-1), lo, hi, bins}, sorted};
}

test('percentiles from bins are within one bin of the exact ones', () => {
  let seed = 1;
  const rand = () => (seed = (seed * 16807) % 2147483647) / 2147483647;
  const values = Array.from({length: 20000}, () => Math.floor(100 + 3000 * rand() * rand()));
  const {channel, sorted} = makeHistogram(values, 0, 4096);
  for (const q of [0.001, 0.1, 0.5, 0.9, 0.999]) {
    const exact = sorted[Math.floor(q * (sorted.length - 1))];
    assert.ok(Math.abs(hist.percentile(channel, q) - exact) <= 4096 / 256 + 1, `q=${q}`);
  }
  assert.equal(hist.percentile({bins: new Array(256).fill(0), lo: 0, hi: 1}, 0.5), null);
});

test('auto-contrast opens a dim 12-bit camera visibly in a 16-bit type', () => {
  const values = Array.from({length: 5000}, (_, i) => 90 + (i % 300));
  const {channel} = makeHistogram(values, 0, 65536);
  channel.p001 = 90;
  channel.p999 = 389;
  const map = hist.valueMap({dtype: 'uint16'}, 0, channel);
  const w = hist.autoContrast(channel, map);
  assert.equal(w.window, 299);
  assert.equal(w.level, 90 + 299 / 2);
  // Without the server's percentiles, the bins give a window within a few bins.
  const w2 = hist.autoContrast({...channel, p001: undefined, p999: undefined}, map);
  assert.ok(w2.window < 2000, `window ${w2.window}`);
});

test('value maps: file units for signed and wide types', () => {
  const i16 = hist.valueMap({dtype: 'int16'}, 0, null);
  assert.equal(hist.toFile(i16, 0), -32768);
  const [lo, hi] = hist.rangeFromWindow(i16, 1000, 32768);
  assert.deepEqual([lo, hi], [-500, 500]);
  const f32 = hist.valueMap({dtype: 'float32'}, 0, {min: -1, max: 1});
  assert.ok(Math.abs(hist.toFile(f32, 65535) - 1) < 1e-12);
  const given = hist.valueMap({dtype: 'float32', value_maps: [{offset: 5, scale: 2}]}, 0, null);
  assert.equal(hist.toFile(given, 1), 7);
  const w = hist.windowFromRange(i16, -500, 500);
  assert.deepEqual(w, {window: 1000, level: 32768});
});

test('scale bars are 1, 2 or 5 × 10^k and fit', () => {
  assert.deepEqual(niceScaleBar(0.5, 200), {um: 100, px: 200, label: '100 µm'});
  const b = niceScaleBar(0.37, 150);
  assert.equal(b.um, 50);
  assert.ok(b.px <= 150);
  assert.equal(niceScaleBar(0.001, 120).label, '100 nm');
  assert.equal(formatLength(2500), '2.5 mm');
  assert.equal(niceScaleBar(0, 100), null);
});

test('opacity curve → LUT → curve', () => {
  const pts = [[0, 0], [0.2, 0], [0.6, 0.8], [1, 1]];
  const lut = tf.buildLut(pts, [0, 1, 0.5]);
  assert.equal(lut.length, 256);
  assert.deepEqual(lut[255], [0, 255, 128, 255]);
  assert.equal(lut[0][3], 0);
  assert.equal(lut[51][3], 0);  // t = 0.2
  assert.ok(Math.abs(tf.evaluate(pts, 0.4) - 0.4) < 1e-9);
  const back = tf.pointsFromLut(lut);
  for (let t = 0; t <= 1; t += 0.05) assert.ok(Math.abs(tf.evaluate(back, t) - tf.evaluate(pts, t)) < 0.02);
  assert.ok(tf.isDefault(tf.DEFAULT_POINTS));
});

test('clip planes sweep the volume: t = 1 keeps every corner, t = 0 none', () => {
  const corners = [];
  for (let i = 0; i < 8; ++i) corners.push([i & 1 ? 100 : 0, i & 2 ? 50 : 0, i & 4 ? 20 : 0]);
  for (const plane of [{kind: 'x', flip: false}, {kind: 'z', flip: true},
    {kind: 'free', flip: false, azimuth: 40, elevation: -25}]) {
    const all = clipPlaneDocument({...plane, t: 1}, extent);
    const none = clipPlaneDocument({...plane, t: 0}, extent);
    assert.ok(corners.every((c) => keptByClipPlanes([all], c)));
    // At t = 0 only the box's touching face or corner remains (inclusive), no inner point.
    const inner = corners.map((c) => c.map((v, a) => v === 0 ? 0.01 * extent[a] : 0.99 * extent[a]));
    assert.ok(inner.every((c) => !keptByClipPlanes([none], c)));
  }
  const half = clipPlaneDocument({kind: 'x', flip: false, t: 0.5}, extent);
  assert.deepEqual(half, {normal: [1, 0, 0], distance: 50});
  assert.deepEqual(clipPlaneDocument({kind: 'x', flip: true, t: 0.25}, extent), {normal: [-1, 0, 0], distance: -75});
});

test('shortcuts ignore form fields and every listed key has an action', () => {
  assert.equal(actionFor({key: 'm', target: {tagName: 'INPUT'}}), null);
  assert.equal(actionFor({key: 'm', target: {tagName: 'INPUT', type: 'number'}}), null);
  assert.equal(actionFor({key: 'm', target: {tagName: 'INPUT', type: 'range'}}), 'mode');
  assert.equal(actionFor({key: 'ArrowLeft', target: {tagName: 'INPUT', type: 'range'}}), null);
  assert.equal(actionFor({key: 'ArrowLeft', target: {tagName: 'CANVAS'}}), 'orbit');
  assert.equal(actionFor({key: 'Escape', target: {tagName: 'INPUT'}}), 'escape');
  assert.equal(actionFor({key: 'm', target: {tagName: 'DIV'}}), 'mode');
  assert.equal(actionFor({key: 'm', ctrlKey: true, target: {tagName: 'DIV'}}), null);
  const keys = SHORTCUTS.flatMap((s) => s.keys);
  assert.equal(new Set(keys).size, keys.length, 'a key is listed twice');
});
