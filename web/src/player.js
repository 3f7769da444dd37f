// Frames on the GPU: progressive queries (coarsest level first, drawn as they arrive), an LRU
// cache of loaded frames, prefetch ahead of the play head, and playback at the dataset's fps.
import { frameWindow } from './connection.js';
import { kHvdb7BatchPoints, kHvdb7Codec } from './hvdb7.js';

// One loaded view of points: a frame's window (or a slice, or a box), at one level of detail.
export class FrameData {
  constructor(key, frame, region, lod) {
    this.key = key;
    this.frame = frame;
    this.region = region;
    this.lod = lod;
    this.chunks = [];
    this.labels = [];       // Uint32Array copies per chunk (for selectedCount)
    this.ids = [];          // per chunk: ids as (low, high) u32 pairs, or null (not sent)
    this.idIndex = null;    // id -> chunk * 2^20 + index, built at the first label refresh
    this.positions = [];    // Float32Array copies per chunk (xyz: the selection's centre)
    this.points = 0;
    this.scale = 1;          // splat growth: the finest complete level's splat_scale
    this.levelsDone = [];
    this.coarsest = null;    // level of the first batch: the dataset's coarsest level
    this.done = false;
    this.error = null;
    this.bboxLo = [Infinity, Infinity, Infinity];
    this.bboxHi = [-Infinity, -Infinity, -Infinity];
    this.sentAt = 0;
    this.firstBatchMs = null;
    this.loadMs = null;      // query sent -> done
    this.serverMs = null;
    this.wireBytes = 0;      // the query's batch messages as received (encoding comparisons)
    this.lastUse = performance.now();
    this.promise = null;
    this.requestId = 0;
    this.disposed = false;
  }

  get layer() { return { chunks: this.chunks, scale: this.scale }; }

  countBit(mask) {
    let n = 0;
    for (const l of this.labels) for (let i = 0; i < l.length; ++i) if (l[i] & mask) ++n;
    return n;
  }

  // Ids (as numbers) of the points with a label bit of `mask`.
  selectedIds(mask) {
    const out = [];
    this.labels.forEach((l, k) => {
      const ids = this.ids[k];
      for (let i = 0; i < l.length; ++i) if ((l[i] & mask) && ids) out.push(ids[2 * i] + ids[2 * i + 1] * 4294967296);
    });
    return out;
  }

  // A select's label-only refresh (SelectReply.flips, decoded by decodeFlips): sets or clears
  // `mask` on the listed points of this view's frame and re-uploads only the labels of the
  // chunks it touched; positions and colours stay on the GPU. False (nothing changed) when
  // this view cannot: a batch came without ids (hvdb7 streams carry none), or an id is past
  // 2^53; the caller then queries the frame again.
  applyFlips(flips, mask, renderer) {
    if (!this.done || this.error || this.chunks.some((c) => !c.labelBuffer)) return false;
    if (!this.idIndex) {
      if (this.ids.some((x) => !x || x.some((v, j) => j % 2 === 1 && v >= 0x200000))) return false;
      this.idIndex = new Map();
      this.ids.forEach((ids, k) => {
        for (let i = 0; 2 * i < ids.length; ++i) this.idIndex.set(ids[2 * i] + ids[2 * i + 1] * 4294967296, k * 1048576 + i);
      });
    }
    const dirty = new Set();
    for (const f of flips) {
      if (f.frame !== this.frame) continue;
      for (const id of f.ids) {
        const at = this.idIndex.get(id);
        if (at === undefined) continue;  // not in this view (a box, a coarser level)
        const k = Math.floor(at / 1048576), i = at % 1048576;
        this.labels[k][i] = f.set ? (this.labels[k][i] | mask) >>> 0 : (this.labels[k][i] & ~mask) >>> 0;
        dirty.add(k);
      }
    }
    for (const k of dirty) renderer.updateLabels(this.chunks[k], this.labels[k]);
    return true;
  }

  // Mean position and count of the points with a label bit of `mask` (displayed coordinates).
  centroid(mask) {
    let n = 0;
    const c = [0, 0, 0];
    this.labels.forEach((l, k) => {
      const p = this.positions[k];
      for (let i = 0; i < l.length; ++i) {
        if (!(l[i] & mask)) continue;
        c[0] += p[3 * i]; c[1] += p[3 * i + 1]; c[2] += p[3 * i + 2];
        ++n;
      }
    });
    return n ? { center: c.map((x) => x / n), count: n } : { center: null, count: 0 };
  }
}

export class FrameStore {
  // onBatch(frameData) is called after each batch is on the GPU (the page redraws if shown).
  // inUse(frameData): whether the page shows it or is loading it for the screen (then it is
  // not disposed until replaced); onReplace(old, fresh): a reload replaced `old` in the cache.
  // encoding: how batches travel, 'COLUMNS' or 'HVDB7' (then `decoder`, an Hvdb7Decoder,
  // decodes them in workers; batches are drawn in the order they came, once decoded).
  // onColumns(frameData, columns, n): each batch's columns (gaussian_mode.js keeps what the
  // records need); onLoaded(frameData): its query is done; onDispose(frameData): it is freed.
  constructor(conn, renderer, { capacity = 24, onBatch = () => {}, onError = () => {}, inUse = () => false, onReplace = () => {}, encoding = 'COLUMNS', decoder = null, onColumns = () => {}, onLoaded = () => {}, onDispose = () => {} } = {}) {
    if (encoding === 'HVDB7' && !decoder) throw new Error('FrameStore: HVDB7 batches need a decoder');
    this.conn = conn;
    this.renderer = renderer;
    this.encoding = encoding;
    this.decoder = decoder;
    this.capacity = capacity;
    this.onBatch = onBatch;
    this.onError = onError;
    this.inUse = inUse;
    this.onReplace = onReplace;
    this.onColumns = onColumns;
    this.onLoaded = onLoaded;
    this.onDispose = onDispose;
    this.map = new Map();
    this.pinned = new Set();  // keys that must not be evicted (what is on screen)
    this.maxLevel = null;
    this.reloads = new Map(); // key -> the newest reload in flight (its generation is current)
    this.retired = new Set(); // dropped entries still on screen: disposed by sweep() later
  }

  static frameKey(dataset, frame, lod, box) {
    return `${dataset}|f${frame}|l${lod}|${box ? JSON.stringify(box) : 'all'}`;
  }

  get(key) {
    const d = this.map.get(key);
    if (d) d.lastUse = performance.now();
    return d;
  }

  // Starts (or returns) the query for `key`. Resolves with the FrameData when it is done.
  // Without a connection nothing is sent: what is cached (even a failed entry) is returned.
  // A `stale` entry (a live change touched its frame after its query was sent) is queried anew.
  load(key, { dataset, frame, region, lod }) {
    let d = this.get(key);
    if (d && !d.error && !d.stale) return d;
    if (d && !this.conn.isOpen) return d;
    if (d) {
      this.map.delete(key);
      this.retire(d);  // its partial chunks' GPU buffers
    }
    d = new FrameData(key, frame, region, lod);
    this.map.set(key, d);
    this.startQuery(d, dataset);
    this.evict();
    return d;
  }

  // A fresh query for an entry already shown: the old data stays on screen until the new
  // one is complete (no flicker after an edit). Resolves with the new FrameData; a reload
  // superseded by a later one (or by invalidate) resolves with `superseded` set and is
  // disposed. Only the newest reload of a key replaces the cached entry.
  reload(key, { dataset, frame, region, lod }) {
    const prev = this.reloads.get(key);
    const d = new FrameData(key, frame, region, lod);
    this.reloads.set(key, d);
    if (prev) this.retire(prev);  // superseded before it completed: cancel it
    this.startQuery(d, dataset);
    const current = () => this.reloads.get(key) === d && !d.disposed;
    d.promise = d.promise.then((fresh) => {
      if (!current()) {
        fresh.superseded = true;
        this.retire(fresh);
        return fresh;
      }
      this.reloads.delete(key);
      const old = this.map.get(key);
      this.map.set(key, fresh);
      if (old && old !== fresh) {
        this.onReplace(old, fresh);  // the page moves to `fresh` if it showed `old`
        this.retire(old);
      }
      this.evict();
      return fresh;
    }, (err) => {
      const wasCurrent = current();
      if (this.reloads.get(key) === d) this.reloads.delete(key);
      this.retire(d);
      if (!wasCurrent) {
        d.superseded = true;
        return d;
      }
      throw err;
    });
    d.promise.catch(() => {});
    return d;
  }

  startQuery(d, dataset) {
    d.sentAt = performance.now();
    d.requestId = 0;
    const hvdb7 = this.encoding === 'HVDB7';
    const query = { dataset, region: d.region, lod: d.lod, progressive: true, encoding: this.encoding };
    if (hvdb7) {
      query.codec = kHvdb7Codec;
      // Smaller batches than the default 16 384 points: the server codes them on the fly
      // (the first two before it sends anything), so the first picture waits for less, and
      // coding, transfer and decoding overlap.
      query.batch_points = kHvdb7BatchPoints;
    }
    // HVDB7: each batch's decode starts as it arrives (in a worker); they are added in order.
    let decoded = Promise.resolve();
    const onPart = (part) => {
      d.wireBytes += part.bytes || 0;
      if (!hvdb7) return this.addBatch(d, part);
      const columns = this.decoder.decode(part.sections.hvdb7 || new Uint8Array(0));
      decoded = decoded.then(() => columns).then((c) => this.addBatch(d, { response: part.response, columns: c.columns }))
        .catch((err) => {
          if (!d.decodeError) {
            d.decodeError = err;
            this.cancelQuery(d);  // nothing more of it can be shown
          }
          throw err;
        });
      decoded.catch(() => {});  // reported through d.promise
    };
    d.promise = this.conn.request({ query }, { onPart, onId: (id) => { d.requestId = id; } })
      .then((reply) => decoded.then(() => reply))
      .then((reply) => {
        d.done = true;
        d.loadMs = performance.now() - d.sentAt;
        d.serverMs = reply.elapsedMs;
        d.reply = reply.done;
        // The last level's splat scale (2^(lod/2)) applies to every point once all are in.
        if (d.levelsDone.length) d.scale = Math.pow(2, d.lod / 2);
        if (!d.disposed) this.onLoaded(d);
        return d;
      }, (err) => {
        if (d.decodeError) err = d.decodeError;  // not the CANCELLED its cancel caused
        d.error = err;
        if (!d.disposed) this.onError(err, d);  // a dropped entry's CANCELLED is no news
        throw err;
      });
    // Callers that only prefetch do not wait: keep unhandled rejections out of the console.
    d.promise.catch(() => {});
  }

  addBatch(d, part) {
    if (d.disposed) return;
    const b = part.response.batch;
    const cols = part.columns;
    const n = Number(b.columns?.count ?? (cols.position ? cols.position.length / 3 : 0));
    if (d.coarsest === null) {
      d.coarsest = Number(b.level);
      if (this.maxLevel === null || d.coarsest > this.maxLevel) this.maxLevel = d.coarsest;
    }
    if (n > 0) {
      if (!cols.position || cols.position.length < 3 * n) throw new Error(`batch of ${n} points without a position column`);
      d.chunks.push(this.renderer.createChunk(cols, n));
      d.labels.push(cols.label ? new Uint32Array(cols.label.subarray(0, n)) : new Uint32Array(n));
      d.ids.push(cols.id ? new Uint32Array(cols.id.subarray(0, 2 * n)) : null);
      d.positions.push(new Float32Array(cols.position.subarray(0, 3 * n)));  // the selection's centre (gizmo.js)
      this.onColumns(d, cols, n);
      d.points += n;
      const p = cols.position;
      const lo = d.bboxLo, hi = d.bboxHi;
      for (let i = 0; i < 3 * n; i += 3) {
        const x = p[i], y = p[i + 1], z = p[i + 2];
        if (x < lo[0]) lo[0] = x; if (x > hi[0]) hi[0] = x;
        if (y < lo[1]) lo[1] = y; if (y > hi[1]) hi[1] = y;
        if (z < lo[2]) lo[2] = z; if (z > hi[2]) hi[2] = z;
      }
    }
    // Until a level is complete its finer points leave holes: grow splats as the coarsest
    // complete level says; then shrink as finer levels complete.
    const scale = Number(b.splat_scale) || 1;
    if (b.level_done) {
      d.levelsDone.push(Number(b.level));
      d.scale = scale;
    } else if (d.levelsDone.length === 0) {
      d.scale = Math.max(d.scale, scale);
    }
    if (d.firstBatchMs === null && n > 0) d.firstBatchMs = performance.now() - d.sentAt;
    this.onBatch(d);
  }

  dispose(d) {
    if (d.disposed) return;
    d.disposed = true;
    this.retired.delete(d);
    this.onDispose(d);
    for (const c of d.chunks) this.renderer.deleteChunk(c);
    d.chunks = [];
    d.labels = [];
    d.ids = [];
    d.idIndex = null;
    d.positions = [];
    this.cancelQuery(d);
  }

  cancelQuery(d) {
    if (d.done || d.error || d.cancelSent) return;
    d.cancelSent = true;
    this.conn.cancel(d.requestId);
  }

  // Disposes an entry no longer cached, or keeps it until the page stops showing it.
  retire(d) {
    if (d.disposed) return;
    if (this.inUse(d)) {
      this.retired.add(d);
      this.cancelQuery(d);  // no more batches for it
    } else {
      this.dispose(d);
    }
  }

  // Disposes the retired entries the page no longer shows (called when it changes what it shows).
  sweep() {
    for (const d of [...this.retired]) {
      if (!this.inUse(d) && this.map.get(d.key) !== d) this.dispose(d);
    }
  }

  evict() {
    if (this.map.size <= this.capacity) return;
    const entries = [...this.map.values()].filter((d) => !this.pinned.has(d.key) && !this.inUse(d))
      .sort((a, b) => a.lastUse - b.lastUse);
    while (this.map.size > this.capacity && entries.length) {
      const d = entries.shift();
      this.map.delete(d.key);
      this.dispose(d);
    }
  }

  // Drops everything but `keep` (after an edit every cached frame may be stale); reloads of
  // dropped keys are cancelled.
  invalidate(keep = new Set()) {
    for (const [k, d] of [...this.reloads]) {
      if (keep.has(k)) continue;
      this.reloads.delete(k);
      this.retire(d);
    }
    for (const [k, d] of [...this.map]) {
      if (keep.has(k)) continue;
      this.map.delete(k);
      this.retire(d);
    }
  }

  // A change committed at `since` (performance.now()) touched these frames: entries of them
  // (and slices, which span all frames) queried before it are stale. Those not on screen are
  // dropped; those on screen stay until load() replaces them (no blank picture meanwhile).
  invalidateFrames(frames, since) {
    const touched = new Set(frames);
    for (const [k, d] of [...this.map]) {
      if (!(d.frame === -1 || touched.has(d.frame)) || d.sentAt >= since) continue;
      d.stale = true;
      if (this.inUse(d)) continue;
      this.map.delete(k);
      this.dispose(d);
    }
  }

  // Another dataset: nothing cached applies, nor its levels of detail.
  reset() {
    this.invalidate();
    this.pinned = new Set();
    this.maxLevel = null;
  }
}

// Playback: the play head follows the wall clock at the dataset's fps; a frame is shown
// when its query is done (so a slow server drops frames rather than slowing time down).
export class Player {
  constructor(app) {
    this.app = app;
    this.playing = false;
    this.prefetchAhead = 8;
    this.stats = null;
    this.raf = 0;
  }

  frameRegion(f) {
    const a = this.app;
    return frameWindow(f / a.info.fps, a.box);
  }

  // Makes sure frames f+1 .. f+ahead are loading (at most a few queries in flight).
  prefetch(f, ahead = this.prefetchAhead) {
    const a = this.app;
    const n = a.info.frame_count;
    if (!n || a.viewMode !== 'frames' || !a.conn.isOpen) return;
    let inFlight = 0;
    for (const d of a.store.map.values()) if (!d.done && !d.error) ++inFlight;
    // In live mode the newest frame is the end: nothing to wrap around to (frame 0 is old news).
    const wrap = !a.live?.on;
    for (let k = 1; k <= ahead && inFlight < 4; ++k) {
      if (f + k >= n && !wrap) break;
      const g = (f + k) % n;
      const key = a.frameKey(g);
      const d = a.store.get(key);
      if (d && !d.error) continue;
      a.store.load(key, { dataset: a.dataset, frame: g, region: this.frameRegion(g), lod: a.lod });
      ++inFlight;
    }
  }

  toggle() { if (this.playing) this.stop(); else this.start(); }

  start() {
    const a = this.app;
    if (this.playing || !a.info || a.viewMode !== 'frames' || a.info.frame_count < 1) return;
    this.playing = true;
    const startFrame = a.frame;
    const t0 = performance.now();
    this.stats = { t0, framesShown: 0, distinct: new Set(), loadMs: [], lastShown: t0, startFrame };
    a.metrics.framesShown = 0;
    a.ui?.setPlaying(true);
    const tick = () => {
      if (!this.playing) return;
      if (!a.conn.isOpen) {  // nothing more can load: stop rather than retry every frame
        this.stop();
        return;
      }
      const now = performance.now();
      const n = a.info.frame_count;
      const want = (startFrame + Math.floor(((now - t0) / 1000) * a.info.fps)) % n;
      this.prefetch(want);
      const key = a.frameKey(want);
      let d = a.store.get(key);
      if (!d) d = a.store.load(key, { dataset: a.dataset, frame: want, region: this.frameRegion(want), lod: a.lod });
      // In gaussian mode a frame is shown once its records are in (gaussian_mode.js).
      if (want !== a.frame && d.done && (!a.gaussian || a.gaussian.drawable(d))) {
        a.showFrameData(d, want, true, a.playResolution);  // drawn now, not on the next animation frame
        const s = this.stats;
        s.framesShown++;
        s.distinct.add(want);
        if (d.loadMs !== null && !d.countedInPlay) {
          d.countedInPlay = true;
          s.loadMs.push(d.loadMs);
        }
        const el = (now - s.t0) / 1000;
        a.metrics.framesShown = s.framesShown;
        a.metrics.playFps = el > 0 ? s.framesShown / el : 0;
      }
      this.raf = requestAnimationFrame(tick);
    };
    this.raf = requestAnimationFrame(tick);
  }

  stop() {
    if (!this.playing) return this.result();
    this.playing = false;
    cancelAnimationFrame(this.raf);
    if (this.app.playResolution < 1) this.app.requestDraw();  // the still frame at full resolution
    this.app.ui?.setPlaying(false);
    const r = this.result();
    this.app.metrics.playFps = r.fps;
    return r;
  }

  result() {
    const s = this.stats;
    if (!s) return { fps: 0, framesShown: 0, distinctFrames: 0, frameLoadMsMedian: null };
    const el = (performance.now() - s.t0) / 1000;
    const sorted = [...s.loadMs].sort((x, y) => x - y);
    const median = sorted.length ? sorted[Math.floor((sorted.length - 1) / 2)] : null;
    return { fps: el > 0 ? s.framesShown / el : 0, framesShown: s.framesShown, distinctFrames: s.distinct.size, frameLoadMsMedian: median };
  }

  playFor(seconds) {
    this.stop();
    this.start();
    if (!this.playing) return Promise.reject(new Error('cannot play: no frames (or a slice is shown)'));
    return new Promise((resolve) => setTimeout(() => resolve(this.stop()), seconds * 1000));
  }
}

// SelectReply.flips (docs/PROTOCOL.md) as [{frame, set, ids: Float64Array}]: each group's
// `count` ids are LEB128 varints of their gaps, base64 in JSON. Null when an id is past 2^53
// (not exact as a number). A malformed list throws: the reply is wrong, not the view.
export function decodeFlips(flips) {
  const out = [];
  for (const f of flips || []) {
    const bin = atob(f.ids || '');
    const count = Number(f.count || 0);
    if (count > bin.length) throw new Error(`select reply: ${count} flipped ids in ${bin.length} bytes`);
    const ids = new Float64Array(count);
    let prev = 0, p = 0;
    for (let i = 0; i < count; ++i) {
      let gap = 0, mul = 1, b;
      do {
        if (p >= bin.length) throw new Error('select reply: flipped ids end early');
        b = bin.charCodeAt(p++);
        gap += (b & 0x7f) * mul;
        mul *= 128;
      } while (b & 0x80);
      if (i > 0 && gap === 0) throw new Error('select reply: flipped ids not ascending');
      prev += gap;
      if (prev > Number.MAX_SAFE_INTEGER) return null;
      ids[i] = prev;
    }
    if (p !== bin.length) throw new Error('select reply: bytes after the flipped ids');
    out.push({ frame: Number(f.frame || 0), set: !!f.set, ids });
  }
  return out;
}
