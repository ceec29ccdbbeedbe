// Connection: the page's one WebSocket to `octoscope serve` (docs/protocol.md). It says hello,
// hands JSON events and decoded binary frames to the app, measures round-trip time with pings,
// and reconnects with a growing back-off (0.5 s … 8 s) when the connection drops — the app then
// restores its view by sending `open` with its whole state. A fatal error or a policy close
// (1008/1009) stops reconnecting and is shown as such.

import {decodeFrame} from './frame_decoder.js';

const PING_INTERVAL_MS = 2000;

export class Connection {
  // handlers: onOpen(isReconnect), onEvent(msg), onFrame(frame), onStatus({state, detail}),
  // onPong(rttMs).
  constructor(url, handlers, clientName = 'octoscope-web') {
    this.url = url;
    this.handlers = handlers;
    this.clientName = clientName;
    this.ws = null;
    this.attempt = 0;
    this.everOpened = false;
    this.stopped = false;
    this.pingTimer = null;
    this.retryTimer = null;
  }

  connect() {
    this.stopped = false;
    clearTimeout(this.retryTimer);
    this.status(this.everOpened ? 'reconnecting' : 'connecting',
        this.attempt ? `attempt ${this.attempt + 1}` : '');
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      this.status('failed', String(e.message || e));
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    ws.onopen = () => {
      const reconnect = this.everOpened;
      this.everOpened = true;
      this.attempt = 0;
      this.send({type: 'hello', client: this.clientName, protocol: 1});
      this.status('open', '');
      clearInterval(this.pingTimer);
      this.pingTimer = setInterval(() => this.ping(), PING_INTERVAL_MS);
      this.ping();
      this.handlers.onOpen?.(reconnect);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        let msg;
        try {
          msg = JSON.parse(ev.data);
        } catch {
          console.warn('octoscope: unparsable event', ev.data.slice(0, 200));
          return;
        }
        if (msg.type === 'pong') {
          if (Number.isFinite(msg.t)) this.handlers.onPong?.(performance.now() - msg.t);
          return;
        }
        this.handlers.onEvent?.(msg);
        return;
      }
      let frame;
      try {
        frame = decodeFrame(ev.data);
      } catch (e) {
        console.warn('octoscope: dropped a malformed frame:', e.message);
        return;
      }
      this.handlers.onFrame?.(frame);
    };
    ws.onclose = (ev) => {
      clearInterval(this.pingTimer);
      if (this.ws !== ws) return;
      this.ws = null;
      if (this.stopped) return;
      if (ev.code === 1008 || ev.code === 1009) {
        this.status('failed', `the server closed the connection: ${ev.reason || ev.code}`);
        return;
      }
      this.scheduleRetry(ev.reason || (this.everOpened ? 'connection lost' : 'cannot connect'));
    };
    ws.onerror = () => {};  // onclose follows and says what happens next.
  }

  scheduleRetry(reason) {
    const delay = Math.min(8000, 500 * Math.pow(2, this.attempt));
    this.attempt += 1;
    this.status(this.everOpened ? 'reconnecting' : 'connecting',
        `${reason}; retrying in ${(delay / 1000).toFixed(1)} s`);
    this.retryTimer = setTimeout(() => this.connect(), delay);
  }

  status(state, detail) {
    this.state = state;
    this.handlers.onStatus?.({state, detail});
  }

  get open() {
    return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
  }

  // Sends one JSON message; false when the connection is not open (the app's state is sent
  // again as a whole on reconnect, so nothing is queued).
  send(msg) {
    if (!this.open) return false;
    this.ws.send(JSON.stringify(msg));
    return true;
  }

  ping() {
    this.send({type: 'ping', t: performance.now()});
  }

  // Drops the connection as if the network failed (tests, "reconnect" button).
  drop() {
    if (this.ws) this.ws.close(4000, 'dropped by the client');
  }

  close() {
    this.stopped = true;
    clearTimeout(this.retryTimer);
    clearInterval(this.pingTimer);
    if (this.ws) this.ws.close(1000, 'page closed');
    this.ws = null;
  }
}
