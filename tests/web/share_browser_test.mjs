// Browser tests of sharing (issue 11, item 4): Debian's headless Chromium, driven by
// playwright-core, with several browser contexts (separate cookie jars and storage: separate
// people) against the REAL `octoscope serve` on a loopback port. The owner shares a viewer link;
// the viewer follows the owner's drags and cannot drive; promoted to controller it drives the
// owner's view; a view link opened in a third context reproduces the owner's final image exactly;
// revoking a link and removing a participant end their sessions with a clear message; the owner's
// reconnect keeps its session and links. Screenshots go to the artefact folder (share-*.png).
// Environment: as browser_test.mjs (OCTOSCOPE_BINARY, OCTOSCOPE_WEB, OCTOSCOPE_ARTIFACTS,
// OCTOSCOPE_CHROMIUM, OCTOSCOPE_NODE_MODULES).

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
const TOKEN = 'share-test-token-0123456789abcdef';
assert.ok(BINARY && fs.existsSync(BINARY), 'OCTOSCOPE_BINARY must name the octoscope binary');
assert.ok(WEB && fs.existsSync(path.join(WEB, 'index.html')), 'OCTOSCOPE_WEB must name web/');

const work = fs.mkdtempSync(path.join(os.tmpdir(), 'octoscope-share-test-'));
const dataDir = path.join(work, 'data');
fs.mkdirSync(ARTIFACTS, {recursive: true});

let server = null;
let browser = null;
let datasetId = null;
const pages = {};          // owner, viewer, fork, guest
const consoleErrors = [];  // From every page, except the expected refusals of dead links.

const shot = (name, p) => h.shot(p, ARTIFACTS, `share-${name}`);
const oct = (p, expr) => p.evaluate(expr);
const version = (p) => oct(p, () => window.octoscope.version);
const role = (p) => oct(p, () => window.octoscope.role);
const camera = (p) => oct(p, () => window.octoscope.state?.camera);

async function newPage(name, options = {}, allowRefusal = false) {
  const context = await browser.newContext({viewport: {width: 1280, height: 760}, ...options});
  const p = await context.newPage();
  p.on('console', (m) => {
    if (m.type() !== 'error') return;
    // A dead link's page: the refused upgrade and the 401 of the probe are expected.
    if (allowRefusal && /WebSocket|401|Failed to load resource/.test(m.text())) return;
    consoleErrors.push(`${name}: ${m.text()}`);
  });
  p.on('pageerror', (e) => consoleErrors.push(`${name}: pageerror: ${e.message}`));
  pages[name] = p;
  return p;
}

// Drags across the middle of the 3-D view.
async function drag3d(p, dx = 12, dy = 4, steps = 10) {
  const box = await p.locator('.view[data-view="3d"] .canvas-box').boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  await p.mouse.move(cx, cy);
  await p.mouse.down();
  for (let i = 1; i <= steps; ++i) await p.mouse.move(cx + i * dx, cy + i * dy);
  await p.mouse.up();
}

// The same camera up to the documents' rounding: the same projection, field of view and ortho
// height, position within 1e-3 µm, viewing direction and up within 1e-4 rad (the server may keep
// the target anywhere along the viewing ray and orthonormalise `up`).
function sameCamera(a, b) {
  if (!a || !b || a.projection !== b.projection || a.fov_y_degrees !== b.fov_y_degrees) return false;
  if (!(Math.abs(a.ortho_height - b.ortho_height) <= 1e-3)) return false;
  for (let i = 0; i < 3; ++i) if (!(Math.abs(a.position[i] - b.position[i]) <= 1e-3)) return false;
  const unit = (v) => v.map((x) => x / Math.hypot(...v));
  const cos = (u, v) => unit(u).reduce((s, x, i) => s + x * unit(v)[i], 0);
  const dir = (c) => c.target.map((t, i) => t - c.position[i]);
  return cos(dir(a), dir(b)) > Math.cos(1e-4) && cos(a.up, b.up) > Math.cos(1e-4);
}

// Deep equality, numbers within 1e-12 relative (a double printed to 15-16 digits and read back).
function assertClose(a, b, what, where = '') {
  if (typeof a === 'number' && typeof b === 'number') {
    assert.ok(Math.abs(a - b) <= 1e-12 * Math.max(1, Math.abs(a), Math.abs(b)), `${what}${where}: ${a} vs ${b}`);
  } else if (a && b && typeof a === 'object' && typeof b === 'object') {
    assert.deepEqual(Object.keys(a).sort(), Object.keys(b).sort(), `${what}${where}: keys`);
    for (const k of Object.keys(a)) assertClose(a[k], b[k], what, `${where}.${k}`);
  } else {
    assert.deepEqual(a, b, `${what}${where}`);
  }
}

async function expectSameCamera(p, q, what) {
  try {
    await h.waitFor(async () => sameCamera(await camera(p), await camera(q)), what, 10000);
  } catch (e) {
    throw new Error(`${e.message}: ${JSON.stringify(await camera(p))} vs ${JSON.stringify(await camera(q))}`);
  }
}

async function waitForLink(p, kind) {
  return h.waitFor(async () => {
    const l = await oct(p, () => window.octoscope.lastLink);
    const field = await p.inputValue('#session-panel .share-result input');
    return l && l.kind === kind && field && field === l.url ? l : null;
  }, `a ${kind} link`, 20000);
}

before(async () => {
  fs.mkdirSync(dataDir, {recursive: true});
  execFileSync(BINARY, ['demo', '--out', dataDir, '--size', '64,56,40', '--name', 'embryo'], {encoding: 'utf8'});
  const stateDir = path.join(work, 'state');
  server = await h.startServer(BINARY, ['--data', dataDir, '--cache', path.join(work, 'cache'), '--port', '0',
    '--token', TOKEN, '--web', WEB, '--ram-mb', '512', '--state-dir', stateDir],
  path.join(ARTIFACTS, 'share-serve.log'), {XDG_STATE_HOME: stateDir});
  const r = await fetch(`http://127.0.0.1:${server.port}/api/datasets`, {headers: {Authorization: `Bearer ${TOKEN}`}});
  datasetId = (await r.json()).find((d) => d.name === 'embryo.ome.tif').id;
  browser = await chromium.launch({executablePath: CHROMIUM, args: ['--headless', '--no-sandbox']});
});

after(async () => {
  await browser?.close();
  await h.stopServer(server);
  fs.rmSync(work, {recursive: true, force: true});
});

test('the owner creates a viewer link: shown, copied, listed; it carries no user token', async () => {
  const owner = await newPage('owner');
  await owner.context().grantPermissions(['clipboard-read', 'clipboard-write'], {origin: `http://127.0.0.1:${server.port}`});
  await owner.goto(`http://127.0.0.1:${server.port}/?token=${TOKEN}&dataset=${datasetId}`);
  await h.waitForFinal(owner, '3d', 0);
  assert.equal(await role(owner), 'owner');
  assert.ok(await owner.locator('#session-panel .share-owner').isVisible(), 'the owner sees the share tools');
  await owner.click('#session-panel .share-viewer');
  const link = await waitForLink(owner, 'viewer');
  const url = new URL(link.url);
  assert.equal(url.port, String(server.port));
  assert.ok(/^[A-Za-z0-9_-]{22,}$/.test(url.searchParams.get('share')), `share token in ${link.url}`);
  assert.equal(url.searchParams.get('token'), null, 'a share link never carries the user token');
  assert.equal(await owner.getAttribute('#session-panel .share-result', 'data-copied'), 'yes');
  assert.equal(await oct(owner, () => navigator.clipboard.readText()), link.url);
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.shares)).length === 1, 'the link listed');
  assert.equal(await owner.locator('#session-panel .share-link[data-role="viewer"]').count(), 1);
  await shot('01-owner-viewer-link', owner);
});

test('a viewer joins and follows the owner: camera, frames, mode, slices, channels', async () => {
  const owner = pages.owner;
  const link = await oct(owner, () => window.octoscope.lastLink.url);
  // Another person on another screen size: frames at its own viewport.
  const viewer = await newPage('viewer', {viewport: {width: 1000, height: 700}});
  await viewer.goto(link);
  await h.waitFor(async () => (await role(viewer)) === 'viewer', 'the viewer role');
  await h.waitFor(() => oct(viewer, () => window.octoscope.dataset?.id), 'the session\'s dataset');
  assert.equal(await oct(viewer, () => window.octoscope.dataset.id), datasetId);
  await h.waitForFinal(viewer, '3d', 0);
  // Everyone sees both participants; the owner's name is the one the viewer follows.
  const ownerName = await h.waitFor(async () => {
    const list = await oct(owner, () => window.octoscope.participants);
    return list.length === 2 ? list.find((p) => p.you).name : null;
  }, 'two participants at the owner');
  const seen = await h.waitFor(async () => {
    const list = await oct(viewer, () => window.octoscope.participants);
    return list.length === 2 ? list : null;
  }, 'two participants at the viewer');
  assert.deepEqual(seen.map((p) => p.role).sort(), ['owner', 'viewer']);
  assert.equal(seen.find((p) => p.you).role, 'viewer');
  const banner = viewer.locator('#follow-banner');
  assert.ok(await banner.isVisible(), 'a viewer sees the follow banner');
  assert.equal(await banner.textContent(), `Following ${ownerName} — view only`);
  // Driving controls are read-only; per-participant ones are not.
  for (const sel of ['input[name=mode][value=dvr]', '#projection', '#add-clip', '#auto-all', '[data-preset="x"]',
    '#reset-view', '#open-dataset', '.view[data-view="z"] .slice-slider', '.channel[data-channel="0"] input.visible']) {
    assert.ok(await viewer.locator(sel).isDisabled(), `${sel} is disabled for a viewer`);
  }
  assert.ok(await viewer.locator('#lossless').isEnabled(), 'lossless finals are the viewer\'s own choice');
  assert.ok(await viewer.locator('.view[data-view="3d"] .enlarge').isEnabled(), 'each participant keeps its own layout');
  assert.ok(await viewer.locator('#session-panel .share-owner').isHidden(), 'only the owner shares live');
  assert.equal(await viewer.locator('#session-panel .participant button').count(), 0, 'a viewer has no actions on others');
  assert.equal(await owner.locator('#session-panel .participant[data-role="viewer"] button.promote').count(), 1);

  // The owner drags: the viewer's state version goes up, its frame and camera follow.
  const v0 = await version(viewer);
  await h.canvasStats(viewer, '3d', 'before-owner-drag');
  await drag3d(owner);
  const driving = await h.waitFor(async () => {
    const list = await oct(viewer, () => window.octoscope.participants);
    return list.find((p) => p.driving)?.name;
  }, 'the owner marked driving at the viewer', 5000);
  assert.equal(driving, ownerName);
  const followed = await h.waitForFinal(viewer, '3d', v0);
  assert.ok(await version(viewer) > v0, 'the viewer\'s state version increased');
  const diff = await h.differenceFrom(viewer, '3d', 'before-owner-drag');
  assert.ok(diff > 2, `the viewer's frame changed with the owner's drag (mean diff ${diff})`);
  await expectSameCamera(viewer, owner, 'the same camera');
  const frame = await h.frameOf(viewer, '3d');
  const box = await viewer.locator('.view[data-view="3d"] .canvas-box').boundingBox();
  assert.ok(Math.abs(frame.width - Math.floor(box.width)) <= 1, `the viewer's frame at its own size (${frame.width} for ${box.width})`);
  await shot('02-owner-drove', owner);
  await shot('03-viewer-follows', viewer);

  // Mode, a slice and a channel: every panel of the viewer follows.
  const mode = await oct(owner, () => window.octoscope.state.params.mode);
  const other = mode === 'mip' ? 'dvr' : 'mip';
  await owner.check(`input[name=mode][value=${other}]`);
  await h.waitFor(() => viewer.isChecked(`input[name=mode][value=${other}]`), 'the viewer\'s mode follows');
  const z = await owner.locator('.view[data-view="z"] .canvas-box').boundingBox();
  await owner.mouse.move(z.x + z.width / 2, z.y + z.height / 2);
  await owner.keyboard.press('PageUp');
  await owner.uncheck('.channel[data-channel="1"] input.visible');
  await h.waitFor(async () => !(await viewer.isChecked('.channel[data-channel="1"] input.visible')), 'the channel follows');
  const ownerZ = await oct(owner, () => window.octoscope.state.slices.position_um[2]);
  await h.waitFor(async () => Math.abs(Number(await viewer.inputValue('.view[data-view="z"] .slice-slider')) - ownerZ) < 1e-6,
      'the viewer\'s z slider follows');
  await owner.check('.channel[data-channel="1"] input.visible');
  await h.waitForFinal(viewer, '3d', followed.stateVersion);
  await shot('04-viewer-panels-follow', viewer);
});

test('a viewer cannot drive: gestures, keys and controls change nothing; the server refuses it too', async () => {
  const {owner, viewer} = pages;
  const ownerFinal = await h.waitForFinal(owner, '3d', 0);
  await h.waitForFinal(viewer, '3d', 0);
  const ownerVersion = await version(owner);
  const viewerVersion = await version(viewer);
  const cam = await camera(viewer);
  await h.canvasStats(owner, '3d', 'owner-before-viewer-drag');
  await drag3d(viewer);
  await viewer.keyboard.press('x');
  await viewer.keyboard.press('m');
  await viewer.locator('input[name=mode][value=dvr]').click({force: true}).catch(() => {});
  assert.ok(await viewer.locator('#toast').isVisible(), 'the viewer is told it only views');
  assert.match(await viewer.textContent('#toast'), /^View only: .+ drives this view\.$/);
  await shot('05-viewer-read-only', viewer);
  await viewer.waitForTimeout(1500);
  assert.equal(await version(owner), ownerVersion, 'the owner\'s state did not change');
  assert.equal(await version(viewer), viewerVersion);
  assert.ok(sameCamera(await camera(viewer), cam), 'the viewer\'s camera did not move');
  const after = await h.frameOf(owner, '3d');
  assert.equal(after.frameId, ownerFinal.frameId, 'the owner got no new frame');
  assert.equal(await h.differenceFrom(owner, '3d', 'owner-before-viewer-drag'), 0);
  // Past the page's own read-only controls, the server refuses a viewer's state change.
  const refusal = await oct(viewer, () => new Promise((resolve) => {
    const share = new URL(location.href).searchParams.get('share');
    const ws = new WebSocket(new URL(`ws?share=${share}`, location.href).toString().replace(/^http/, 'ws'));
    ws.onopen = () => {
      ws.send(JSON.stringify({type: 'hello', client: 'test', protocol: 1}));
      ws.send(JSON.stringify({type: 'slices', position_um: [1, 1, 1]}));
    };
    ws.onmessage = (e) => {
      if (typeof e.data !== 'string') return;
      const m = JSON.parse(e.data);
      if (m.type === 'error') {
        ws.close();
        resolve(m);
      }
    };
    setTimeout(() => resolve(null), 10000);
  }));
  assert.equal(refusal?.request, 'slices');
  assert.match(refusal.message, /viewers cannot drive the view/);
  assert.equal(await version(owner), ownerVersion, 'the owner\'s state still did not change');
});

test('promoted to controller, the former viewer drives the owner\'s view', async () => {
  const {owner, viewer} = pages;
  await owner.click('#session-panel .participant[data-role="viewer"] button.promote');
  await h.waitFor(async () => (await role(viewer)) === 'controller', 'the controller role');
  assert.ok(await viewer.locator('#follow-banner').isHidden(), 'no banner for a controller');
  assert.ok(await viewer.locator('input[name=mode][value=dvr]').isEnabled(), 'the controls are enabled');
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.participants)).some((p) => p.role === 'controller'),
      'the owner sees the controller');
  assert.equal(await owner.locator('#session-panel .participant[data-role="controller"] button.demote').count(), 1);
  const base = await h.waitForFinal(owner, '3d', 0);
  const v0 = await version(owner);
  await h.canvasStats(owner, '3d', 'owner-before-controller-drag');
  await drag3d(viewer, -10, 6);
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.participants)).find((p) => p.driving)?.role === 'controller',
      'the controller marked driving at the owner', 5000);
  await h.waitForFinal(owner, '3d', Math.max(v0, base.stateVersion));
  assert.ok(await version(owner) > v0, 'the owner\'s state version increased');
  await expectSameCamera(owner, viewer, 'the owner follows the controller');
  const diff = await h.differenceFrom(owner, '3d', 'owner-before-controller-drag');
  assert.ok(diff > 2, `the owner's frame changed with the controller's drag (mean diff ${diff})`);
  await shot('06-controller-drove', viewer);
  await shot('07-owner-follows-controller', owner);
});

test('a view link opened in a third context reproduces the owner\'s final image exactly', async () => {
  const owner = pages.owner;
  // Lossless finals from the next state on (a final already sent is not sent again).
  await owner.check('#lossless');
  const v0 = await version(owner);
  await owner.keyboard.press('+');
  const ownerFinal = await h.waitFor(async () => {
    const f = await h.waitForFinal(owner, '3d', v0);
    return f.lossless ? f : null;
  }, 'a lossless final at the owner', 120000);
  await owner.click('#session-panel .copy-view-link');
  const link = await waitForLink(owner, 'view');
  assert.ok(/[?&]view=[A-Za-z0-9_-]{22}$/.test(link.url), `view link ${link.url}`);
  // A third person who prefers lossless finals (the preference is the browser's, kept in its
  // storage): the page asks for them before its first frame.
  const fork = await newPage('fork');
  await fork.context().addInitScript(() => localStorage.setItem('octoscope.lossless', '1'));
  await fork.goto(link.url);
  await h.waitFor(() => oct(fork, () => window.octoscope.dataset?.id), 'the view opened');
  assert.ok(await fork.isChecked('#lossless'), 'the preference is restored');
  const forkFinal = await h.waitFor(async () => {
    const f = await h.waitForFinal(fork, '3d', 0);
    return f.lossless ? f : null;
  }, 'a lossless final of the view', 120000);
  assert.equal(await role(fork), 'owner', 'a view link opens a session of one\'s own');
  assert.notEqual(await oct(fork, () => window.octoscope.session), await oct(owner, () => window.octoscope.session));
  assert.equal((await oct(fork, () => window.octoscope.participants)).length, 1);
  await expectSameCamera(fork, owner, 'the same camera');
  // The session opened with exactly the stored document (GET /api/views/ID).
  const stored = await (await fetch(`http://127.0.0.1:${server.port}/api/views/${link.id}`,
      {headers: {Authorization: `Bearer ${TOKEN}`}})).json();
  assert.equal(stored.dataset, datasetId);
  const forkState = await oct(fork, () => window.octoscope.state);
  for (const part of ['camera', 'params', 'slices']) {
    assertClose(forkState[part], stored.state[part], `opened ${part} vs the stored view`);
  }
  assert.deepEqual([forkFinal.width, forkFinal.height], [ownerFinal.width, ownerFinal.height]);
  // Pixel by pixel: both lossless PNG finals decoded without colour management.
  const a = await oct(owner, () => window.octoscope.frameImage('3d'));
  const b = await oct(fork, () => window.octoscope.frameImage('3d'));
  const cmp = await fork.evaluate(async ([x, y]) => {
    const pixels = async (img) => {
      const bytes = Uint8Array.from(atob(img.base64), (c) => c.charCodeAt(0));
      const bmp = await createImageBitmap(new Blob([bytes], {type: img.mime}),
          {premultiplyAlpha: 'none', colorSpaceConversion: 'none'});
      const ctx = new OffscreenCanvas(bmp.width, bmp.height).getContext('2d');
      ctx.drawImage(bmp, 0, 0);
      return ctx.getImageData(0, 0, bmp.width, bmp.height);
    };
    const [p, q] = [await pixels(x), await pixels(y)];
    if (p.width !== q.width || p.height !== q.height) return {size: [p.width, p.height, q.width, q.height]};
    let maxDiff = 0, lit = 0;
    for (let i = 0; i < p.data.length; ++i) {
      maxDiff = Math.max(maxDiff, Math.abs(p.data[i] - q.data[i]));
      if (i % 4 === 1 && p.data[i] > 8) ++lit;
    }
    return {maxDiff, lit: lit / (p.data.length / 4), width: p.width, height: p.height};
  }, [a, b]);
  console.log(`view link vs owner final: ${JSON.stringify(cmp)}`);
  assert.equal(a.mime, 'image/png');
  assert.ok(!cmp.size, `sizes differ: ${cmp.size}`);
  assert.ok(cmp.lit > 0.02, `the image is not blank: ${JSON.stringify(cmp)}`);
  assert.equal(cmp.maxDiff, 0, 'the view link reproduces the same final image');
  await shot('08-view-link-fork', fork);
  // The fork is independent: driving it leaves the owner's session alone.
  const v = await version(owner);
  await drag3d(fork);
  await h.waitForFinal(fork, '3d', forkFinal.stateVersion);
  assert.equal(await version(owner), v, 'the owner\'s session is untouched by the fork');
});

test('revoking the link ends its participants\' sessions with a clear message', async () => {
  const {owner, viewer} = pages;
  await owner.click('#session-panel .share-link[data-role="viewer"] button.revoke');
  await h.waitFor(async () => (await oct(viewer, () => window.octoscope.connection)) === 'ended', 'the viewer left');
  const banner = await viewer.textContent('#connection-banner');
  assert.match(banner, /revoked this share link/);
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.participants)).length === 1, 'the owner alone');
  assert.deepEqual(await oct(owner, () => window.octoscope.shares), []);
  await viewer.waitForTimeout(2000);
  assert.equal(await oct(viewer, () => window.octoscope.connection), 'ended', 'no reconnect after a revoke');
  await shot('09-viewer-revoked', viewer);
  // The dead link, opened again, says so instead of retrying forever.
  const late = await newPage('late', {}, true);
  await late.goto(viewer.url());
  await h.waitFor(async () => (await oct(late, () => window.octoscope.connection)) === 'ended', 'the dead link refused', 30000);
  assert.match(await late.textContent('#connection-banner'), /no longer works/);
  await shot('10-dead-link', late);
});

test('the owner removes a participant; the owner\'s reconnect keeps its session and links', async () => {
  const owner = pages.owner;
  await owner.selectOption('#session-panel .share-ttl', '3600');
  await owner.click('#session-panel .share-controller');
  const link = await waitForLink(owner, 'controller');
  const shares = await h.waitFor(async () => {
    const s = await oct(owner, () => window.octoscope.shares);
    return s.length === 1 ? s : null;
  }, 'the controller link listed');
  assert.ok(shares[0].expires, 'the link expires');
  assert.match(await owner.textContent('#session-panel .share-link .info'), /^expires in (59 min|1 h) · 0 joined$/);
  const guest = await newPage('guest', {viewport: {width: 420, height: 860}, hasTouch: true, isMobile: true});
  await guest.goto(link.url);
  await h.waitFor(async () => (await role(guest)) === 'controller', 'the guest joined as controller');
  await h.waitForFinal(guest, '3d', 0);
  await guest.locator('#session-panel').scrollIntoViewIfNeeded();
  await shot('11-guest-phone', guest);
  await owner.click('#session-panel .participant[data-role="controller"] button.kick');
  await h.waitFor(async () => (await oct(guest, () => window.octoscope.connection)) === 'ended', 'the guest removed');
  assert.match(await guest.textContent('#connection-banner'), /removed you/);
  await shot('12-guest-removed', guest);

  const session = await oct(owner, () => window.octoscope.session);
  await oct(owner, () => window.octoscope.dropConnection());
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.connection)) !== 'open', 'the owner dropped');
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.connection)) === 'open', 'the owner reconnected', 30000);
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.session)) === session, 'the same session', 10000);
  assert.equal(await role(owner), 'owner');
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.shares)).length === 1, 'the link still listed');
  await h.waitForFinal(owner, '3d', 0);
  await shot('13-owner-reconnected', owner);
});

test('the address bar never shows the user token; the owner lists, expires and deletes view links', async () => {
  const owner = pages.owner;
  // The token left the address bar at once: copying the address hands nobody the token.
  assert.equal(new URL(owner.url()).searchParams.get('token'), null, `address: ${owner.url()}`);
  assert.equal(new URL(owner.url()).searchParams.get('dataset'), datasetId);
  // A reload still works (this tab kept the token) and comes back to the same session.
  const session = await oct(owner, () => window.octoscope.session);
  await owner.reload();
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.session)) === session, 'the same session after a reload', 30000);
  assert.equal(new URL(owner.url()).searchParams.get('token'), null);
  await h.waitForFinal(owner, '3d', 0);
  // The view link of the fork's test is listed; a new one expiring in a day joins it.
  const first = await h.waitFor(async () => {
    const list = await oct(owner, () => window.octoscope.viewLinks);
    return list.length === 1 ? list[0] : null;
  }, 'the earlier view link listed');
  assert.equal(first.valid, true);
  await owner.selectOption('#session-panel .view-ttl', '86400');
  await owner.click('#session-panel .copy-view-link');
  const link = await waitForLink(owner, 'view');
  assert.ok(link.expires, 'the new view link expires');
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.viewLinks)).length === 2, 'two view links listed');
  const fresh = owner.locator(`#session-panel .view-link[data-id="${link.id}"] .info`);
  assert.match(await fresh.textContent(), /^embryo\.ome\.tif · made just now · expires in 24 h$/);
  await owner.locator('#session-panel .view-links').scrollIntoViewIfNeeded();
  await shot('14-view-links', owner);
  // Deleting the earlier one ends the session opened through it (the fork), with a clear message.
  const fork = pages.fork;
  await owner.click(`#session-panel .view-link[data-id="${first.id}"] button.delete`);
  await h.waitFor(async () => (await oct(owner, () => window.octoscope.viewLinks)).length === 1, 'the link gone from the list');
  await h.waitFor(async () => (await oct(fork, () => window.octoscope.connection)) === 'ended', 'the fork ended', 20000);
  assert.match(await fork.textContent('#connection-banner'), /access to this session ended/);
  await shot('15-fork-ended', fork);
});

test('no console errors', () => {
  assert.deepEqual(consoleErrors, []);
});
