// The light stream client (docs/protocol.md): one WebSocket to /ws/light, the hello, then
// binary light vectors (and, for the kiosk, site-camera JPEG frames and occlusion masks).
// When the connection drops it keeps the last vector (the caller shows it as stale),
// reconnects with exponential backoff and jitter, and carries on without a reload.
// It asks for protocol version 3 (the sky in float16); a server of before version 3 refuses
// that with HTTP 400, which a browser only sees as a connection closed before the hello, so
// each attempt that ends before a hello switches between asking 3 and 2 (docs/protocol.md,
// "Versions").
import {
  decodeMessage, decodeOcclusionMask, FALLBACK_VERSION, lightStreamUrl, MessageType,
  parseHello, pingMessage, PROTOCOL_VERSION, ProtocolError, subscribeMessage,
} from './protocol.js';

const MIN_BACKOFF_MS = 500;
const MAX_BACKOFF_MS = 10000;
const PING_EVERY_MS = 20000;
// The server re-sends the vector at least every max_interval_s (5 s); three missed keep-alives
// mean the connection is dead even if the socket has not noticed.
const SILENCE_LIMIT_MS = 16000;
const OCCLUSION_STREAM = 'occlusion'; // server/lightstream.py OCCLUSION

export class LightStream {
  /**
   * @param {{siteCamera?: boolean, token?: string, url?: string,
   *   location?: {protocol: string, host: string},
   *   onLight?: Function, onFrame?: Function, onMask?: Function, onHello?: Function,
   *   onState?: Function}} options  url: a fixed URL (no version fallback); location: the
   *   server's (default the page's).
   *   onLight({rgb, saturated, sequence, captureTime, stale, flags, sun}): sun is
   *   {direction, normalIrradiance, source, estimated} (protocol 2) or null (an older
   *   server's protocol 1: the sun is then inside its patch's value in rgb),
   *   onFrame({jpeg: Uint8Array, sequence, captureTime}),
   *   onMask({width, height, mask, people, sequence, captureTime}),
   *   onState(state): 'connecting' | 'open' | 'reconnecting' | 'closed';
   *   token: the operator's token (a kiosk's), sent as the subscription's ?token=.
   */
  constructor(options = {}) {
    this.options = options;
    this.streams = options.siteCamera ? ['light', 'site-camera'] : ['light'];
    this.location = options.location ?? globalThis.location;
    this.version = PROTOCOL_VERSION; // the version the next connection asks for
    this.url = options.url ?? lightStreamUrl(this.location, this.streams, this.version, this.options.token);
    this.ws = null;
    this.state = 'closed';
    this.hello = null;
    this.backoffMs = MIN_BACKOFF_MS;
    this.reconnects = 0;
    this.lastMessageMs = 0;
    this.clockOffsetS = 0; // server_time - local time, from ping/pong
    this.messages = { light: 0, 'site-camera': 0, occlusion: 0, skipped: 0 };
    this._timer = null;
    this._pingTimer = null;
    this._stopped = true;
  }

  start() {
    this._stopped = false;
    this._connect();
  }

  stop() {
    this._stopped = true;
    clearTimeout(this._timer);
    clearInterval(this._pingTimer);
    if (this.ws) {
      this.ws.onclose = null;
      this.ws.close(1000, 'client leaving');
      this.ws = null;
    }
    this._setState('closed');
  }

  /** True while a vector is arriving on an open connection. */
  get live() {
    return this.state === 'open' && performance.now() - this.lastMessageMs < SILENCE_LIMIT_MS;
  }

  _setState(state) {
    if (state === this.state) return;
    this.state = state;
    this.options.onState?.(state);
  }

  _connect() {
    clearTimeout(this._timer);
    this._setState(this.reconnects ? 'reconnecting' : 'connecting');
    if (!this.options.url) this.url = lightStreamUrl(this.location, this.streams, this.version, this.options.token);
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch {
      this._scheduleReconnect();
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    this.hello = null;
    ws.onmessage = (event) => this._onMessage(event.data);
    ws.onclose = () => {
      if (this.ws !== ws) return;
      if (this.hello === null && !this.options.url) {
        // Closed before the hello: a server down, or one of before version 3 refusing it.
        this.version = this.version === PROTOCOL_VERSION ? FALLBACK_VERSION : PROTOCOL_VERSION;
      }
      this.ws = null;
      clearInterval(this._pingTimer);
      if (!this._stopped) this._scheduleReconnect();
    };
    ws.onerror = () => {}; // onclose follows; the browser already reports the failure itself
  }

  _scheduleReconnect() {
    this.reconnects += 1;
    this._setState('reconnecting');
    const delay = this.backoffMs * (0.75 + 0.5 * Math.random());
    this.backoffMs = Math.min(MAX_BACKOFF_MS, this.backoffMs * 2);
    this._timer = setTimeout(() => this._connect(), delay);
  }

  _onMessage(data) {
    this.lastMessageMs = performance.now();
    if (typeof data === 'string') {
      this._onText(data);
      return;
    }
    let msg;
    try {
      msg = decodeMessage(data);
    } catch (err) {
      if (!(err instanceof ProtocolError)) throw err;
      this.messages.skipped += 1; // a message we cannot read: skip it, keep the stream
      return;
    }
    if (msg.type === MessageType.LIGHT) {
      this.messages.light += 1;
      this.options.onLight?.({
        rgb: msg.rgb, saturated: msg.saturated, sequence: msg.sequence,
        captureTime: msg.captureTime, stale: msg.stale, flags: msg.flags, sun: msg.sun,
      });
    } else if (msg.type === MessageType.SITE_CAMERA) {
      this.messages['site-camera'] += 1;
      this.options.onFrame?.({ jpeg: msg.payload, sequence: msg.sequence, captureTime: msg.captureTime });
    } else if (msg.type === MessageType.OCCLUSION_MASK) {
      let mask;
      try {
        mask = decodeOcclusionMask(msg.payload);
      } catch (err) {
        if (!(err instanceof ProtocolError)) throw err;
        this.messages.skipped += 1;
        return;
      }
      this.messages.occlusion += 1;
      this.options.onMask?.({ ...mask, sequence: msg.sequence, captureTime: msg.captureTime });
    }
    // other types: skipped, as the protocol asks
  }

  _onText(text) {
    if (this.hello === null) {
      try {
        this.hello = parseHello(text);
      } catch (err) {
        if (!(err instanceof ProtocolError)) throw err;
        this.ws?.close(1002, 'bad hello');
        return;
      }
      this.backoffMs = MIN_BACKOFF_MS;
      this._setState('open');
      this._subscribeOcclusion();
      this._ping();
      clearInterval(this._pingTimer);
      this._pingTimer = setInterval(() => this._ping(), PING_EVERY_MS);
      this.options.onHello?.(this.hello);
      return;
    }
    let msg;
    try {
      msg = JSON.parse(text);
    } catch {
      return;
    }
    if (msg.type === 'pong' && typeof msg.id === 'number' && this._pingSentMs !== undefined) {
      const nowMs = performance.now();
      const rttS = (nowMs - this._pingSentMs) / 1000;
      this.clockOffsetS = msg.server_time_s - (Date.now() / 1000 - rttS / 2);
      this.rttMs = rttS * 1000;
    }
  }

  /** True when the kiosk asked for the site camera but the server withheld it (no or a wrong
   * operator token: server/access.py), though the server has one. */
  get siteCameraDenied() {
    if (!this.options.siteCamera || !this.hello) return false;
    const available = this.hello.available_streams ?? [];
    return available.includes('site-camera') && !(this.hello.streams ?? []).includes('site-camera');
  }

  /** The kiosk also wants the occlusion masks when the server offers them. */
  _subscribeOcclusion() {
    if (!this.options.siteCamera) return;
    const available = this.hello.available_streams ?? [];
    const granted = this.hello.streams ?? [];
    if (available.includes(OCCLUSION_STREAM) && !granted.includes(OCCLUSION_STREAM)) {
      this.ws?.send(subscribeMessage([...new Set([...granted, ...this.streams, OCCLUSION_STREAM])]
        .filter((name) => available.includes(name))));
    }
  }

  _ping() {
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) return;
    this._pingSentMs = performance.now();
    this.ws.send(pingMessage(1));
  }

  /** Seconds since a capture time (server clock), corrected by the measured clock offset. */
  ageS(captureTimeS) {
    return Date.now() / 1000 + this.clockOffsetS - captureTimeS;
  }
}
