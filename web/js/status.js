// Status: what the page tells the user about the server and the data — connection state (a
// banner while connecting, lost or reconnecting), the dataset's construction/streaming progress,
// and the stats overlay (frames per second, round-trip time, KB per frame, bricks pending,
// frames dropped). Errors from the server are shown as a short-lived toast.

import {describeState} from './dataset_picker.js';

export class Status {
  constructor(root) {
    this.banner = root.querySelector('#connection-banner');
    this.conn = root.querySelector('#connection-state');
    this.progress = root.querySelector('#dataset-progress');
    this.progressBar = root.querySelector('#dataset-progress-bar');
    this.stats = root.querySelector('#stats');
    this.toast = root.querySelector('#toast');
    this.frameTimes = [];
    this.frameBytes = [];
    this.rtt = null;
    this.server = {};
    this.toastTimer = null;
    setInterval(() => this.renderStats(), 500);
  }

  connection({state, detail}) {
    document.body.dataset.connection = state;
    const labels = {connecting: 'Connecting…', open: 'Connected', reconnecting: 'Connection lost — reconnecting…',
      failed: 'Disconnected', ended: 'Left the session'};
    this.conn.textContent = labels[state] ?? state;
    this.conn.className = `conn ${state}`;
    this.conn.title = detail || '';
    const show = state !== 'open';
    this.banner.hidden = !show;
    // A session that ended (link revoked, removed, credential refused) says why in a sentence.
    this.banner.textContent = !show ? '' : state === 'ended' && detail ? detail :
      `${labels[state] ?? state}${detail ? ' (' + detail + ')' : ''}`;
    this.banner.setAttribute('role', state === 'ended' || state === 'failed' ? 'alert' : 'status');
  }

  // A neutral, short-lived hint (e.g. "view only" when a viewer tries to drive).
  notice(message) {
    this.error(message);
    this.toast.classList.add('notice');
  }

  dataset(d) {
    if (!d) {
      this.progress.textContent = '';
      this.progressBar.style.width = '0';
      this.progressBar.parentElement.hidden = true;
      return;
    }
    this.progress.textContent = describeState(d);
    const growing = d.state === 'building' || d.state === 'streaming';
    this.progressBar.parentElement.hidden = !growing;
    this.progressBar.style.width = `${Math.round((d.progress ?? 0) * 100)}%`;
  }

  frame(frame) {
    const now = performance.now();
    this.frameTimes.push(now);
    this.frameBytes.push(frame.imageBytes);
    while (this.frameTimes.length && now - this.frameTimes[0] > 2000) {
      this.frameTimes.shift();
      this.frameBytes.shift();
    }
  }

  pong(rtt) {
    this.rtt = this.rtt === null ? rtt : 0.7 * this.rtt + 0.3 * rtt;
  }

  serverStats(msg) {
    this.server = msg;
  }

  renderStats() {
    if (this.stats.hidden) return;
    const n = this.frameTimes.length;
    const fps = n > 1 ? (n - 1) / ((this.frameTimes[n - 1] - this.frameTimes[0]) / 1000) : 0;
    const kb = n ? this.frameBytes.reduce((a, b) => a + b, 0) / n / 1024 : 0;
    const s = this.server;
    this.stats.textContent = [
      `fps ${fps.toFixed(1)}`,
      `rtt ${this.rtt === null ? '–' : this.rtt.toFixed(0) + ' ms'}`,
      `${kb.toFixed(1)} KB/frame`,
      `bricks pending ${s.bricks_pending ?? '–'}`,
      `sent ${s.frames_sent ?? '–'} · dropped ${s.frames_dropped ?? '–'}`,
    ].join('\n');
  }

  error(message) {
    this.toast.classList.remove('notice');
    this.toast.textContent = message;
    this.toast.hidden = false;
    clearTimeout(this.toastTimer);
    this.toastTimer = setTimeout(() => {
      this.toast.hidden = true;
    }, 6000);
  }
}
