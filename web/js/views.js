// Views: the 3-D view and the three slice views (Fig. 1 of the paper). Each view is a frame
// coloured by its axis with an image canvas (the server's frames, drawn at the canvas's physical
// size: CSS size × devicePixelRatio), an overlay canvas (plane outlines, crosshairs, scale bar),
// a quality badge, and enlarge/restore. Sizes go to the server as `viewport` messages in CSS
// pixels + dpr; a hidden view (another one enlarged) gets 0 × 0 so it is not rendered.

export const VIEW_IDS = ['3d', 'x', 'y', 'z'];
export const AXIS_COLORS = {x: '#ff5a4e', y: '#4fd16a', z: '#4f9dff'};

export class View {
  constructor(id, element, handlers) {
    this.id = id;
    this.el = element;
    this.image = element.querySelector('canvas.image');
    this.overlay = element.querySelector('canvas.overlay');
    this.badge = element.querySelector('.badge');
    this.handlers = handlers;
    this.cssWidth = 0;
    this.cssHeight = 0;
    this.dpr = 1;
    this.shownVersion = 0;  // State version of the frame on screen.
    this.shownFrameId = 0;
    this.lastFrame = null;  // Header of the frame on screen.
    this.bitmap = null;
    this.sentViewport = '';
    this.decoding = Promise.resolve();
    new ResizeObserver(() => this.resize()).observe(this.el.querySelector('.canvas-box'));
    element.querySelector('.enlarge')?.addEventListener('click', () => handlers.onEnlarge(id));
  }

  resize() {
    const box = this.el.querySelector('.canvas-box');
    const hidden = this.el.offsetParent === null;
    const rect = box.getBoundingClientRect();
    this.cssWidth = hidden ? 0 : Math.max(0, Math.floor(rect.width));
    this.cssHeight = hidden ? 0 : Math.max(0, Math.floor(rect.height));
    this.dpr = Math.min(4, Math.max(0.5, window.devicePixelRatio || 1));
    const pw = Math.round(this.cssWidth * this.dpr), ph = Math.round(this.cssHeight * this.dpr);
    for (const c of [this.image, this.overlay]) {
      if (c.width !== pw || c.height !== ph) {
        c.width = Math.max(1, pw);
        c.height = Math.max(1, ph);
      }
    }
    this.redrawImage();
    this.handlers.onResize(this);
  }

  // The viewport message for this view, or null when unchanged since the last one sent.
  viewportMessage(force = false) {
    const msg = {type: 'viewport', view: this.id, width: Math.min(8192, this.cssWidth),
      height: Math.min(8192, this.cssHeight), dpr: Math.round(this.dpr * 1000) / 1000};
    const key = JSON.stringify(msg);
    if (!force && key === this.sentViewport) return null;
    this.sentViewport = key;
    return msg;
  }

  // Decodes and shows a frame; resolves once it is on screen (or was dropped as stale).
  show(frame) {
    this.decoding = this.decoding.then(async () => {
      if (frame.stateVersion < this.shownVersion) return false;  // Never older over newer.
      const blob = new Blob([frame.image], {type: frame.mime});
      let bitmap;
      try {
        bitmap = await createImageBitmap(blob);
      } catch (e) {
        console.warn(`octoscope: frame ${frame.frameId} of view ${this.id} does not decode`);
        return false;
      }
      if (frame.stateVersion < this.shownVersion) {
        bitmap.close?.();
        return false;
      }
      this.bitmap?.close?.();
      this.bitmap = bitmap;
      this.shownVersion = frame.stateVersion;
      this.shownFrameId = frame.frameId;
      this.lastFrame = frame;
      this.redrawImage();
      this.updateBadge(frame);
      this.el.dataset.tier = frame.tier;
      this.el.dataset.frames = String((Number(this.el.dataset.frames) || 0) + 1);
      return true;
    });
    return this.decoding;
  }

  redrawImage() {
    const ctx = this.image.getContext('2d');
    ctx.fillStyle = '#000';
    ctx.fillRect(0, 0, this.image.width, this.image.height);
    if (!this.bitmap) return;
    // Interactive frames come at a reduced size: scale them up to the canvas, smoothly.
    ctx.imageSmoothingEnabled = true;
    ctx.imageSmoothingQuality = 'high';
    ctx.drawImage(this.bitmap, 0, 0, this.image.width, this.image.height);
  }

  updateBadge(frame) {
    if (!this.badge) return;
    let text, cls;
    if (frame.tier === 'final' || frame.final) {
      text = frame.lossless ? 'final · lossless' : 'final';
      cls = 'final';
    } else if (frame.tier === 'refining') {
      text = `refining ${Math.round(frame.progress * 100)} %`;
      cls = 'refining';
    } else {
      const scale = this.image.width ? frame.width / this.image.width : 1;
      text = scale < 0.99 ? `interactive · ${Math.round(scale * 100)} %` : 'interactive';
      cls = 'interactive';
    }
    this.badge.textContent = text;
    this.badge.className = `badge ${cls}`;
    this.badge.title = `frame ${frame.frameId}, state ${frame.stateVersion}, ` +
        `${frame.width}×${frame.height}, render ${frame.renderMs.toFixed(1)} ms, ` +
        `encode ${frame.encodeMs.toFixed(1)} ms, LOD bias ${frame.lodBias.toFixed(2)}`;
  }

  clear() {
    this.bitmap?.close?.();
    this.bitmap = null;
    this.shownVersion = 0;
    this.lastFrame = null;
    this.redrawImage();
    if (this.badge) {
      this.badge.textContent = '';
      this.badge.className = 'badge';
    }
  }

  // The overlay's 2-D context scaled so drawing is in CSS pixels.
  overlayContext() {
    const ctx = this.overlay.getContext('2d');
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.clearRect(0, 0, this.overlay.width, this.overlay.height);
    ctx.setTransform(this.overlay.width / Math.max(1, this.cssWidth), 0, 0,
        this.overlay.height / Math.max(1, this.cssHeight), 0, 0);
    return ctx;
  }
}

// The layout: which view (if any) is enlarged. Other views are hidden (display: none).
export class Layout {
  constructor(grid, views, onChange) {
    this.grid = grid;
    this.views = views;
    this.onChange = onChange;
    this.maximized = null;
  }

  set(maximized) {
    this.maximized = VIEW_IDS.includes(maximized) ? maximized : null;
    this.grid.dataset.maximized = this.maximized ?? '';
    for (const v of Object.values(this.views)) {
      v.el.classList.toggle('maximized', v.id === this.maximized);
      v.el.classList.toggle('hidden', this.maximized !== null && v.id !== this.maximized);
      const b = v.el.querySelector('.enlarge');
      if (b) {
        b.textContent = v.id === this.maximized ? '⤡' : '⤢';
        b.title = v.id === this.maximized ? 'Restore (Esc)' : 'Enlarge';
      }
    }
    for (const v of Object.values(this.views)) v.resize();
    this.onChange(this.maximized);
  }

  toggle(id) {
    this.set(this.maximized === id ? null : id);
  }
}
