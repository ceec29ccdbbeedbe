import {test} from 'node:test';
import assert from 'node:assert/strict';
import * as cm from '../../../web/js/camera_math.js';

const extent = [120, 80, 40];
const near = (a, b, tol = 1e-6) => assert.ok(Math.abs(a - b) <= tol, `${a} vs ${b}`);

for (const projection of ['ortho', 'perspective']) {
  test(`project inverts imageRay (${projection})`, () => {
    let cam = cm.fitCamera('iso', extent, 1.5, projection);
    cam = cm.orbit(cam, 0.3, -0.2);
    const [w, h] = [300, 200];
    for (const [x, y] of [[0.5, 0.5], [150, 100], [299.5, 10.25], [17, 180]]) {
      const ray = cm.imageRay(cam, extent, w, h, x, y);
      const p = cm.add(ray.origin, cm.mul(ray.dir, 57.5));
      const q = cm.project(cam, extent, w, h, p);
      near(q[0], x);
      near(q[1], y);
    }
  });

  test(`a fitted preset shows the whole box and touches an edge (${projection})`, () => {
    for (const preset of ['x', '-x', 'y', '-y', 'z', '-z', 'iso']) {
      const [w, h] = [400, 300];
      const cam = cm.fitCamera(preset, extent, w / h, projection);
      let maxFrac = 0;
      for (let i = 0; i < 8; ++i) {
        const c = [i & 1 ? extent[0] : 0, i & 2 ? extent[1] : 0, i & 4 ? extent[2] : 0];
        const [x, y] = cm.project(cam, extent, w, h, c);
        assert.ok(x >= -1e-6 && x <= w + 1e-6 && y >= -1e-6 && y <= h + 1e-6, `${preset} corner ${i}`);
        maxFrac = Math.max(maxFrac, Math.abs(x - w / 2) / (w / 2), Math.abs(y - h / 2) / (h / 2));
      }
      if (projection === 'ortho') near(maxFrac, 1, 1e-9);
    }
  });
}

test('standard frames follow camera.h (z: image x = +x, rows = +y; x: image x = +y, rows = +z)', () => {
  const z = cm.presetFrame('z');
  assert.deepEqual(z.right.map((v) => Math.round(v) + 0), [1, 0, 0]);
  assert.deepEqual(z.up.map((v) => Math.round(v) + 0), [0, -1, 0]);
  const x = cm.presetFrame('x');
  assert.deepEqual(x.right.map((v) => Math.round(v) + 0), [0, 1, 0]);
  assert.deepEqual(x.up.map((v) => Math.round(v) + 0), [0, 0, -1]);
  const y = cm.presetFrame('y');
  assert.deepEqual(y.forward.map((v) => Math.round(v) + 0), [0, -1, 0]);
  assert.deepEqual(y.right.map((v) => Math.round(v) + 0), [1, 0, 0]);
});

test('camera document round trip keeps the image', () => {
  for (const projection of ['ortho', 'perspective']) {
    const cam = cm.pan(cm.orbit(cm.fitCamera('iso', extent, 1, projection), 1, 0.5), 10, -5);
    const doc = cm.toCameraDocument(cam, extent);
    const back = cm.fromCameraDocument(doc, extent);
    for (const [x, y] of [[10, 20], [100, 100]]) {
      const a = cm.imageRay(cam, extent, 200, 200, x, y);
      const b = cm.imageRay(back, extent, 200, 200, x, y);
      // Same ray (origins may differ along the ray for ortho).
      for (let i = 0; i < 3; ++i) near(a.dir[i], b.dir[i], 1e-5);
      const d = cm.sub(b.origin, a.origin);
      const off = cm.sub(d, cm.mul(a.dir, cm.dot(d, a.dir)));
      near(cm.length(off), 0, 1e-4);
    }
  }
});

test('an orthographic camera stands outside the volume', () => {
  const cam = cm.zoom(cm.fitCamera('z', extent, 1, 'ortho'), 50);
  const pos = cm.cameraPosition(cam, extent);
  assert.ok(pos[2] < 0, `camera plane at z=${pos[2]} is inside the box`);
});

test('orbit keeps the frame orthonormal and the pivot', () => {
  let cam = cm.fitCamera('iso', extent, 1);
  for (let i = 0; i < 50; ++i) cam = cm.orbit(cam, 0.37, 0.11);
  near(cm.length(cam.forward), 1, 1e-9);
  near(cm.length(cam.up), 1, 1e-9);
  near(cm.dot(cam.forward, cam.up), 0, 1e-9);
  assert.deepEqual(cam.pivot, [60, 40, 20]);
});

test('plane outlines: a plane seen edge-on in a standard view, clipped behind a perspective eye', () => {
  const cam = cm.fitCamera('z', extent, 1.5, 'ortho');
  const segs = cm.planeOutline(cam, extent, 300, 200, 0, 30);  // x = 30 plane, seen from +z
  assert.equal(segs.length, 4);
  for (const [[x0], [x1]] of segs) {
    const expect = cm.project(cam, extent, 300, 200, [30, 0, 0])[0];
    near(x0, expect, 1e-6);
    near(x1, expect, 1e-6);
  }
  // A perspective eye inside the box, looking along +z from z = 10: the z = 5 plane is behind it,
  // the x = 60 plane is cut at the eye's depth.
  const inside = {projection: 'perspective', pivot: [60, 40, 30], forward: [0, 0, 1], up: [0, -1, 0], distance: 20, fov: 60,
    orthoHeight: 10};
  assert.equal(cm.planeOutline(inside, extent, 100, 100, 2, 5).length, 0);
  const cut = cm.planeOutline(inside, extent, 100, 100, 0, 60);
  assert.ok(cut.length >= 2);
  for (const seg of cut) for (const [x, y] of seg) assert.ok(Number.isFinite(x) && Number.isFinite(y));
});
