// The page's "gaussian" render mode: a frame's points drawn as 3DGS splats with their
// Gaussian records (gaussian_renderer.js), as the server's gaussian render draws them.
//
// - Mode: a Gaussian-splat dataset (DatasetInfo.gaussians) opens in it; `?mode=gaussian|
//   visibility` or the toolbar's Render select chooses for any dataset (a plain one draws the
//   records derived from its points).
// - Data: while the mode is on, frames are queried as COLUMNS (they carry the point ids; the
//   page's hvdb7 decoder returns none) and the columns the records need are kept with each
//   batch. Once a frame's query is done its records are read with ReadGaussians (a Gaussian-
//   splat dataset only: a plain one has none), packed into textures, and its positions go to
//   the sort worker; the frame is drawable once its first back-to-front order is in. All of
//   it lives and dies with the frame's FrameData (the FrameStore's LRU and eviction).
// - Drawing: the frame on screen is drawn once drawable; until then the last frame drawn stays
//   (playback shows a frame only when it is drawable). A camera or frame change asks the worker
//   for a new order; the last one is drawn meanwhile, and the new one redraws when it comes.
import { GaussianRenderer } from './gaussian_renderer.js';
import { packSplats, readGaussians } from './gaussian_records.js';
import { viewTransform } from './camera.js';

const kNearZ = 0.2;  // the reference's near cull (gaussian_raster_kernels.h kNearZ)
// GPU bytes of Gaussian frames kept: the cache holds fewer frames when they are large
// (a 1 M-splat degree-3 frame takes 240 MB of textures).
const kBudgetBytes = 1 << 30;
let nextId = 1;

function concat(list, T) {
  let n = 0;
  for (const a of list) n += a.length;
  const out = new T(n);
  let at = 0;
  for (const a of list) { out.set(a, at); at += a.length; }
  return out;
}

// The depth function of a camera (its third rotation row and translation): what an order is for.
function depthOf(cam) {
  const { rot, trans } = viewTransform(cam);
  const r = [rot[6], rot[7], rot[8]];
  return { r, t: trans[2], key: `${r.join(',')},${trans[2]}` };
}

export class GaussianMode {
  constructor(app) {
    this.app = app;
    this.mode = 'visibility';
    this.chosen = app.params.mode || '';  // the address's or the user's choice; else the dataset's
    this.renderer = null;
    this.worker = null;
    this.seq = 0;
    this.inFlight = null;  // {g, view, seq}
    this.wanting = new Set();  // frames waiting for an order
    this.live = new Set();     // frames with GPU data
    this.drawn = null;         // the FrameData last drawn in this mode
    this.stats = { sorts: 0, lastSortMs: null, lastRecordsMs: null, lastPackMs: null };
    this.buildUi();
  }

  get active() { return this.mode === 'gaussian'; }

  buildUi() {
    const bar = document.getElementById('toolbar');
    if (!bar) return;
    const label = document.createElement('label');
    label.title = 'How frames are drawn: visibility (EWA splatting of the points) or gaussian (3D Gaussian splats, as the server\'s gaussian render)';
    label.append('Render ');
    const sel = document.createElement('select');
    sel.id = 'render-mode';
    for (const m of ['visibility', 'gaussian']) {
      const o = document.createElement('option');
      o.value = m;
      o.textContent = m;
      sel.append(o);
    }
    sel.addEventListener('change', () => this.setMode(sel.value).catch((e) => this.app.showError(e)));
    label.append(sel);
    const ds = document.getElementById('dataset')?.closest('label');
    if (ds) ds.after(label); else bar.append(label);
    this.select = sel;
  }

  // The mode a dataset opens in (before its first query).
  chooseFor(info) {
    this.apply(this.chosen || (info.gaussians ? 'gaussian' : 'visibility'));
  }

  apply(mode) {
    this.mode = mode;
    if (this.select) this.select.value = mode;
    const a = this.app;
    if (a.store) a.store.encoding = this.active || a.params.encoding !== 'hvdb7' ? 'COLUMNS' : 'HVDB7';
    if (this.active) this.ensureRenderer();
    else if (a.store) a.store.capacity = 24;  // fitCache's, for Gaussian frames
  }

  // The user's choice: frames cached without the columns the records need are queried anew.
  async setMode(mode) {
    if (!['gaussian', 'visibility'].includes(mode)) throw new Error(`render mode: gaussian or visibility, not "${mode}"`);
    this.chosen = mode;
    if (mode === this.mode) return;
    this.apply(mode);
    const a = this.app;
    a.player.stop();
    if (this.active && a.info) {
      a.store.invalidate();
      await a.showCurrent();
    } else {
      a.requestDraw();
    }
  }

  ensureRenderer() {
    if (this.renderer) return this.renderer;
    this.renderer = new GaussianRenderer(this.app.renderer);
    this.renderer.background = this.app.renderer.background;
    this.worker = new Worker(new URL('./gaussian_sort_worker.js', import.meta.url), { type: 'module' });
    this.worker.onmessage = (ev) => this.onSorted(ev.data);
    this.worker.onerror = (ev) => {
      ev.preventDefault();
      this.app.showError(new Error(`gaussian sort worker failed: ${ev.message || 'could not start'}`));
    };
    return this.renderer;
  }

  // FrameStore hooks. collect: a batch's columns (kept while the mode is on); loaded: its query
  // is done; release: it is disposed.
  collect(d, cols, n) {
    if (!this.active) return;
    const c = d.gcols || (d.gcols = { n: 0, ids: [], covariance: [], color: [], flags: [], missing: false });
    c.n += n;
    if (!cols.id) c.missing = true;
    else c.ids.push(cols.id.slice(0, 2 * n));
    // Columns a batch lacks as renderer.js createChunk reads them: grey, no covariance.
    c.covariance.push(cols.covariance ? cols.covariance.slice(0, 6 * n) : new Float32Array(6 * n));
    c.color.push(cols.color ? cols.color.slice(0, 3 * n) : new Uint8Array(3 * n).fill(204));
    c.flags.push(cols.flags ? cols.flags.slice(0, n) : new Uint8Array(n).fill(cols.covariance ? 2 : 0));
  }

  loaded(d) {
    // A frame queried before the mode was on lacks the ids: setMode queries it anew.
    if (!this.active || d.gauss || (d.points > 0 && !d.gcols)) return;
    this.prepare(d).catch((e) => {
      // A failed read (a transient error, OVERLOADED) is tried again when the frame is next
      // wanted: its columns are kept until the records are in.
      if (d.gauss && !d.gauss.ready) d.gauss = null;
      if (!d.disposed && (d === this.app.target || d === this.app.shown)) this.app.showError(e, `gaussian records of ${d.key}`);
    });
  }

  release(d) {
    d.gcols = null;
    const g = d.gauss;
    if (!g || g.disposed) return;
    g.disposed = true;
    this.wanting.delete(g);
    this.live.delete(g);
    if (g.frame) this.renderer.deleteFrame(g.frame);
    if (g.sent) this.worker.postMessage({ type: 'drop', id: g.id });
    if (this.drawn === d) this.drawn = null;
  }

  // Whether the store must keep `d` (it is the picture on screen).
  holds(d) { return this.active && d === this.drawn; }

  isReady(d) { return !!(d && !d.disposed && d.gauss && d.gauss.ready && !d.gauss.disposed); }

  // For playback: `d` can be shown now (in visibility mode: always); starts its preparation.
  drawable(d) {
    if (!this.active) return true;
    if (this.isReady(d)) return true;
    if (d.done && !d.gauss) this.loaded(d);
    return false;
  }

  // Resolves with `d` once its records are on the GPU and it has an order (idempotent).
  prepare(d) {
    if (d.gauss) return d.gauss.promise;
    const a = this.app;
    const dataset = a.dataset, gaussians = !!a.info?.gaussians;
    const g = { id: nextId++, d, frame: null, orderKey: null, ready: false, disposed: false, sent: false, waiters: [] };
    d.gauss = g;
    g.promise = (async () => {
      await d.promise;
      const n = d.points;
      const c = d.gcols || { n: 0, ids: [], covariance: [], color: [], flags: [], missing: false };
      if (g.disposed) return d;
      if (c.n !== n || c.missing) throw new Error('frame loaded without its point ids (reload it in gaussian mode)');
      const cols = {
        positions: concat(d.positions, Float32Array),
        ids: concat(c.ids, Uint32Array),
        covariance: concat(c.covariance, Float32Array),
        color: concat(c.color, Uint8Array),
        flags: concat(c.flags, Uint8Array),
        labels: concat(d.labels, Uint32Array),
      };
      const t0 = performance.now();
      const parts = gaussians && n ? await readGaussians(a.conn, dataset, cols.ids, n, () => !g.disposed) : [];
      if (g.disposed) return d;
      const t1 = performance.now();
      const r = this.ensureRenderer();
      const packed = packSplats(cols, parts, n, r.texWidth);
      g.frame = r.createFrame(packed);
      d.gcols = null;  // the records are in: the columns are not needed again
      g.stored = packed.stored;
      this.stats.lastRecordsMs = t1 - t0;
      this.stats.lastPackMs = performance.now() - t1;
      this.live.add(g);
      this.fitCache();
      this.worker.postMessage({ type: 'frame', id: g.id, positions: cols.positions }, [cols.positions.buffer]);
      g.sent = true;
      await this.sortFor(g, depthOf(a.cam.camera(a.canvas.width, a.canvas.height)));
      if (g.disposed) return d;
      g.ready = true;
      if (d === a.shown || d === a.target) a.requestDraw();
      return d;
    })();
    g.promise.catch(() => {});
    return g.promise;
  }

  // Fewer cached frames when frames are large (at least 4: the one shown and a few ahead).
  fitCache() {
    let bytes = 0;
    for (const g of this.live) bytes += g.frame.bytes;
    const per = bytes / Math.max(1, this.live.size);
    this.app.store.capacity = Math.max(4, Math.min(24, Math.floor(kBudgetBytes / Math.max(1, per))));
    this.app.store.evict();
  }

  // Resolves once g has an order (for `view`, or for the view before it while the camera moves),
  // asked of the worker one sort at a time; the frame on screen goes first.
  sortFor(g, view) {
    return new Promise((resolve) => {
      g.waiters.push(resolve);
      this.requestSort(g, view);
    });
  }

  requestSort(g, view) {
    if (g.disposed) return;
    g.want = view;
    if (g.orderKey === view.key && !(this.inFlight && this.inFlight.g === g)) {
      this.settleWaiters(g);
      return;
    }
    this.wanting.add(g);
    this.pump();
  }

  pump() {
    if (this.inFlight || !this.wanting.size) return;
    const a = this.app;
    let g = null;
    for (const h of this.wanting) {
      if (h.d === a.shown || h.d === a.target) { g = h; break; }
    }
    g = g || this.wanting.values().next().value;
    this.wanting.delete(g);
    const view = g.want;
    if (g.orderKey === view.key) {
      this.settleWaiters(g);
      this.pump();
      return;
    }
    this.inFlight = { g, view, seq: ++this.seq };
    this.worker.postMessage({ type: 'sort', id: g.id, seq: this.seq, r: view.r, t: view.t, near: kNearZ });
  }

  onSorted(msg) {
    const f = this.inFlight;
    if (!f || msg.seq !== f.seq) return;
    this.inFlight = null;
    const g = f.g;
    if (!g.disposed && msg.order) {
      this.renderer.setOrder(g.frame, msg.order);
      g.orderKey = f.view.key;
      this.stats.sorts++;
      this.stats.lastSortMs = msg.ms;
      if (g.want && g.want.key !== g.orderKey) this.wanting.add(g);  // the camera moved meanwhile
      this.settleWaiters(g);  // any order makes the frame drawable (settle() wants the view's)
      const a = this.app;
      if (g.ready && (g.d === a.shown || g.d === this.drawn)) a.requestDraw();
    }
    this.pump();
  }

  settleWaiters(g) {
    const w = g.waiters;
    g.waiters = [];
    for (const r of w) r();
  }

  // Draws the frame on screen if drawable, else the last one drawn. Returns the splats drawn.
  draw(shown, cam, opts) {
    const r = this.ensureRenderer();
    if (shown && !shown.disposed && shown.done && !shown.gauss) this.loaded(shown);
    let d = this.isReady(shown) ? shown : null;
    if (!d && this.isReady(this.drawn)) d = this.drawn;
    if (!d) {
      if (!this.drawn) r.draw(null, cam, opts);  // nothing yet: the background
      return 0;
    }
    const view = depthOf(cam);
    if (d.gauss.orderKey !== view.key) this.requestSort(d.gauss, view);
    const n = r.draw(d.gauss.frame, cam, opts);
    if (this.drawn !== d) {
      this.drawn = d;
      this.app.store.sweep();  // the frame drawn before may be retired
    }
    return n;
  }

  // Resolves once the frame drawn has an order for the current camera (tests, stills).
  async settle() {
    const a = this.app;
    for (let k = 0; k < 50 && this.active; ++k) {
      const d = this.isReady(a.shown) ? a.shown : (this.isReady(this.drawn) ? this.drawn : null);
      if (!d) return;
      const view = depthOf(a.cam.camera(a.canvas.width, a.canvas.height));
      if (d.gauss.orderKey === view.key) return;
      await this.sortFor(d.gauss, view);
    }
  }

  // The server render's fields (Render still, sequence, video): the page's mode. Shadows are
  // the points' (the server refuses them in gaussian mode); a plain dataset in visibility mode
  // keeps auto (its photos or billboards where it has them).
  renderFields() {
    const shadows = !!this.app.exporter?.shadows;
    if (this.active && !shadows) return { mode: 'RENDER_GAUSSIAN' };
    return this.active || this.app.info?.gaussians ? { mode: 'RENDER_VISIBILITY' } : {};
  }

  info() {
    const d = this.drawn, g = d && d.gauss;
    const r = this.renderer;
    return {
      mode: this.mode,
      frame: d ? d.frame : null,
      splats: g && g.frame ? g.frame.n : 0,
      drawn: g && g.frame ? g.frame.count : 0,
      stored: g ? g.stored : 0,
      degree: g && g.frame ? g.frame.degree : null,
      accumulation: r ? r.accumFormat : null,
      primitive: r ? (r.sprites ? 'sprites' : 'quads') : null,
      maxPointSize: r ? r.maxPointSize : null,
      framesOnGpu: this.live.size,
      ...this.stats,
    };
  }
}
