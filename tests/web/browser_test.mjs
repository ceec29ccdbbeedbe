// Browser tests of the web client (issue 10, item 7): Debian's headless Chromium, driven by
// playwright-core, against the REAL `octoscope serve` started here on a loopback port chosen by
// the system, with a token. Datasets: a demo OME-TIFF and a dim 12-bit raw scan (written here)
// under --data, and the streamed-in demo (--demo). Screenshots of every view are saved to the
// artefact folder. Run: node --test browser_test.mjs (environment below; ctest sets it).
//   OCTOSCOPE_BINARY   the octoscope binary
//   OCTOSCOPE_WEB      the web/ folder to serve
//   OCTOSCOPE_ARTIFACTS where screenshots go (default: ./test-artifacts/web)
//   OCTOSCOPE_CHROMIUM Chromium (default /usr/bin/chromium)
//   OCTOSCOPE_NODE_MODULES the node_modules holding playwright-core (default: beside this file)

import {after, before, test} from 'node:test';
import assert from 'node:assert/strict';
import {execFileSync} from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import * as h from './browser_helpers.mjs';

const {chromium} = h.loadPlaywright();

const BINARY = process.env.OCTOSCOPE_BINARY;
const WEB = process.env.OCTOSCOPE_WEB;
const ARTIFACTS = path.resolve(process.env.OCTOSCOPE_ARTIFACTS || 'test-artifacts/web');
const CHROMIUM = process.env.OCTOSCOPE_CHROMIUM || '/usr/bin/chromium';
const TOKEN = 'web-test-token-0123456789abcdef';
assert.ok(BINARY && fs.existsSync(BINARY), 'OCTOSCOPE_BINARY must name the octoscope binary');
assert.ok(WEB && fs.existsSync(path.join(WEB, 'index.html')), 'OCTOSCOPE_WEB must name web/');

const work = fs.mkdtempSync(path.join(os.tmpdir(), 'octoscope-web-test-'));
const dataDir = path.join(work, 'data');
const cacheDir = path.join(work, 'cache');
fs.mkdirSync(ARTIFACTS, {recursive: true});

let server = null;     // {proc, url, port, stderr}
let browser = null;
let page = null;
const consoleErrors = [];
const foreignRequests = [];  // The page must need nothing but its own server (no CDN).
let expectConnectionErrors = false;

// ---- the server ----

function startServer(port = 0, demo = true) {
  const args = ['--data', dataDir, '--cache', cacheDir, '--port', String(port), '--token', TOKEN,
    '--web', WEB, '--ram-mb', '512', '--state-dir', path.join(work, 'state')];
  if (demo) args.push('--demo', '--demo-size', '96,96,48', '--demo-rate', '6');
  return h.startServer(BINARY, args, path.join(ARTIFACTS, 'serve.log'));
}
const stopServer = h.stopServer;

// ---- data ----

function writeDim12BitScan() {
  // One uint16 channel of a 12-bit camera at low light: background ≈ 100, a blob up to ≈ 400.
  const [nx, ny, nz] = [64, 64, 32];
  const buf = Buffer.alloc(nx * ny * nz * 2);
  let seed = 7;
  for (let z = 0; z < nz; ++z) {
    for (let y = 0; y < ny; ++y) {
      for (let x = 0; x < nx; ++x) {
        const r2 = ((x - 32) ** 2 + (y - 30) ** 2) / 400 + ((z - 16) ** 2) / 100;
        seed = (seed * 1103515245 + 12345) & 0x7fffffff;
        const v = Math.round(100 + 300 * Math.exp(-r2) + (seed % 20));
        buf.writeUInt16LE(v, 2 * ((z * ny + y) * nx + x));
      }
    }
  }
  fs.writeFileSync(path.join(dataDir, 'dim12bit.raw'), buf);
  fs.writeFileSync(path.join(dataDir, 'dim12bit.raw.json'), JSON.stringify({
    file: 'dim12bit.raw', size: [nx, ny, nz], channels: 1, channel_names: ['gfp'], dtype: 'uint16',
    endianness: 'little', layout: 'planar', header_bytes: 0, spacing: [0.5, 0.5, 1]}));
}

// ---- page helpers (on the current page) ----

const shot = (name) => h.shot(page, ARTIFACTS, name);
const frameOf = (view) => h.frameOf(page, view);
const waitForFinal = (...args) => h.waitForFinal(page, ...args);
const canvasStats = (...args) => h.canvasStats(page, ...args);
const differenceFrom = (...args) => h.differenceFrom(page, ...args);
const waitFor = h.waitFor;

// Centroid of the overlay pixels of one colour (the plane outlines in the 3-D view).
async function overlayCentroid(view, rgb) {
  return page.evaluate(([v, [r, g, b]]) => {
    const c = document.querySelector(`.view[data-view="${v}"] canvas.overlay`);
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sx = 0, sy = 0, n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i + 3] > 200 && Math.abs(d[i] - r) < 40 && Math.abs(d[i + 1] - g) < 40 && Math.abs(d[i + 2] - b) < 40) {
        const p = i / 4;
        sx += p % c.width;
        sy += Math.floor(p / c.width);
        ++n;
      }
    }
    return n ? {x: sx / n, y: sy / n, n} : {n: 0};
  }, [view, rgb]);
}

async function datasets() {
  const r = await fetch(`http://127.0.0.1:${server.port}/api/datasets`, {headers: {Authorization: `Bearer ${TOKEN}`}});
  assert.equal(r.status, 200);
  return r.json();
}

async function openPage(query, options = {}) {
  const context = await browser.newContext({viewport: {width: 1280, height: 760}, acceptDownloads: true, ...options});
  const p = await context.newPage();
  p.on('console', (m) => {
    if (m.type() !== 'error') return;
    if (expectConnectionErrors && /WebSocket|ERR_CONNECTION_REFUSED|Failed to load resource/.test(m.text())) return;
    consoleErrors.push(m.text());
  });
  p.on('pageerror', (e) => consoleErrors.push(`pageerror: ${e.message}`));
  p.on('request', (r) => {
    const u = new URL(r.url());
    if (!['127.0.0.1', 'localhost'].includes(u.hostname) && u.protocol !== 'data:' && u.protocol !== 'blob:') {
      foreignRequests.push(r.url());
    }
  });
  await p.goto(`http://127.0.0.1:${server.port}/?token=${TOKEN}${query}`);
  return p;
}

// ---- setup ----

let demoFile = null;
before(async () => {
  fs.mkdirSync(dataDir, {recursive: true});
  demoFile = execFileSync(BINARY, ['demo', '--out', dataDir, '--size', '64,56,40', '--name', 'embryo'],
      {encoding: 'utf8'}).trim().split('\n').pop();
  writeDim12BitScan();
  server = await startServer();
  browser = await chromium.launch({executablePath: CHROMIUM, args: ['--headless', '--no-sandbox']});
});

after(async () => {
  await browser?.close();
  await stopServer(server);
  fs.rmSync(work, {recursive: true, force: true});
});

// ---- tests, in order ----

test('the printed --demo URL opens the streaming demo, which fills in', async () => {
  const url = new URL(server.url);
  assert.equal(url.searchParams.get('token'), TOKEN);
  const demoId = url.searchParams.get('dataset');
  assert.ok(demoId, `the printed URL names the demo: ${server.url}`);
  page = await openPage(`&dataset=${demoId}`);
  await waitFor(() => page.evaluate(() => window.octoscope.connection === 'open'), 'connection');
  const first = await waitFor(() => page.evaluate(() => window.octoscope.dataset), 'opened');
  assert.equal(first.id, demoId);
  await waitFor(() => frameOf('3d'), 'a first 3-D frame');
  const early = await page.evaluate(() => window.octoscope.dataset);
  await shot('01-demo-streaming');
  const earlyStats = await canvasStats('z');
  // Growth: planes inserted rise and the views fill in.
  const grown = await waitFor(async () => {
    const d = await page.evaluate(() => window.octoscope.dataset);
    return d.planes_inserted > early.planes_inserted && d.planes_inserted >= d.planes_total ? d : null;
  }, 'the stream to complete', 90000);
  assert.ok(early.planes_inserted < grown.planes_total, 'the stream was seen before it completed');
  await waitForFinal('3d', 0);
  await waitForFinal('z', 0);
  const lateStats = await canvasStats('3d');
  assert.ok(lateStats.lit > 0.05, `3-D view shows the embryo (${JSON.stringify(lateStats)})`);
  const progressText = await page.textContent('#dataset-progress');
  await shot('02-demo-complete');
  console.log(`stream: ${early.planes_inserted} → ${grown.planes_inserted}/${grown.planes_total} planes; z view lit ${earlyStats.lit.toFixed(3)}; status "${progressText}"`);
  await page.context().close();
});

test('picker lists the datasets; opening one names it in the URL; the final frame equals the reference render', async () => {
  page = await openPage('');
  const dialog = page.locator('#picker');
  await dialog.waitFor({state: 'visible'});
  await page.waitForSelector('#picker tbody tr');
  await shot('03-picker');
  const rows = await page.locator('#picker tbody tr').allTextContents();
  assert.ok(rows.some((r) => r.includes('embryo')), `picker rows: ${rows}`);
  assert.ok(rows.some((r) => r.includes('dim12bit')), `picker rows: ${rows}`);
  await page.locator('#picker tbody tr', {hasText: 'embryo.ome.tif'}).locator('button').click();
  await waitFor(() => page.evaluate(() => window.octoscope.dataset?.name === 'embryo.ome.tif'), 'embryo opened');
  const id = await page.evaluate(() => window.octoscope.dataset.id);
  assert.equal(new URL(page.url()).searchParams.get('dataset'), id);
  // The token left the address bar (a copied address must not carry it); the dataset is there.
  assert.equal(new URL(page.url()).searchParams.get('token'), null);
  // Lossless finals: PNG frames, exact pixels.
  await page.check('#lossless');
  await page.evaluate(() => window.octoscope.frame('3d'));
  const f = await waitFor(async () => {
    const fr = await waitForFinal('3d', 0);
    return fr.lossless ? fr : null;
  }, 'a lossless final frame', 120000);
  const stats = await canvasStats('3d');
  assert.equal(f.width, stats.width);
  assert.equal(f.height, stats.height);
  assert.ok(stats.lit > 0.05, `non-blank 3-D frame: ${JSON.stringify(stats)}`);
  await shot('04-embryo-final');
  // The server's reference render of the same state: `octoscope render` with the page's camera
  // and parameters, at the frame's size.
  const state = await page.evaluate(() => window.octoscope.state);
  fs.writeFileSync(path.join(work, 'camera.json'), JSON.stringify(state.camera));
  fs.writeFileSync(path.join(work, 'params.json'), JSON.stringify(state.params));
  const ref = path.join(ARTIFACTS, '04-reference-render.png');
  execFileSync(BINARY, ['render', demoFile, '--out', ref, '--size', `${f.width}x${f.height}`, '--view',
    path.join(work, 'camera.json'), '--params', path.join(work, 'params.json'), '--refine'], {stdio: 'pipe'});
  const png = fs.readFileSync(ref).toString('base64');
  const cmp = await page.evaluate(async (b64) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const bmp = await createImageBitmap(new Blob([bytes], {type: 'image/png'}), {premultiplyAlpha: 'none',
      colorSpaceConversion: 'none'});
    const rc = new OffscreenCanvas(bmp.width, bmp.height).getContext('2d');
    rc.drawImage(bmp, 0, 0);
    const r = rc.getImageData(0, 0, bmp.width, bmp.height).data;
    const c = document.querySelector('.view[data-view="3d"] canvas.image');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    if (bmp.width !== c.width || bmp.height !== c.height) return {size: [bmp.width, bmp.height, c.width, c.height]};
    let maxDiff = 0, sum = 0, over2 = 0;
    for (let i = 0; i < d.length; i += 4) {
      for (let k = 0; k < 3; ++k) {
        // The reference PNG may carry alpha: composite it over black as the viewer shows it.
        const ref = Math.round(r[i + k] * r[i + 3] / 255);
        const diff = Math.abs(ref - d[i + k]);
        maxDiff = Math.max(maxDiff, diff);
        sum += diff;
        if (diff > 2) ++over2;
      }
    }
    const n = d.length / 4 * 3;
    return {maxDiff, mean: sum / n, over2: over2 / n};
  }, png);
  console.log(`final frame vs reference render: ${JSON.stringify(cmp)}`);
  assert.ok(!cmp.size, `sizes differ: ${cmp.size}`);
  assert.ok(cmp.mean < 0.5 && cmp.over2 < 0.005, `final frame differs from the reference: ${JSON.stringify(cmp)}`);
});

test('orbit drag, MIP/DVR switch and a channel toggle change the frame', async () => {
  const before = await waitForFinal('3d', 0);
  await canvasStats('3d', 'before-drag');
  const box = await page.locator('.view[data-view="3d"] .canvas-box').boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  for (let i = 1; i <= 10; ++i) await page.mouse.move(cx + i * 12, cy + i * 4);
  await page.mouse.up();
  const dragged = await waitForFinal('3d', before.stateVersion);
  const dragDiff = await differenceFrom('3d', 'before-drag');
  assert.ok(dragDiff > 2, `orbit changed the frame (mean diff ${dragDiff})`);
  await shot('05-after-orbit');

  const mode = await page.evaluate(() => window.octoscope.state.params.mode);
  const other = mode === 'mip' ? 'dvr' : 'mip';
  await canvasStats('3d', 'before-mode');
  await page.check(`input[name=mode][value=${other}]`);
  const moded = await waitForFinal('3d', dragged.stateVersion);
  assert.equal(await page.evaluate(() => window.octoscope.state.params.mode), other);
  const modeDiff = await differenceFrom('3d', 'before-mode');
  assert.ok(modeDiff > 2, `${mode} → ${other} changed the frame (mean diff ${modeDiff})`);
  await shot(`06-mode-${other}`);

  await canvasStats('3d', 'before-toggle');
  await page.uncheck('.channel[data-channel="1"] input.visible');
  const toggled = await waitForFinal('3d', moded.stateVersion);
  const toggleDiff = await differenceFrom('3d', 'before-toggle');
  assert.ok(toggleDiff > 2, `hiding channel 2 changed the frame (mean diff ${toggleDiff})`);
  await shot('07-channel-2-hidden');
  await page.check('.channel[data-channel="1"] input.visible');
  // A clipping plane (z, through the middle) cuts the volume; removing it restores the frame.
  const restored = await waitForFinal('3d', toggled.stateVersion);
  await canvasStats('3d', 'before-clip');
  await page.click('#add-clip');
  const clipped = await waitForFinal('3d', restored.stateVersion);
  const clipDiff = await differenceFrom('3d', 'before-clip');
  const planes = await page.evaluate(() => window.octoscope.state.params.clip_planes);
  assert.equal(planes.length, 1);
  assert.ok(clipDiff > 2, `a clipping plane changed the frame (mean diff ${clipDiff})`);
  await shot('07b-clip-plane');
  await page.click('#clip-planes .remove');
  await waitForFinal('3d', clipped.stateVersion);
  console.log(`mean differences: orbit ${dragDiff.toFixed(1)}, mode ${modeDiff.toFixed(1)}, channel ${toggleDiff.toFixed(1)}, clip ${clipDiff.toFixed(1)}`);
});

test('a slice drag moves its plane in the 3-D view; a click moves the other two planes', async () => {
  const zBlue = [0x4f, 0x9d, 0xff];
  const before = await overlayCentroid('3d', zBlue);
  assert.ok(before.n > 50, 'the z plane outline is drawn in the 3-D view');
  const pos0 = await page.evaluate(() => window.octoscope.state.slices.position_um.slice());
  const z = await page.locator('.view[data-view="z"] .canvas-box').boundingBox();
  // Right-drag upwards moves the z plane towards +z.
  await page.mouse.move(z.x + z.width / 2, z.y + z.height * 0.8);
  await page.mouse.down({button: 'right'});
  for (let i = 1; i <= 8; ++i) await page.mouse.move(z.x + z.width / 2, z.y + z.height * 0.8 - i * 6);
  await page.mouse.up({button: 'right'});
  const pos1 = await page.evaluate(() => window.octoscope.state.slices.position_um.slice());
  assert.ok(pos1[2] > pos0[2], `z plane moved: ${pos0[2]} → ${pos1[2]}`);
  await page.waitForTimeout(200);
  const afterDrag = await overlayCentroid('3d', zBlue);
  const moved = Math.hypot(afterDrag.x - before.x, afterDrag.y - before.y);
  assert.ok(moved > 3, `z plane outline moved ${moved.toFixed(1)} px in the 3-D view`);
  // A click in the z view at its upper-left quarter moves x and y there.
  await page.mouse.click(z.x + z.width * 0.35, z.y + z.height * 0.35);
  const pos2 = await page.evaluate(() => window.octoscope.state.slices.position_um.slice());
  assert.ok(pos2[0] < pos1[0] && pos2[1] < pos1[1] && pos2[2] === pos1[2], `click: ${pos1} → ${pos2}`);
  // The wheel steps the plane voxel by voxel.
  await page.mouse.move(z.x + z.width / 2, z.y + z.height / 2);
  await page.mouse.wheel(0, -300);
  await page.waitForTimeout(150);
  const pos3 = await page.evaluate(() => window.octoscope.state.slices.position_um.slice());
  assert.ok(pos3[2] > pos2[2], `wheel moved z: ${pos2[2]} → ${pos3[2]}`);
  await waitForFinal('x', 0);
  await waitForFinal('z', 0);
  await shot('08-slices-moved');
  console.log(`z plane ${pos0[2].toFixed(2)} → ${pos1[2].toFixed(2)} µm, outline moved ${moved.toFixed(1)} px`);
});

test('enlarge and restore a view; help overlay', async () => {
  const small = await waitForFinal('y', 0);
  await page.click('.view[data-view="y"] .enlarge');
  await waitFor(() => page.locator('.view[data-view="3d"]').isHidden(), '3-D hidden');
  const f = await waitForFinal('y', 0, 90000, 700, small.frameId);
  const s = await canvasStats('y');
  await shot('09-y-enlarged');
  await page.keyboard.press('Escape');
  await waitFor(() => page.locator('.view[data-view="3d"]').isVisible(), '3-D visible');
  assert.ok(s.width > 2 * small.width, `the enlarged canvas is larger (${small.width} → ${s.width})`);
  assert.ok(Math.abs(f.width - s.width) <= 1 && Math.abs(f.height - s.height) <= 1,
      `enlarged y view rendered at its size (${f.width}×${f.height}, canvas ${s.width}×${s.height})`);
  await page.keyboard.press('.');
  await waitFor(async () => /fps [0-9.]+[\s\S]*rtt [0-9]+ ms[\s\S]*KB\/frame[\s\S]*bricks pending/.test(
      await page.textContent('#stats')), 'the stats overlay', 10000);
  await page.keyboard.press('.');
  await page.keyboard.press('?');
  assert.ok(await page.locator('#help').isVisible());
  await shot('10-help');
  await page.keyboard.press('Escape');
  assert.ok(await page.locator('#help').isHidden());
});

test('screenshot waits for the final frame and saves a 2× PNG with a scale bar', async () => {
  await page.click('#screenshot-button');
  await page.selectOption('#screenshot-dialog select[name=scale]', '2');
  const downloadP = page.waitForEvent('download', {timeout: 120000});
  await page.click('#screenshot-dialog button[type=submit]');
  const download = await downloadP;
  const file = path.join(ARTIFACTS, '11-screenshot-3d-2x.png');
  await download.saveAs(file);
  const png = fs.readFileSync(file);
  assert.equal(png.subarray(1, 4).toString(), 'PNG');
  const w = png.readUInt32BE(16), h = png.readUInt32BE(20);
  const c = await canvasStats('3d');
  assert.ok(Math.abs(w - 2 * c.width) <= 2 && Math.abs(h - 2 * c.height) <= 2, `2× of ${c.width}×${c.height}: ${w}×${h}`);
  await page.click('#screenshot-dialog .close');
});

test('auto-contrast gives a visible image on a dim 12-bit dataset', async () => {
  const list = await datasets();
  const dim = list.find((d) => d.name.includes('dim12bit'));
  assert.ok(dim, `dim dataset listed: ${list.map((d) => d.name)}`);
  await page.goto(`http://127.0.0.1:${server.port}/?token=${TOKEN}&dataset=${dim.id}`);
  await waitFor(() => page.evaluate((id) => window.octoscope.dataset?.id === id, dim.id), 'dim opened');
  const opened = await waitForFinal('z', 0);
  const auto = await canvasStats('z');
  assert.ok(auto.mean > 10 && auto.lit > 0.2, `dim data opens visible: ${JSON.stringify(auto)}`);
  await shot('12-dim-auto-contrast');
  // The full 16-bit window shows it black; one click on Auto brings it back.
  await page.fill('.channel[data-channel="0"] input.lo', '0');
  await page.fill('.channel[data-channel="0"] input.hi', '65535');
  await page.locator('.channel[data-channel="0"] input.hi').press('Enter');
  await page.locator('.channel[data-channel="0"] input.lo').dispatchEvent('change');
  const full = await waitForFinal('z', opened.stateVersion);
  const black = await canvasStats('z');
  assert.ok(black.mean < 4, `full 16-bit window is (nearly) black: ${JSON.stringify(black)}`);
  await shot('13-dim-full-window');
  await page.click('.channel[data-channel="0"] button.auto');
  await waitForFinal('z', full.stateVersion);
  const again = await canvasStats('z');
  assert.ok(again.mean > 10, `Auto makes it visible again: ${JSON.stringify(again)}`);
  const [lo, hi] = [await page.inputValue('.channel[data-channel="0"] input.lo'),
    await page.inputValue('.channel[data-channel="0"] input.hi')];
  assert.ok(Number(lo) >= 90 && Number(hi) <= 500, `window in file units ${lo} … ${hi}`);
  console.log(`dim 12-bit: auto mean ${auto.mean.toFixed(1)}, full window ${black.mean.toFixed(2)}, window ${lo}…${hi}`);
});

test('frames come at the canvas\'s physical size (device pixel ratio 2)', async () => {
  const ctx2 = await browser.newContext({viewport: {width: 900, height: 600}, deviceScaleFactor: 2});
  const p2 = await ctx2.newPage();
  p2.on('pageerror', (e) => consoleErrors.push(`pageerror: ${e.message}`));
  const list = await datasets();
  const dim = list.find((d) => d.name.includes('dim12bit'));
  await p2.goto(`http://127.0.0.1:${server.port}/?token=${TOKEN}&dataset=${dim.id}`);
  const f = await waitFor(() => p2.evaluate(() => {
    const fr = window.octoscope.frame('z');
    return fr && fr.tier === 'final' ? fr : null;
  }), 'a final z frame at DPR 2', 90000);
  const css = await p2.locator('.view[data-view="z"] .canvas-box').boundingBox();
  assert.ok(Math.abs(f.width - Math.floor(css.width) * 2) <= 2, `frame ${f.width} px for ${css.width} CSS px`);
  await p2.screenshot({path: path.join(ARTIFACTS, '14-dpr2.png')});
  await ctx2.close();
});

test('a lost connection is shown and recovers with the view restored', async () => {
  const list = await datasets();
  const embryo = list.find((d) => d.name === 'embryo.ome.tif');
  await page.goto(`http://127.0.0.1:${server.port}/?token=${TOKEN}&dataset=${embryo.id}`);
  await waitForFinal('3d', 0);
  await page.keyboard.press('x');  // A non-default camera that must survive the reconnect.
  await page.waitForTimeout(300);
  await waitForFinal('3d', 0);
  const camBefore = await page.evaluate(() => window.octoscope.state.camera);
  expectConnectionErrors = true;
  const port = server.port;
  await stopServer(server);
  await waitFor(() => page.evaluate(() => ['reconnecting', 'connecting'].includes(window.octoscope.connection)), 'lost connection shown');
  assert.ok(await page.locator('#connection-banner').isVisible(), 'banner shown');
  const banner = await page.textContent('#connection-banner');
  await shot('15-connection-lost');
  server = await startServer(port, false);
  await waitFor(() => page.evaluate(() => window.octoscope.connection === 'open'), 'reconnected', 60000);
  expectConnectionErrors = false;
  assert.ok(await page.locator('#connection-banner').isHidden());
  const f = await waitForFinal('3d', 0);
  const camAfter = await page.evaluate(() => window.octoscope.state.camera);
  for (let i = 0; i < 3; ++i) {
    assert.ok(Math.abs(camAfter.position[i] - camBefore.position[i]) < 1e-3, `camera restored: ${JSON.stringify(camBefore)} → ${JSON.stringify(camAfter)}`);
  }
  const s = await canvasStats('3d');
  assert.ok(s.lit > 0.02, 'the view is back');
  await shot('16-reconnected');
  console.log(`banner "${banner}"; reconnected, frame ${f.frameId}`);
});

test('no console errors, no request beyond the server', () => {
  assert.deepEqual(consoleErrors, []);
  assert.deepEqual(foreignRequests, []);
});
