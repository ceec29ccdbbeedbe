// Helpers shared by the browser tests (browser_test.mjs, share_browser_test.mjs): start and stop
// the real `octoscope serve`, wait for frames, measure and compare what a page's canvases show.
// Every page helper takes the Playwright page it works on.

import {spawn} from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import {createRequire} from 'node:module';

// playwright-core from the build folder's node_modules (ctest) or the one beside this script.
export function loadPlaywright() {
  const require = createRequire(process.env.OCTOSCOPE_NODE_MODULES ?
    path.join(process.env.OCTOSCOPE_NODE_MODULES, '..', 'index.js') : import.meta.url);
  return require('playwright-core');
}

// Starts `octoscope serve ARGS` and resolves once it printed its URL (first stdout line):
// {proc, url, port, stderr}. Its stderr is appended to `logFile`.
export function startServer(binary, args, logFile, env = {}) {
  const proc = spawn(binary, ['serve', ...args], {stdio: ['ignore', 'pipe', 'pipe'], env: {...process.env, ...env}});
  let stderr = '';
  proc.stderr.on('data', (d) => {
    stderr += d;
    fs.appendFileSync(logFile, d);
  });
  return new Promise((resolve, reject) => {
    let out = '';
    const timer = setTimeout(() => reject(new Error(`serve printed no URL in 60 s: ${stderr}`)), 60000);
    proc.stdout.on('data', (d) => {
      out += d;
      const line = out.split('\n')[0];
      if (out.includes('\n')) {
        clearTimeout(timer);
        const url = new URL(line.trim());
        resolve({proc, url: line.trim(), port: Number(url.port), get stderr() { return stderr; }});
      }
    });
    proc.on('exit', (code) => {
      clearTimeout(timer);
      reject(new Error(`serve exited with ${code}: ${stderr}`));
    });
  });
}

export function stopServer(s) {
  return new Promise((resolve) => {
    if (!s || s.proc.exitCode !== null) return resolve(s?.proc.exitCode);
    s.proc.removeAllListeners('exit');
    s.proc.on('exit', (code) => resolve(code));
    s.proc.kill('SIGTERM');
    setTimeout(() => s.proc.kill('SIGKILL'), 20000).unref();
  });
}

export async function waitFor(fn, what, timeoutMs = 60000) {
  const start = Date.now();
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() - start > timeoutMs) throw new Error(`timed out waiting for ${what}`);
    await new Promise((r) => setTimeout(r, 150));
  }
}

// Screenshots of the page and of every visible view.
export async function shot(page, dir, name) {
  await page.screenshot({path: path.join(dir, `${name}.png`)});
  for (const v of ['3d', 'x', 'y', 'z']) {
    const el = page.locator(`.view[data-view="${v}"]`);
    if (await el.isVisible()) await el.screenshot({path: path.join(dir, `${name}-view-${v}.png`)});
  }
}

export const frameOf = (page, view) => page.evaluate((v) => window.octoscope.frame(v), view);

// Waits until `view` shows a final frame newer than `afterVersion` (and `afterFrame`) and nothing
// newer arrived for `quietMs`. Returns its header.
export async function waitForFinal(page, view, afterVersion = 0, timeoutMs = 90000, quietMs = 700, afterFrame = 0) {
  const start = Date.now();
  let last = null, since = 0;
  while (Date.now() - start < timeoutMs) {
    const f = await frameOf(page, view);
    const key = f ? `${f.frameId}` : '';
    if (key !== last) {
      last = key;
      since = Date.now();
    }
    if (f && f.tier === 'final' && f.stateVersion > afterVersion && f.frameId > afterFrame &&
        Date.now() - since >= quietMs) {
      return f;
    }
    await page.waitForTimeout(100);
  }
  throw new Error(`no settled final frame of view ${view} after state ${afterVersion}: last ${JSON.stringify(await frameOf(page, view))}`);
}

// Canvas statistics computed in the page: mean luminance, fraction of non-black pixels; a
// snapshot kept under a name for later comparison.
export async function canvasStats(page, view, snapshot) {
  return page.evaluate(([v, name]) => {
    const c = document.querySelector(`.view[data-view="${v}"] canvas.image`);
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0, lit = 0;
    for (let i = 0; i < d.length; i += 4) {
      const l = 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2];
      sum += l;
      if (l > 8) ++lit;
    }
    if (name) (window.__snaps ??= {})[name] = {w: c.width, h: c.height, data: d};
    const n = d.length / 4;
    return {mean: sum / n, lit: lit / n, width: c.width, height: c.height};
  }, [view, snapshot ?? null]);
}

// Mean absolute difference (0..255) between a snapshot and the canvas now.
export async function differenceFrom(page, view, snapshot) {
  return page.evaluate(([v, name]) => {
    const c = document.querySelector(`.view[data-view="${v}"] canvas.image`);
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    const s = window.__snaps[name];
    if (s.w !== c.width || s.h !== c.height) return 255;
    let diff = 0;
    for (let i = 0; i < d.length; i += 4) {
      diff += Math.abs(d[i] - s.data[i]) + Math.abs(d[i + 1] - s.data[i + 1]) + Math.abs(d[i + 2] - s.data[i + 2]);
    }
    return diff / (d.length / 4 * 3);
  }, [view, snapshot]);
}
