// The Octoscope viewer page: wires the connection, the four views, the controls and panels
// together and owns the client's copy of the session state (camera, parameters, slices,
// layout), which it sends in full with `open` after a reconnect so the view comes back as it was.
// In a shared session it follows the state the others drive (`state` events update every panel)
// and, as a viewer, keeps every driving control read-only.

import {apiUrl, credentialParams, linkUrl, readUrlState, webSocketUrl, withDataset, withoutToken} from './url_state.js';
import {Connection} from './connection.js';
import {cleanName, Participants} from './participants.js';
import {SharePanel} from './share_panel.js';
import {AXIS_COLORS, Layout, View, VIEW_IDS} from './views.js';
import {CameraControls} from './camera_controls.js';
import {SliceControls} from './slice_controls.js';
import {fitCamera, fromCameraDocument, orbit, planeOutline, toCameraDocument, umPerPixel,
  volumeExtent, zoom} from './camera_math.js';
import {SLICE_AXES, sliceUmPerPixel, sliceUmToPixel, stepSlice} from './slice_geometry.js';
import {drawScaleBar, formatLength} from './scale_bar.js';
import {ChannelsPanel} from './channels_panel.js';
import {RenderPanel} from './render_panel.js';
import {DatasetPicker} from './dataset_picker.js';
import {Status} from './status.js';
import {saveBlob, screenshotBlob, Screenshots} from './screenshot.js';
import {actionFor, drivesView, fillHelp} from './shortcuts.js';

const MODES = ['dvr', 'mip', 'minip'];
const HISTOGRAM_REFRESH_MS = 2000;
const VIEW_ONLY_HINT_MS = 4000;
const RESUME_KEY = 'octoscope.resume';
const TOKEN_KEY = 'octoscope.token';
const NAME_KEY = 'octoscope.name';
const LOSSLESS_KEY = 'octoscope.lossless';

class App {
  constructor() {
    const url = readUrlState(location.href);
    // The user token leaves the address bar at once (a copied address must never hand it on);
    // this tab keeps it for reloads.
    if (url.token) {
      writeStorage(TOKEN_KEY, url.token, () => sessionStorage);
      history.replaceState(history.state, '', withoutToken(location.href));
    } else {
      url.token = readStorage(TOKEN_KEY, () => sessionStorage);
    }
    this.url = url;
    this.token = url.token;
    // A share link joins someone else's session: its dataset is theirs, not the address's.
    this.datasetId = url.mode === 'user' ? url.dataset : '';
    this.participants = new Participants();
    // A page that opens its own session owns it; a share link's role comes with `welcome`.
    if (url.mode !== 'share') this.participants.setOwnRole('owner');
    this.resume = this.loadResume();
    this.reconnecting = false;
    this.lastHint = 0;
    this.dataset = null;
    this.histogram = null;
    this.state = null;  // {camera, params, slices: {position_um}, layout}
    this.cam = null;    // Orbit camera of the 3-D view.
    this.version = 0;
    // Lossless finals are this browser's preference: on from the first frame of every page.
    this.quality = {lod_bias: 0, lossless_final: readStorage(LOSSLESS_KEY) === '1'};
    document.querySelector('#lossless').checked = this.quality.lossless_final;
    this.pending = {};  // Messages waiting for the next animation frame, by type.
    this.interactions = new Set();
    this.hovered = null;
    this.lastHistogramFetch = 0;
    this.serverErrors = [];  // The server's `error` events (tests, console).

    this.status = new Status(document);
    this.views = {};
    for (const id of VIEW_IDS) {
      this.views[id] = new View(id, document.querySelector(`.view[data-view="${id}"]`), {
        onEnlarge: (v) => this.layout.toggle(v),
        onResize: (v) => this.viewResized(v),
      });
      this.views[id].el.addEventListener('pointerenter', () => {
        this.hovered = id;
      });
    }
    this.layout = new Layout(document.querySelector('#views'), this.views, (m) => {
      if (this.state) this.state.layout = {maximized: m};
      this.drawOverlays();
    });
    new CameraControls(this.views['3d'].el.querySelector('.canvas-box'), () => this.cam,
        (cam) => this.setCamera(cam), (a) => this.interaction('3d', a));
    for (const id of ['x', 'y', 'z']) {
      new SliceControls(this.views[id], {
        getGeometry: () => this.dataset && this.state ? {extent: this.extent(),
          spacing: this.dataset.spacing, positions: this.state.slices.position_um} : null,
        onPositions: (p) => this.setSlices(p),
        onInteraction: (a) => this.interaction(`slice-${id}`, a),
      });
      const slider = this.views[id].el.querySelector('.slice-slider');
      slider.addEventListener('input', () => {
        if (!this.state) return;
        const p = this.state.slices.position_um.slice();
        p[SLICE_AXES[id].axis] = Number(slider.value);
        this.interaction(`slider-${id}`, true);
        this.setSlices(p);
      });
      slider.addEventListener('change', () => this.interaction(`slider-${id}`, false));
    }
    this.channels = new ChannelsPanel(document.querySelector('#channels'),
        (i, doc, interactive) => this.changeChannel(i, doc, interactive));
    this.channels.onNotice = (text) => this.status.error(text);
    this.renderPanel = new RenderPanel(document.querySelector('#render-panel'), {
      onMode: (m) => this.changeParams({mode: m}),
      onProjection: (p) => this.setProjection(p),
      onLodBias: (b, interactive) => {
        this.quality.lod_bias = b;
        // The bias is this page's own (`quality`); only a driver's slide marks an interaction.
        if (this.canDrive) this.interaction('lod', interactive);
        this.queue({type: 'quality', lod_bias: b});
      },
      onLossless: (on) => {
        this.quality.lossless_final = on;
        writeStorage(LOSSLESS_KEY, on ? '1' : '');
        this.connection.send({type: 'quality', lossless_final: on});
      },
      onClipPlanes: (docs, interactive) => {
        this.interaction('clip', interactive);
        this.changeParams({clip_planes: docs});
      },
    });
    this.picker = new DatasetPicker(document.querySelector('#picker'), () => this.fetchJson('api/datasets'),
        (id) => this.openDataset(id));
    this.screenshots = new Screenshots((m) => this.connection.send(m));
    // A signed-in user lists and deletes the view links they own (GET/DELETE api/views).
    const user = url.mode === 'user' && this.token;
    this.sharePanel = new SharePanel(document.querySelector('#session-panel'), {
      send: (m) => this.connection.send(m),
      fallbackUrl: (kind, secret) => linkUrl(location.href, kind, secret),
      storedName: () => this.displayName(),
      onName: (name) => this.setDisplayName(name),
      listViews: user ? () => this.fetchJson('api/views') : null,
      deleteView: user ? async (id) => (await this.request(`api/views/${id}`, 'DELETE')).ok : null,
    });
    this.bindToolbar();
    this.applyRole();
    this.connection = new Connection(webSocketUrl(location.href, credentialParams(url)), {
      onOpen: (re) => this.connected(re),
      helloFields: () => this.helloFields(),
      probe: () => this.probeCredential(),
      onEvent: (m) => this.event(m),
      onFrame: (f) => this.frame(f),
      onStatus: (s) => {
        this.status.connection(s);
        if (s.state === 'ended') {
          // Left the session for good (revoked, removed): nothing here drives or lists anyone.
          this.participants.update([]);
          this.participants.setOwnRole(null);
          this.sharePanel.setShares([]);
          this.applyRole();
        }
        if (s.state !== 'open') {
          this.screenshots.failAll('the connection was lost');
          for (const id of ['3d', 'x', 'y', 'z']) this.views[id].shownVersion = 0;
        }
      },
      onPong: (rtt) => this.status.pong(rtt),
    });
    if (url.mode === 'user' && !this.token) {
      this.status.error('This page needs the access token: open the URL that `octoscope serve` printed.');
    }
    this.connection.connect();
  }

  extent() {
    return volumeExtent(this.dataset);
  }

  // A user's token goes in a header (kept out of server logs); a share or view link's credential
  // is the query parameter the server knows it by.
  request(path, method = 'GET') {
    const user = this.url.mode === 'user';
    return fetch(apiUrl(location.href, path, user ? {} : credentialParams(this.url)), {
      method,
      headers: user && this.token ? {Authorization: `Bearer ${this.token}`} : {},
      cache: 'no-store',
    });
  }

  async fetchJson(path) {
    const r = await this.request(path);
    const body = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(body.error || `HTTP ${r.status}`);
    return body;
  }

  // Asked before each reconnect: null while the server is away or accepts this page's
  // credential; a sentence when it refuses it (a revoked or expired link, an expired token).
  async probeCredential() {
    const r = await this.request('api/datasets');
    if (r.status !== 401) return null;
    const body = await r.json().catch(() => ({}));
    if (this.url.mode === 'share') return 'This share link no longer works: the owner revoked it, or it expired.';
    if (this.url.mode === 'view') return 'This view link is not known to the server.';
    if (body.error === 'token expired') return 'Your access token has expired: ask the administrator for a new one.';
    return 'The server refused the access token: open the URL that `octoscope serve` printed.';
  }

  // `hello`'s optional fields: the name others see, and the owner's resume key (only a user
  // token may reattach; a view link's page forks the link again and restores its own state).
  helloFields() {
    const f = {};
    this.sentResume = this.url.mode === 'user' && this.token ? this.resume : '';
    if (this.sentResume) f.resume = this.sentResume;
    const name = this.displayName();
    if (name) f.name = name;
    return f;
  }

  displayName() {
    return cleanName(readStorage(NAME_KEY));
  }

  setDisplayName(name) {
    writeStorage(NAME_KEY, cleanName(name));
  }

  // The resume key kept by this tab: used when the page was reloaded (the same session comes
  // back); a page opened afresh, even at the same address, starts a session of its own.
  loadResume() {
    if (this.url.mode !== 'user') return '';
    const nav = performance.getEntriesByType?.('navigation')?.[0];
    if (nav?.type !== 'reload') {
      writeStorage(RESUME_KEY, '', () => sessionStorage);
      return '';
    }
    return readStorage(RESUME_KEY, () => sessionStorage);
  }

  // The owner's resume key (`welcome`): reattaches this tab to its session after a reconnect or a
  // reload, so its share links and participants stay.
  storeResume(key) {
    this.resume = typeof key === 'string' ? key : '';
    if (this.url.mode === 'user') writeStorage(RESUME_KEY, this.resume, () => sessionStorage);
  }

  // ---- connection ----

  connected(reconnect) {
    this.reconnecting = reconnect;
    // A view link's page forks the link again (its `opened` may come before `welcome`): put back
    // what this page had changed since.
    if (this.url.mode === 'view') this.restoreAfterOpen = reconnect && this.state ? this.stateDocument() : null;
    this.connection.send({type: 'quality', ...this.quality});
    for (const v of Object.values(this.views)) {
      v.resize();
      const m = v.viewportMessage(true);
      if (m) this.connection.send(m);
    }
  }

  // `welcome`: this page's role and session. The server itself sends `opened` to a share
  // participant (the session's dataset and state), to a view link's page (the link's state) and
  // to an owner it reattached (its `resume` key was accepted); any other page opens its dataset.
  welcome(msg) {
    this.session = msg.session;
    this.participantId = msg.participant;
    if (msg.role) this.participants.setOwnRole(msg.role);
    if (msg.role === 'owner' && typeof msg.resume === 'string') this.storeResume(msg.resume);
    const resumed = Boolean(this.sentResume) && msg.resume === this.sentResume;
    this.sentResume = '';
    this.applyRole();
    if (this.url.mode !== 'user' || resumed) return;
    this.sendOpen(this.reconnecting);
  }

  stateDocument() {
    this.flushPending();
    return {camera: toCameraDocument(this.cam, this.extent()), params: this.state.params,
      slices: {position_um: this.state.slices.position_um}, layout: {maximized: this.layout.maximized}};
  }

  sendOpen(reconnect) {
    if (this.datasetId) {
      const msg = {type: 'open', dataset: this.datasetId};
      // After a reconnect the view comes back exactly as it was.
      if (reconnect && this.state && this.dataset?.id === this.datasetId) msg.state = this.stateDocument();
      this.connection.send(msg);
    } else {
      this.picker.open();
    }
  }

  event(msg) {
    switch (msg.type) {
      case 'welcome':
        this.welcome(msg);
        break;
      case 'participants':
        this.participants.update(msg.participants);
        this.applyRole();
        break;
      case 'role':
        this.participants.setOwnRole(msg.role);
        this.applyRole();
        break;
      case 'shares':
        this.sharePanel.setShares(msg.shares);
        break;
      case 'share_created':
        this.sharePanel.showLink(msg.role, msg.url || linkUrl(location.href, 'share', msg.token));
        window.octoscope.lastLink = {kind: msg.role, url: msg.url, token: msg.token};
        break;
      case 'view_saved':
        this.sharePanel.showLink('view', msg.url || linkUrl(location.href, 'view', msg.id));
        window.octoscope.lastLink = {kind: 'view', url: msg.url, id: msg.id, expires: msg.expires};
        this.sharePanel.refreshViewLinks();
        break;
      case 'opened':
        this.opened(msg);
        break;
      case 'state':
        this.serverState(msg.state, msg.version);
        break;
      case 'dataset': {
        // The event carries the dataset's JSON, either as "dataset" or at its top level.
        const d = msg.dataset && typeof msg.dataset === 'object' ? msg.dataset : msg;
        if (this.dataset && d.id === this.dataset.id) {
          const grew = d.planes_inserted !== this.dataset.planes_inserted || d.state !== this.dataset.state;
          this.dataset = {...this.dataset, ...d};
          this.status.dataset(this.dataset);
          if (grew) this.refreshHistogram(false);
        }
        break;
      }
      case 'stats':
        this.status.serverStats(msg);
        break;
      case 'error':
        console.warn(`octoscope server: ${msg.request ? msg.request + ': ' : ''}${msg.message}`);
        this.serverErrors.push(msg);
        // A resume key the server no longer knows (it restarted, the session was released): the
        // page simply opens a new session, nothing for the user to act on.
        if (msg.request === 'hello' && /resume/i.test(msg.message)) {
          this.storeResume('');
          break;
        }
        // A fatal error closes the connection: the banner says why (closeOutcome).
        if (msg.fatal === true) break;
        // A link that could not be made says so where it was asked for.
        if (msg.request === 'view_save' || msg.request === 'share_create') this.sharePanel.showNote(msg.message);
        this.status.error(`${msg.request ? msg.request + ': ' : ''}${msg.message}`);
        break;
      default:
        break;
    }
  }

  opened(msg) {
    const first = !this.dataset || this.dataset.id !== msg.dataset.id;
    this.dataset = msg.dataset;
    this.datasetId = msg.dataset.id;
    document.title = `${msg.dataset.name} — Octoscope`;
    document.querySelector('#dataset-name').textContent = msg.dataset.name;
    this.status.dataset(this.dataset);
    this.renderPanel.setExtent(this.extent());
    for (const id of ['x', 'y', 'z']) {
      const slider = this.views[id].el.querySelector('.slice-slider');
      slider.min = 0;
      slider.max = this.extent()[SLICE_AXES[id].axis];
      slider.step = 'any';
    }
    if (first) for (const v of Object.values(this.views)) v.clear();
    this.serverState(msg.state, msg.version, true);
    this.refreshHistogram(true);
    // A reattached session may show another dataset than the address named.
    if (this.url.mode === 'user' && readUrlState(location.href).dataset !== this.datasetId) {
      history.replaceState(null, '', withDataset(location.href, this.datasetId));
    }
    const restore = this.restoreAfterOpen;
    this.restoreAfterOpen = null;
    if (restore && this.canDrive) {
      this.connection.send({type: 'camera', camera: restore.camera});
      this.connection.send({type: 'params', params: restore.params});
      this.connection.send({type: 'slices', position_um: restore.slices.position_um});
      this.serverState({...this.state, ...restore}, this.version, true);
    }
  }

  // The session's state from the server: after `open`/join (full) or when someone else changed
  // it (a `state` event): every panel follows, except the layout, which each participant keeps.
  serverState(state, version, full = false) {
    this.version = version;
    const rebuild = full || !this.state;
    if (!full && this.state?.layout) state = {...state, layout: this.state.layout};
    this.state = state;
    if (!this.interactions.has('3d')) this.cam = fromCameraDocument(state.camera, this.extent());
    this.renderPanel.setMode(state.params.mode);
    this.renderPanel.setProjection(this.cam.projection);
    this.renderPanel.setClipPlanes(state.params.clip_planes);
    if (rebuild) {
      this.channels.setDataset(this.dataset, this.histogram, state.params);
    } else {
      this.channels.update(state.params);
    }
    const m = state.layout?.maximized ?? null;
    if (full && m !== this.layout.maximized) this.layout.set(m);
    this.updateSliceSliders();
    this.drawOverlays();
  }

  // Fetches the histogram now (force) or at most every HISTOGRAM_REFRESH_MS while the data
  // grows, the last growth always followed by one fetch (trailing edge).
  async refreshHistogram(force) {
    const now = performance.now();
    if (!force && now - this.lastHistogramFetch < HISTOGRAM_REFRESH_MS) {
      if (!this.histogramTimer) {
        this.histogramTimer = setTimeout(() => {
          this.histogramTimer = null;
          this.refreshHistogram(true);
        }, HISTOGRAM_REFRESH_MS - (now - this.lastHistogramFetch));
      }
      return;
    }
    clearTimeout(this.histogramTimer);
    this.histogramTimer = null;
    this.lastHistogramFetch = now;
    const id = this.datasetId;
    try {
      const h = await this.fetchJson(`api/datasets/${id}/histogram`);
      if (id !== this.datasetId) return;
      this.histogram = h;
      this.channels.setHistogram(h);
    } catch (e) {
      console.warn(`octoscope: histogram of ${id}: ${e.message}`);
    }
  }

  frame(frame) {
    const ack = () => this.connection.send({type: 'ack', frame: frame.frameId});
    this.status.frame(frame);
    if (frame.tier === 'screenshot') {
      this.screenshots.offer(frame);
      ack();
      return;
    }
    this.views[frame.view].show(frame).then((shown) => {
      ack();
      if (shown && frame.view === '3d') this.drawOverlays();
    });
  }

  // ---- state changes ----

  // Coalesces messages of one type (and view) into one per animation frame.
  queue(msg, key = msg.type) {
    this.pending[key] = msg;
    if (!this.raf) this.raf = requestAnimationFrame(() => this.flushPending());
  }

  flushPending() {
    cancelAnimationFrame(this.raf);
    this.raf = null;
    const pending = this.pending;
    this.pending = {};
    for (const msg of Object.values(pending)) this.connection.send(msg);
  }

  get canDrive() {
    return this.participants.canDrive;
  }

  // A viewer tried to drive: say so, at most every few seconds.
  viewOnlyHint() {
    const now = performance.now();
    if (now - this.lastHint < VIEW_ONLY_HINT_MS) return;
    this.lastHint = now;
    const f = this.participants.followed;
    this.status.notice(f && !f.you ? `View only: ${f.name} drives this view.` : 'View only.');
  }

  // Driving controls are read-only (disabled, marked) unless this page may drive; a viewer sees
  // whom it follows.
  applyRole() {
    const drive = this.canDrive;
    const role = this.participants.role;
    document.body.dataset.role = role ?? 'none';
    document.body.classList.toggle('read-only', !drive);
    for (const el of document.querySelectorAll('.drives')) el.disabled = !drive;
    // A share participant never opens another dataset; nor does a viewer.
    document.querySelector('#open-dataset').disabled = !drive || this.url.mode === 'share';
    for (const id of ['x', 'y', 'z']) this.views[id].el.querySelector('.slice-slider').disabled = !drive;
    for (const v of Object.values(this.views)) {
      const box = v.el.querySelector('.canvas-box');
      if (drive) box.removeAttribute('aria-disabled'); else box.setAttribute('aria-disabled', 'true');
      box.title = drive ? '' : 'View only';
    }
    if (!drive) {
      // Demoted mid-gesture: what was queued is no longer ours to send.
      this.interactions.clear();
      for (const k of Object.keys(this.pending)) if (!k.startsWith('viewport') && k !== 'quality') delete this.pending[k];
    }
    const banner = document.querySelector('#follow-banner');
    const text = this.participants.bannerText();
    banner.textContent = text;
    banner.hidden = !text;
    const n = this.participants.list.length;
    document.querySelector('#share-button .participant-count').textContent = n > 1 ? ` · ${n}` : '';
    document.querySelector('#session-panel .copy-view-link').disabled = role === null;
    this.sharePanel.setParticipants(this.participants);
  }

  interaction(source, active) {
    if (!this.canDrive) {
      if (active) this.viewOnlyHint();
      return;
    }
    const before = this.interactions.size > 0;
    if (active) this.interactions.add(source); else this.interactions.delete(source);
    const after = this.interactions.size > 0;
    if (before !== after) {
      this.flushPending();
      this.connection.send({type: 'interaction', active: after});
    }
  }

  setCamera(cam) {
    if (!this.state || !this.canDrive) return;
    this.cam = cam;
    this.state.camera = toCameraDocument(cam, this.extent());
    this.queue({type: 'camera', camera: this.state.camera});
    this.drawOverlays();
  }

  setProjection(p) {
    if (!this.cam || this.cam.projection === p) return;
    const t = Math.tan(this.cam.fov * Math.PI / 360);
    // Keep the framing at the pivot: ortho height = what the perspective camera sees there.
    this.setCamera(p === 'perspective' ? {...this.cam, projection: p, distance: this.cam.orthoHeight / (2 * t)} :
      {...this.cam, projection: p, orthoHeight: 2 * this.cam.distance * t});
  }

  preset(name) {
    if (!this.state) return;
    const v = this.views['3d'];
    const aspect = v.cssWidth > 0 && v.cssHeight > 0 ? v.cssWidth / v.cssHeight : 1;
    this.setCamera(fitCamera(name, this.extent(), aspect, this.cam?.projection ?? 'ortho', this.cam?.fov ?? 30));
  }

  setSlices(p) {
    if (!this.state || !this.canDrive) return;
    const e = this.extent();
    this.state.slices.position_um = p.map((v, a) => Math.min(Math.max(v, 0), e[a]));
    this.queue({type: 'slices', position_um: this.state.slices.position_um});
    this.updateSliceSliders();
    this.drawOverlays();
  }

  changeParams(doc) {
    if (!this.state) return;
    if (!this.canDrive) {
      // A control that changed itself (a radio button) goes back to the session's value.
      this.renderPanel.setMode(this.state.params.mode);
      this.viewOnlyHint();
      return;
    }
    Object.assign(this.state.params, doc);
    this.channels.update(this.state.params);
    this.renderPanel.setMode(this.state.params.mode);
    this.queue({type: 'params', params: doc}, 'params-global');
    this.flushPending();
  }

  changeChannel(i, doc, interactive) {
    if (!this.state) return;
    if (!this.canDrive) {
      this.channels.update(this.state.params);
      this.viewOnlyHint();
      return;
    }
    const ch = this.state.params.channels[i];
    for (const [k, v] of Object.entries(doc)) {
      if (k === 'transform') {
        const {translate: t, scale: s} = v;
        ch.transform = [s[0], 0, 0, t[0], 0, s[1], 0, t[1], 0, 0, s[2], t[2], 0, 0, 0, 1];
      } else if (v === null) {
        delete ch[k];
      } else {
        ch[k] = v;
      }
    }
    this.channels.update(this.state.params);
    this.interaction(`channel-${i}`, interactive);
    // Partial documents: the other channels' entries are {} and keep their values.
    const key = `params-${i}`;
    const prev = this.pending[key]?.params.channels[i] ?? {};
    const channels = this.state.params.channels.map(() => ({}));
    channels[i] = {...prev, ...doc};
    this.queue({type: 'params', params: {channels}}, key);
    if (!interactive) this.flushPending();
  }

  viewResized(v) {
    const m = v.viewportMessage();
    if (m) this.queue(m, `viewport-${v.id}`);
    this.drawOverlays();
  }

  // ---- datasets ----

  openDataset(id) {
    if (!id || !this.canDrive || this.url.mode === 'share') return;
    this.datasetId = id;
    this.state = null;
    this.dataset = null;
    this.histogram = null;
    for (const v of Object.values(this.views)) v.clear();
    history.pushState(null, '', withDataset(location.href, id));
    this.connection.send({type: 'open', dataset: id});
  }

  // ---- overlays ----

  updateSliceSliders() {
    if (!this.state) return;
    for (const id of ['x', 'y', 'z']) {
      const slider = this.views[id].el.querySelector('.slice-slider');
      const a = SLICE_AXES[id].axis;
      if (document.activeElement !== slider) slider.value = this.state.slices.position_um[a];
    }
  }

  drawOverlays() {
    if (this.overlayRaf) return;
    this.overlayRaf = requestAnimationFrame(() => {
      this.overlayRaf = null;
      for (const v of Object.values(this.views)) {
        const ctx = v.overlayContext();
        if (!this.state || !this.dataset || v.cssWidth === 0) continue;
        if (v.id === '3d') this.draw3dOverlay(v, ctx); else this.drawSliceOverlay(v, ctx);
      }
    });
  }

  draw3dOverlay(v, ctx) {
    const e = this.extent();
    ctx.lineWidth = 1.5;
    for (const id of ['x', 'y', 'z']) {
      const axis = SLICE_AXES[id].axis;
      const segs = planeOutline(this.cam, e, v.cssWidth, v.cssHeight, axis, this.state.slices.position_um[axis]);
      ctx.strokeStyle = AXIS_COLORS[id];
      ctx.beginPath();
      for (const [[x0, y0], [x1, y1]] of segs) {
        ctx.moveTo(x0, y0);
        ctx.lineTo(x1, y1);
      }
      ctx.stroke();
    }
    drawScaleBar(ctx, umPerPixel(this.cam, v.cssHeight), v.cssWidth, v.cssHeight);
  }

  drawSliceOverlay(v, ctx) {
    const e = this.extent();
    const {axis, u, v: vAxis} = SLICE_AXES[v.id];
    const p = this.state.slices.position_um;
    const [cx, cy] = sliceUmToPixel(v.id, e, v.cssWidth, v.cssHeight, p[u], p[vAxis]);
    const [x0, y0] = sliceUmToPixel(v.id, e, v.cssWidth, v.cssHeight, 0, 0);
    const [x1, y1] = sliceUmToPixel(v.id, e, v.cssWidth, v.cssHeight, e[u], e[vAxis]);
    ctx.lineWidth = 1;
    ctx.setLineDash([6, 4]);
    const uName = 'xyz'[u], vName = 'xyz'[vAxis];
    ctx.strokeStyle = AXIS_COLORS[uName];  // The u-plane shows as a vertical line.
    ctx.beginPath();
    ctx.moveTo(cx, y0);
    ctx.lineTo(cx, y1);
    ctx.stroke();
    ctx.strokeStyle = AXIS_COLORS[vName];
    ctx.beginPath();
    ctx.moveTo(x0, cy);
    ctx.lineTo(x1, cy);
    ctx.stroke();
    ctx.setLineDash([]);
    const spacing = this.dataset.spacing[axis] || 1;
    const plane = Math.min(this.dataset.size[axis] - 1, Math.max(0, Math.floor(p[axis] / spacing)));
    const label = v.el.querySelector('.position');
    label.textContent = `${formatLength(Math.round(p[axis] * 100) / 100)} · ${plane + 1}/${this.dataset.size[axis]}`;
    label.title = `${'xyz'[axis]} = ${formatLength(p[axis])}, plane ${plane + 1} of ${this.dataset.size[axis]}`;
    drawScaleBar(ctx, sliceUmPerPixel(v.id, e, v.cssWidth, v.cssHeight), v.cssWidth, v.cssHeight);
  }

  // ---- toolbar, keys, dialogs ----

  bindToolbar() {
    const $ = (s) => document.querySelector(s);
    $('#open-dataset').addEventListener('click', () => this.picker.open());
    $('#share-button').addEventListener('click', () => {
      const panel = $('#session-panel');
      panel.scrollIntoView({block: 'start', behavior: 'smooth'});
      panel.focus({preventScroll: true});
    });
    $('#reset-view').addEventListener('click', () => this.preset('iso'));
    document.querySelectorAll('[data-preset]').forEach((b) =>
      b.addEventListener('click', () => this.preset(b.dataset.preset)));
    $('#auto-all').addEventListener('click', () => this.channels.autoContrastAll());
    $('#help-button').addEventListener('click', () => this.toggleHelp());
    $('#stats-button').addEventListener('click', () => this.toggleStats());
    $('#screenshot-button').addEventListener('click', () => this.openScreenshotDialog());
    $('#screenshot-dialog form').addEventListener('submit', (e) => {
      e.preventDefault();
      this.takeScreenshot();
    });
    $('#screenshot-dialog .close').addEventListener('click', () => $('#screenshot-dialog').close());
    fillHelp($('#help table'));
    $('#help').addEventListener('click', () => this.toggleHelp(false));
    document.addEventListener('keydown', (e) => this.key(e));
    window.addEventListener('popstate', () => {
      const {dataset} = readUrlState(location.href);
      if (dataset && dataset !== this.datasetId) this.openDataset(dataset);
    });
    window.addEventListener('resize', () => Object.values(this.views).forEach((v) => v.resize()));
    matchMedia(`(resolution: ${window.devicePixelRatio}dppx)`).addEventListener?.('change', () =>
      Object.values(this.views).forEach((v) => v.resize()));
  }

  toggleHelp(show) {
    const help = document.querySelector('#help');
    help.hidden = show === undefined ? !help.hidden : !show;
  }

  toggleStats() {
    const stats = document.querySelector('#stats');
    stats.hidden = !stats.hidden;
    this.status.renderStats();
  }

  key(e) {
    const action = actionFor(e);
    if (!action) return;
    const [name, arg] = action.split(':');
    if (drivesView(action) && (!this.canDrive || (name === 'picker' && this.url.mode === 'share'))) {
      this.viewOnlyHint();
      e.preventDefault();
      return;
    }
    switch (name) {
      case 'help': this.toggleHelp(); break;
      case 'picker': this.picker.open(); break;
      case 'reset': this.preset('iso'); break;
      case 'preset': this.preset(e.shiftKey ? `-${arg}` : arg); break;
      case 'mode': {
        const m = this.state?.params.mode;
        this.changeParams({mode: MODES[(MODES.indexOf(m) + 1) % MODES.length]});
        break;
      }
      case 'projection':
        if (this.cam) this.setProjection(this.cam.projection === 'ortho' ? 'perspective' : 'ortho');
        break;
      case 'auto': this.channels.autoContrastAll(); break;
      case 'channel': {
        const i = Number(e.key) - 1;
        const ch = this.state?.params.channels[i];
        if (ch) this.changeChannel(i, {enabled: ch.enabled === false}, false);
        break;
      }
      case 'enlarge': this.layout.toggle(this.hovered ?? '3d'); break;
      case 'escape':
        this.toggleHelp(false);
        if (this.layout.maximized) this.layout.set(null);
        break;
      case 'orbit': {
        if (!this.cam) break;
        const d = 5 * Math.PI / 180;
        const [yaw, pitch] = {ArrowLeft: [-d, 0], ArrowRight: [d, 0], ArrowUp: [0, -d], ArrowDown: [0, d]}[e.key];
        this.setCamera(orbit(this.cam, yaw, pitch));
        break;
      }
      case 'zoom': if (this.cam) this.setCamera(zoom(this.cam, e.key === '+' ? 1.25 : 0.8)); break;
      case 'slice': {
        const id = ['x', 'y', 'z'].includes(this.hovered) ? this.hovered : 'z';
        if (!this.state) break;
        const steps = (e.key === 'PageUp' ? 1 : -1) * (e.shiftKey ? 10 : 1);
        this.setSlices(stepSlice(id, this.state.slices.position_um, this.extent(), this.dataset.spacing, steps));
        break;
      }
      case 'screenshot': this.openScreenshotDialog(); break;
      case 'stats': this.toggleStats(); break;
      default: return;
    }
    e.preventDefault();
  }

  openScreenshotDialog() {
    const d = document.querySelector('#screenshot-dialog');
    d.querySelector('.message').textContent = '';
    if (!d.open) d.showModal();
  }

  async takeScreenshot() {
    const d = document.querySelector('#screenshot-dialog');
    const form = d.querySelector('form');
    const view = form.elements.view.value, scale = Number(form.elements.scale.value);
    const withBar = form.elements.scalebar.checked;
    const msg = d.querySelector('.message');
    msg.textContent = 'Rendering at final quality…';
    form.querySelector('button[type=submit]').disabled = true;
    try {
      const frame = await this.screenshots.request(view, scale);
      let umpp = null;
      if (withBar) {
        umpp = view === '3d' ? umPerPixel(this.cam, frame.height) :
            sliceUmPerPixel(view, this.extent(), frame.width, frame.height);
      }
      const blob = await screenshotBlob(frame, umpp);
      const name = `${(this.dataset?.name ?? 'octoscope').replace(/[^A-Za-z0-9._-]+/g, '_')}-${view}-${scale}x.png`;
      saveBlob(blob, name);
      msg.textContent = `Saved ${name} (${frame.width} × ${frame.height}).`;
      window.octoscope.lastScreenshot = {name, width: frame.width, height: frame.height, bytes: blob.size};
    } catch (e) {
      msg.textContent = `Screenshot failed: ${e.message}`;
    } finally {
      form.querySelector('button[type=submit]').disabled = false;
    }
  }
}

// Browser storage that may be disabled (privacy settings): then nothing is remembered.
function readStorage(key, storage = () => localStorage) {
  try {
    return storage().getItem(key) || '';
  } catch {
    return '';
  }
}

function writeStorage(key, value, storage = () => localStorage) {
  try {
    if (value) storage().setItem(key, value); else storage().removeItem(key);
  } catch {
    // Not remembered.
  }
}

const app = new App();
// A small read-only window onto the page for automation (the browser tests) and the console.
window.octoscope = {
  get connection() { return app.connection.state; },
  get dataset() { return app.dataset; },
  get version() { return app.version; },
  get state() { return app.state; },
  get camera() { return app.cam; },
  frame(view) {
    const f = app.views[view].lastFrame;
    return f ? {...f, image: undefined} : null;
  },
  // The image bytes of the frame on screen, base64 (tests compare pixels across pages).
  frameImage(view) {
    const f = app.views[view].lastFrame;
    if (!f) return null;
    let s = '';
    for (let i = 0; i < f.image.length; i += 0x8000) s += String.fromCharCode(...f.image.subarray(i, i + 0x8000));
    return {mime: f.mime, base64: btoa(s)};
  },
  get role() { return app.participants.role; },
  get participants() { return app.participants.list.map((p) => ({...p})); },
  get shares() { return app.sharePanel.shares.map((s) => ({...s})); },
  get viewLinks() { return app.sharePanel.viewLinks.map((v) => ({...v})); },
  get serverErrors() { return app.serverErrors.slice(); },
  get session() { return app.session; },
  dropConnection() { app.connection.drop(); },
  lastScreenshot: null,
  lastLink: null,
};
