// The WebSocket client of hvdb's browser transport (docs/PROTOCOL.md, "HTTP and WebSocket").
// Requests go out as proto3 JSON text; answers come back as text JSON, or as binary messages
// (u32 LE header length, JSON header, 8-byte aligned payload sections) for bulk replies.

export const PROTOCOL_VERSION = 2;

// An error reply of the server (or of the transport), with the protocol's code.
export class HvdbError extends Error {
  constructor(code, message, parameter = '') {
    super(`${code}: ${message}${parameter ? ` (${parameter})` : ''}`);
    this.name = 'HvdbError';
    this.code = code;
    this.parameter = parameter;
  }
}

const kDecoder = new TextDecoder();

// Typed views for the "Point columns" of docs/PROTOCOL.md: [constructor, element size].
const kColumnTypes = {
  id: [Uint32Array, 4],  // u64 read as pairs of u32 (low, high): BigUint64Array is not needed
  position: [Float32Array, 4],
  frame: [Uint32Array, 4],
  color: [Uint8Array, 1],
  covariance: [Float32Array, 4],
  normal: [Int16Array, 2],
  label: [Uint32Array, 4],
  camera: [Uint16Array, 2],
  flags: [Uint8Array, 1],
};

// Decodes one binary message: {response, sections: {field: Uint8Array}, columns: {field: view}}.
// Views share the message's buffer (sections start at multiples of 8, so any view is aligned).
export function decodeBinary(buffer) {
  if (buffer.byteLength < 4) throw new HvdbError('MALFORMED', 'binary message shorter than 4 bytes');
  const dv = new DataView(buffer);
  const j = dv.getUint32(0, true);
  if (4 + j > buffer.byteLength) throw new HvdbError('MALFORMED', `binary header of ${j} bytes overruns the message`);
  const header = JSON.parse(kDecoder.decode(new Uint8Array(buffer, 4, j)));
  const sections = {};
  const columns = {};
  for (const s of header.payload || []) {
    const offset = Number(s.offset), length = Number(s.length);
    if (offset % 8 !== 0 || offset + length > buffer.byteLength) {
      throw new HvdbError('MALFORMED', `payload section ${s.field} [${offset}, +${length}) is misaligned or out of range`);
    }
    sections[s.field] = new Uint8Array(buffer, offset, length);
    const t = kColumnTypes[s.field];
    if (t) columns[s.field] = new t[0](buffer, offset, length / t[1]);
  }
  return { response: header.response, sections, columns };
}

// The body kind of a Response (its oneof field), e.g. "batch", "done", "error".
function bodyKind(r) {
  for (const k of ['error', 'batch', 'done', 'render', 'info', 'datasets', 'commit', 'selected',
    'graph_cut', 'copied', 'compacted', 'pong', 'stats', 'server', 'gaussians', 'ack', 'event']) {
    if (r[k] !== undefined && r[k] !== null) return k;
  }
  return null;
}

export class Connection {
  // onState(state, detail): 'connecting' | 'open' | 'closed' | 'error'.
  constructor(url, { token = '', clientName = 'hvdb-web', capabilities = [], onState = () => {} } = {}) {
    this.url = url;
    this.token = token;
    this.capabilities = capabilities;  // the Hello's ("hvdb7" when the page asks for it)
    this.clientName = clientName;
    this.onState = onState;
    this.ws = null;
    this.nextId = 1;
    this.pending = new Map();  // id -> {resolve, reject, onPart, kind}
    this.hello = null;
  }

  // Opens the socket and performs the handshake; resolves with the HelloReply.
  open() {
    return new Promise((resolve, reject) => {
      this.onState('connecting', this.url);
      let ws;
      try {
        ws = new WebSocket(this.url);
      } catch (e) {
        this.onState('error', e.message);
        reject(e);
        return;
      }
      ws.binaryType = 'arraybuffer';
      this.ws = ws;
      let greeted = false;
      ws.onopen = () => {
        ws.send(JSON.stringify({ protocol_version: PROTOCOL_VERSION, capabilities: this.capabilities, client_name: this.clientName, token: this.token }));
      };
      ws.onmessage = (ev) => {
        if (!greeted) {
          greeted = true;
          let msg;
          try {
            msg = JSON.parse(typeof ev.data === 'string' ? ev.data : kDecoder.decode(ev.data));
          } catch (e) {
            reject(new HvdbError('MALFORMED', `handshake reply is not JSON: ${e.message}`));
            return;
          }
          if (msg.error) {
            const err = new HvdbError(msg.error.code, msg.error.message, msg.error.parameter);
            this.onState('error', err.message);
            reject(err);
            return;
          }
          this.hello = msg;
          this.onState('open', msg.server_name || '');
          resolve(msg);
          return;
        }
        this.dispatch(ev.data);
      };
      ws.onerror = () => {
        // The browser gives no detail here; onclose follows with the code.
        this.onState('error', `WebSocket error on ${this.url}`);
      };
      ws.onclose = (ev) => {
        const why = `connection closed (code ${ev.code}${ev.reason ? `: ${ev.reason}` : ''})`;
        this.onState('closed', why);
        const err = new HvdbError('CLOSED', why);
        if (!greeted) reject(err);
        this.ws = null;
        const pending = [...this.pending.values()];
        this.pending.clear();
        for (const p of pending) p.reject(err);
      };
    });
  }

  get isOpen() { return !!this.ws && this.ws.readyState === WebSocket.OPEN; }

  close() { if (this.ws) this.ws.close(1000, 'client closing'); }

  // Sends {id, ...body}. Resolves with the final Response (JSON, with `sections`/`columns`
  // attached for binary replies); rejects with HvdbError on an error reply.
  // onPart(decoded) is called for every streamed part: each query batch ({response, columns,
  // sections, bytes}: bytes is the message's size), each render reply (the last one too) and each watch event (a watch resolves
  // with its DROPPED or LAGGED event, and rejects with CANCELLED once cancelled).
  request(body, { onPart = null, onId = null } = {}) {
    if (!this.isOpen) return Promise.reject(new HvdbError('CLOSED', 'not connected to the server'));
    const id = this.nextId++;
    const kind = Object.keys(body)[0];
    const msg = JSON.stringify({ id, ...body });
    if (onId) onId(id);  // the caller can cancel it later (only ids actually sent are given)
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject, onPart, kind, sentAt: performance.now() });
      this.ws.send(msg);
    });
  }

  // Cancels a request in flight (its promise then rejects with CANCELLED).
  cancel(id) {
    if (!this.isOpen || !(id > 0)) return Promise.resolve(null);
    return this.request({ cancel: { target: id } }).catch(() => null);
  }

  // The id the next request will get (so that a caller can cancel it later).
  peekId() { return this.nextId; }

  // A message that cannot be decoded: the request it answers (when its id can still be read)
  // fails with MALFORMED; otherwise nothing on this connection can be trusted any more.
  undecodable(data, e) {
    console.error('hvdb: undecodable message from the server', e);
    const err = e instanceof HvdbError ? e : new HvdbError('MALFORMED', `undecodable message from the server: ${e.message}`);
    const id = readId(data);
    const p = id > 0 ? this.pending.get(id) : null;
    if (p) {
      this.pending.delete(id);
      p.reject(err);
      this.cancel(id);
      return;
    }
    this.failAll(err);
    if (this.ws) this.ws.close(4000, 'undecodable message');
  }

  // Every request in flight fails with `err` (a connection-level error).
  failAll(err) {
    this.onState('error', err.message);
    const pending = [...this.pending.values()];
    this.pending.clear();
    for (const p of pending) p.reject(err);
  }

  dispatch(data) {
    let decoded;
    try {
      if (typeof data === 'string') {
        decoded = { response: JSON.parse(data), sections: {}, columns: {} };
      } else {
        decoded = decodeBinary(data);
      }
      decoded.bytes = typeof data === 'string' ? data.length : data.byteLength;  // on the wire
    } catch (e) {
      this.undecodable(data, e);
      return;
    }
    const r = decoded.response;
    const id = Number(r.id || 0);
    const kind = bodyKind(r);
    if (id === 0) {
      // A connection-level error: every request fails with it; the server closes.
      this.failAll(new HvdbError(r.error?.code || 'MALFORMED', r.error?.message || 'connection error'));
      return;
    }
    const p = this.pending.get(id);
    if (!p) return;  // a late part of a cancelled request
    if (kind === 'error') {
      this.pending.delete(id);
      p.reject(new HvdbError(r.error.code, r.error.message, r.error.parameter));
      return;
    }
    // A watch's events (WatchEvent) stream like batches; DROPPED and LAGGED end the watch.
    const watchEnds = kind === 'event' && (r.event.kind === 'WATCH_DROPPED' || r.event.kind === 'WATCH_LAGGED');
    if (kind === 'batch' || kind === 'render' || kind === 'event') {
      if (p.onPart) {
        try {
          p.onPart(decoded);
        } catch (e) {
          console.error('hvdb: batch handler failed', e);
          this.pending.delete(id);
          p.reject(e);
          this.cancel(id);  // the server stops streaming what nobody reads any more
          return;
        }
      }
      if (kind === 'batch') return;
      if (kind === 'render' && !r.render.last) return;
      if (kind === 'event' && !watchEnds) return;
    }
    this.pending.delete(id);
    r.sections = decoded.sections;
    r.columns = decoded.columns;
    r.elapsedMs = performance.now() - p.sentAt;
    p.resolve(r);
  }
}

// The request id of a message that did not decode, if it can be read (0 if not).
function readId(data) {
  try {
    let text = data;
    if (typeof data !== 'string') {
      const dv = new DataView(data);
      const j = dv.getUint32(0, true);
      text = kDecoder.decode(new Uint8Array(data, 4, Math.min(j, data.byteLength - 4)));
    }
    const m = /"id"\s*:\s*"?(\d+)/.exec(text);
    return m ? Number(m[1]) : 0;
  } catch (e) {
    return 0;
  }
}

// Regions of the protocol.
export function frameWindow(t, box = null) {
  const lo = box ? [box.lo[0], box.lo[1], box.lo[2], t] : [-1e30, -1e30, -1e30, t];
  const hi = box ? [box.hi[0], box.hi[1], box.hi[2], t] : [1e30, 1e30, 1e30, t];
  return { window: { lo, hi } };
}

export function allTimeWindow(box = null) {
  const lo = box ? [box.lo[0], box.lo[1], box.lo[2], -1e30] : [-1e30, -1e30, -1e30, -1e30];
  const hi = box ? [box.hi[0], box.hi[1], box.hi[2], 1e30] : [1e30, 1e30, 1e30, 1e30];
  return { window: { lo, hi } };
}

export function sliceRegion(normal, offset, thickness) {
  return { slice: { normal: normal.slice(0, 4), offset, thickness, clip_frames: true } };
}
