// Connection: the page's one WebSocket to `octoscope serve` (docs/protocol.md). It says hello,
// hands JSON events and decoded binary frames to the app, measures round-trip time with pings,
// and reconnects with a growing back-off (0.5 s … 8 s) when the connection drops — the app then
// restores its view (a share participant rejoins, an owner reattaches with its resume key). A
// policy close (1008/1009), a revoked share link or a removal from the session stops
// reconnecting and says why (closeOutcome); so does a credential the server no longer accepts
// (the app's probe, asked before each retry).

import {decodeFrame} from './frame_decoder.js';

const PING_INTERVAL_MS = 2000;

// Close codes the server sends when a participant must not come back (docs/protocol.md).
export const CLOSE_REVOKED = 4001;
export const CLOSE_RESUMED_ELSEWHERE = 4002;
export const CLOSE_KICKED = 4003;
export const CLOSE_GONE = 4004;
export const CLOSE_ACCESS_ENDED = 4005;

// What a close means for the page: {retry: bool, message: text for the user}; `joined`: the
// connection had been welcomed into a session. Pure.
export function closeOutcome(code, reason, joined = true) {
  const why = typeof reason === 'string' && reason ? reason : '';
  switch (code) {
    case CLOSE_REVOKED:
      if (/expired/.test(why)) return {retry: false, message: 'This share link expired — you have left the session.'};
      return {retry: false, message: joined ? 'The owner revoked this share link — you have left the session.' :
        'This share link no longer works: the owner revoked it, or it expired.'};
    case CLOSE_ACCESS_ENDED:
      // The grant this connection rested on ended (a token expired, a user removed, a link
      // deleted): reconnecting would be refused.
      return {retry: false, message: `Your access to this session ended${why ? ` (${why.replace(/^access ended: /, '')})` : ''}.`};
    case CLOSE_KICKED:
      return {retry: false, message: 'The owner removed you from the session.'};
    case CLOSE_RESUMED_ELSEWHERE:
      return {retry: false, message: 'This session continues in another tab or window (resumed elsewhere).'};
    case CLOSE_GONE:
      return {retry: false, message: `This link's view or session no longer exists${why ? ` (${why})` : ''}.`};
    case 1008:
    case 1009:
      return {retry: false, message: `The server closed the connection: ${why || code}`};
    case 1013:
      return {retry: true, message: why ? `server busy: ${why}` : 'server busy'};
    default:
      return {retry: true, message: why};
  }
}

export class Connection {
  // handlers: onOpen(isReconnect), onEvent(msg), onFrame(frame), onStatus({state, detail}),
  // onPong(rttMs); optional helloFields() → extra fields of `hello` (a resume key), probe() →
  // Promise of null (keep retrying) or a message (the credential is refused: stop, say why).
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
    this.welcomed = false;
    ws.onopen = () => {
      const reconnect = this.everOpened;
      this.everOpened = true;
      this.attempt = 0;
      this.send({type: 'hello', client: this.clientName, protocol: 1, ...(this.handlers.helloFields?.() ?? {})});
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
        if (msg.type === 'welcome') this.welcomed = true;
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
      const outcome = closeOutcome(ev.code, ev.reason, this.welcomed);
      if (!outcome.retry) {
        this.stopped = true;
        this.status(ev.code >= 4000 ? 'ended' : 'failed', outcome.message);
        return;
      }
      this.scheduleRetry(outcome.message || (this.everOpened ? 'connection lost' : 'cannot connect'));
    };
    ws.onerror = () => {};  // onclose follows and says what happens next.
  }

  scheduleRetry(reason) {
    const delay = Math.min(8000, 500 * Math.pow(2, this.attempt));
    this.attempt += 1;
    this.status(this.everOpened ? 'reconnecting' : 'connecting',
        `${reason}; retrying in ${(delay / 1000).toFixed(1)} s`);
    this.retryTimer = setTimeout(async () => {
      // A link revoked or expired while the page was away: the upgrade would fail with 401
      // forever (a browser sees only 1006), so ask the server in plain HTTP first.
      const refused = await this.handlers.probe?.().catch(() => null);
      if (this.stopped) return;
      if (refused) {
        this.stopped = true;
        this.status('ended', refused);
        return;
      }
      this.connect();
    }, delay);
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
