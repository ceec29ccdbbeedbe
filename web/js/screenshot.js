// Screenshot: asks the server to render a view's current state to completion at 1× or 2× its
// size (tier `screenshot`, a PNG of the final-quality pixels), optionally draws the scale bar on
// it, and saves it as a PNG file.

import {drawScaleBar} from './scale_bar.js';

export class Screenshots {
  constructor(send) {
    this.send = send;
    this.nextId = 1;
    this.pending = new Map();  // id → {resolve, reject, timer}
  }

  // Resolves with the PNG frame (header + image bytes) of a new screenshot of `view`.
  request(view, scale, timeoutMs = 120000) {
    const id = this.nextId++;
    return new Promise((resolve, reject) => {
      if (!this.send({type: 'screenshot', view, scale, id})) {
        reject(new Error('not connected'));
        return;
      }
      const timer = setTimeout(() => {
        this.pending.delete(id);
        reject(new Error('the screenshot did not arrive in time'));
      }, timeoutMs);
      this.pending.set(id, {resolve, reject, timer});
    });
  }

  // A frame of tier `screenshot`: completes its request. True when it was one of ours.
  offer(frame) {
    const p = this.pending.get(frame.screenshotId);
    if (!p) return false;
    clearTimeout(p.timer);
    this.pending.delete(frame.screenshotId);
    p.resolve(frame);
    return true;
  }

  failAll(reason) {
    for (const [, p] of this.pending) {
      clearTimeout(p.timer);
      p.reject(new Error(reason));
    }
    this.pending.clear();
  }
}

// The PNG to save: the server's bytes as they are, or redrawn with a scale bar
// (`umPerPixel` of the screenshot's pixels).
export async function screenshotBlob(frame, scaleBarUmPerPixel) {
  const png = new Blob([frame.image], {type: 'image/png'});
  if (!scaleBarUmPerPixel) return png;
  const bitmap = await createImageBitmap(png);
  const canvas = document.createElement('canvas');
  canvas.width = bitmap.width;
  canvas.height = bitmap.height;
  const ctx = canvas.getContext('2d');
  ctx.drawImage(bitmap, 0, 0);
  drawScaleBar(ctx, scaleBarUmPerPixel, canvas.width, canvas.height, Math.max(1, canvas.width / 800));
  return new Promise((resolve) => canvas.toBlob(resolve, 'image/png'));
}

export function saveBlob(blob, filename) {
  const a = document.createElement('a');
  a.href = URL.createObjectURL(blob);
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10000);
}
