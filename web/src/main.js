// The hvdb viewer: wires the connection, renderer, frame store, player, editor and UI
// together, reads the URL parameters and exposes window.hvdbApp (the test hooks).
//   /?dataset=NAME&t=SECONDS&look_at=EX,EY,EZ,TX,TY,TZ&fov=DEG&size=WxH&lod=N&token=T
//     &renderer=points&splats=sprites|quads&bit=N&live=1&mode=gaussian|visibility
// The token may also be given as #token=T (a fragment is not sent to servers nor logged).
import { Connection, frameWindow, allTimeWindow, sliceRegion } from './connection.js';
import { ViewCamera, NavigationController, wireCamera, DEFAULT_UP } from './camera.js';
import { SplatRenderer } from './renderer.js';
import { FrameStore, Player, decodeFlips } from './player.js';
import { Editor } from './editor.js';
import { UI } from './ui.js';
import { Live } from './live.js';
import { SliceTool } from './slice_tool.js';
import { Transformer } from './transform.js';
import { Gizmo } from './gizmo.js';
import { editingHooks } from './transform.js';
import { MediaImport } from './media_import.js';
import { RenderExport } from './render_export.js';
import { Hvdb7Decoder } from './hvdb7.js';
import { GaussianMode } from './gaussian_mode.js';

function parseParams() {
  const q = new URLSearchParams(location.search);
  const nums = (s, n, what) => {
    const v = s.split(',').map(Number);
    if (v.length !== n || v.some((x) => !Number.isFinite(x))) throw new Error(`URL parameter ${what}: expected ${n} comma-separated numbers, got "${s}"`);
    return v;
  };
  const p = {
    dataset: q.get('dataset') || '',
    t: q.has('t') ? Number(q.get('t')) : 0,
    lookAt: q.has('look_at') ? nums(q.get('look_at'), 6, 'look_at') : null,
    fov: q.has('fov') ? Number(q.get('fov')) : 40,
    size: null,
    lod: q.has('lod') ? Number(q.get('lod')) : 0,
    token: new URLSearchParams(location.hash.replace(/^#/, '')).get('token') || q.get('token') || '',
    renderer: q.get('renderer') === 'points' ? 'points' : 'splats',
    splats: ['sprites', 'quads'].includes(q.get('splats')) ? q.get('splats') : 'auto',
    bit: q.has('bit') ? Number(q.get('bit')) : 0,
    live: ['1', 'true', 'yes'].includes(q.get('live')),
    // How query batches travel (web/README.md): columns (packed columns as stored) or hvdb7
    // (a fifth of the bytes, decoded in workers). Columns by default: on loopback and two
    // shared cores hvdb7's coding costs more time than its bytes save (bench/README.md).
    encoding: (q.get('encoding') || 'columns').toLowerCase(),
    // gaussian: 3DGS splats (gaussian_mode.js); default: gaussian on a Gaussian-splat dataset.
    mode: (q.get('mode') || '').toLowerCase(),
  };
  if (!['', 'gaussian', 'visibility'].includes(p.mode)) throw new Error(`URL parameter mode: gaussian or visibility, got "${q.get('mode')}"`);
  if (!['hvdb7', 'columns'].includes(p.encoding)) throw new Error(`URL parameter encoding: hvdb7 or columns, got "${q.get('encoding')}"`);
  if (q.has('size')) {
    const m = /^(\d+)x(\d+)$/.exec(q.get('size'));
    if (!m) throw new Error(`URL parameter size: expected WxH, got "${q.get('size')}"`);
    p.size = [Number(m[1]), Number(m[2])];
  }
  if (!Number.isFinite(p.t)) throw new Error('URL parameter t: not a number');
  if (!(p.fov > 0 && p.fov < 180)) throw new Error('URL parameter fov: must be in (0, 180) degrees');
  if (!Number.isInteger(p.lod) || p.lod < 0) throw new Error('URL parameter lod: a level >= 0');
  if (!Number.isInteger(p.bit) || p.bit < 0 || p.bit > 31) throw new Error('URL parameter bit: 0..31');
  return p;
}

// The next animation frame; a page that is hidden or occluded gets none (browsers stop them),
// so a timer settles it as well: nothing waiting for a picture can hang on that.
const nextFrame = () => new Promise((r) => {
  const timer = setTimeout(r, 100);
  requestAnimationFrame(() => { clearTimeout(timer); r(); });
});

class App {
  constructor(params) {
    this.params = params;
    this.canvas = document.getElementById('view');
    this.overlayCanvas = document.getElementById('overlay-canvas');
    this.viewport = document.getElementById('viewport');
    this.metrics = { firstPictureMs: null, firstFrameMs: null, playFps: 0, framesShown: 0, lastQueryMs: null };
    this.lastSelect = null;
    this.lastEditMs = null;
    this.dataset = '';
    this.info = null;
    this.frame = 0;
    this.lod = params.lod;
    this.bit = params.bit;
    this.overlay = true;
    this.box = null;
    this.viewMode = 'frames';
    this.slice = null;
    this.shown = null;    // the FrameData on screen
    this.target = null;   // the FrameData being loaded for the screen (drawn as it arrives)
    this.drawPending = false;
    this.firstQueryAt = null;
    this.cam = new ViewCamera();
    this.cam.fovDeg = params.fov;
    this.ui = null;
    this.sequence = null;
    this.live = new Live(this);  // live mode (the Live button, ?live=1)
  }

  async start() {
    this.setupCanvas();
    this.renderer = new SplatRenderer(this.canvas, { mode: this.params.renderer, primitive: this.params.splats });
    this.gaussian = new GaussianMode(this);  // the "gaussian" render mode
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    const hvdb7 = this.params.encoding === 'hvdb7';
    this.conn = new Connection(`${scheme}://${location.host}/ws`, {
      token: this.params.token,
      capabilities: hvdb7 ? ['hvdb7'] : [],
      onState: (state, detail) => this.onConnState(state, detail),
    });
    this.store = new FrameStore(this.conn, this.renderer, {
      capacity: 24,
      onBatch: (d) => this.onBatch(d),
      onError: (err, d) => { if (err.code !== 'CANCELLED' && err.code !== 'CLOSED') this.showError(err, `query of ${d.key}`); },
      inUse: (d) => d === this.shown || d === this.target || this.gaussian.holds(d),
      onReplace: (old, fresh) => this.onReplace(old, fresh),
      encoding: hvdb7 ? 'HVDB7' : 'COLUMNS',
      decoder: hvdb7 ? new Hvdb7Decoder() : null,
      onColumns: (d, cols, n) => this.gaussian.collect(d, cols, n),
      onLoaded: (d) => this.gaussian.loaded(d),
      onDispose: (d) => this.gaussian.release(d),
    });
    this.watchContext();
    this.player = new Player(this);
    this.editor = new Editor(this, this.canvas, this.overlayCanvas);
    this.nav = new NavigationController(this.canvas, this.cam, {
      shouldNavigate: (e) => !this.editor.wantsPointer(e),
      onChange: () => this.requestDraw(true),
    });
    this.sliceTool = new SliceTool(this);
    this.transformer = new Transformer(this);
    this.gizmo = new Gizmo(this, this.transformer);
    this.preview = null;  // a pending transform's preview: {m, t} of the displayed space
    this.ui = new UI(this);
    this.mediaImport = new MediaImport(this);
    this.exporter = new RenderExport(this);  // the Shadows toggle, Render video
    this.editor.setTool('navigate');
    this.editor.setMode('SELECT_REPLACE');
    if (this.renderer.mode === 'points') this.setStatus('edit', `point renderer${this.renderer.fallbackReason ? ` (${this.renderer.fallbackReason})` : ''}`);
    else if (this.renderer.software) this.setStatus('edit', `software WebGL (${this.renderer.rendererName.slice(0, 60)}): half resolution while moving or playing`);
    await this.conn.open();
    const list = await this.conn.request({ list: {} });
    const names = list.datasets?.names || [];
    if (!names.length) throw new Error('the server has no datasets');
    const name = this.params.dataset || names[0];
    if (!names.includes(name)) throw new Error(`dataset "${name}" is not on the server (it has: ${names.join(', ')})`);
    this.ui.setDatasets(names, name);
    await this.openDataset(name, true);
    if (this.params.live) await this.live.start();
  }

  onConnState(state, detail) {
    if (state === 'closed') {
      this.player?.stop();
      this.setStatus('conn', `disconnected: ${detail} (reload the page)`, state);
      this.showError(new Error(`server connection closed: ${detail}; reload the page to reconnect`));
      return;
    }
    if (this.conn && !this.conn.isOpen && state === 'error') this.player?.stop();
    this.setStatus('conn', `${state}${detail ? `: ${detail}` : ''}`, state);
    if (state === 'error') this.showError(new Error(`server connection error: ${detail}`));
  }

  // A lost WebGL context (GPU reset, driver update, too many contexts) draws nothing more:
  // say so; preventDefault lets the browser restore it, and a restored context starts afresh.
  watchContext() {
    this.canvas.addEventListener('webglcontextlost', (e) => {
      e.preventDefault();
      this.contextLost = true;
      this.player?.stop();
      this.showError(new Error('the GPU context was lost; reload the page'));
      this.setStatus('points', 'GPU context lost', 'error');
    });
    this.canvas.addEventListener('webglcontextrestored', () => location.reload());
  }

  setupCanvas() {
    const size = this.params.size;
    if (size) {
      this.viewport.classList.add('fixed');
      this.viewport.style.width = `${size[0]}px`;
      this.viewport.style.height = `${size[1]}px`;
    }
    const fit = () => {
      const dpr = window.devicePixelRatio || 1;
      const w = size ? size[0] : this.viewport.clientWidth, h = size ? size[1] : this.viewport.clientHeight;
      const bw = Math.max(1, Math.round(w * dpr)), bh = Math.max(1, Math.round(h * dpr));
      for (const c of [this.canvas, this.overlayCanvas]) {
        c.style.width = `${w}px`;
        c.style.height = `${h}px`;
        if (c.width !== bw || c.height !== bh) { c.width = bw; c.height = bh; }
      }
      this.requestDraw();
    };
    fit();
    new ResizeObserver(fit).observe(this.viewport);
    window.addEventListener('resize', fit);
  }

  async openDataset(name, initial = false) {
    this.player.stop();
    const wasLive = this.live.on && name !== this.dataset;
    if (wasLive) this.live.stop();
    const reply = await this.conn.request({ describe: { dataset: name } });
    this.info = reply.info;
    this.info.fps = Number(this.info.fps) || 30;
    this.info.frame_count = Number(this.info.frame_count) || 0;
    if (name !== this.dataset) {
      this.editor.resetHistory();  // LSNs are per dataset
      this.stopSequence();
    }
    this.dataset = name;
    this.shown = this.target = null;
    this.store.reset();
    this.gaussian.chooseFor(this.info);
    this.viewMode = 'frames';
    this.ui.setFrameRange(this.info.frame_count);
    // The slider's range is the dataset's (its coarsest level, learned from the first batch).
    this.ui.setLodRange(this.lodMax(), this.lod);
    const p = this.params;
    if (initial && p.lookAt) {
      this.cam.set(p.lookAt.slice(0, 3), p.lookAt.slice(3, 6), p.fov, DEFAULT_UP);
    } else if (this.info.bounds_min?.length === 3) {
      this.cam.frameBounds(this.info.bounds_min.map(Number), this.info.bounds_max.map(Number), initial ? p.fov : this.cam.fovDeg, this.canvas.width / this.canvas.height);
    }
    const f = initial ? this.frameAt(p.t) : 0;
    this.firstQueryAt = performance.now();
    const firstQueryAt = this.firstQueryAt;
    await this.gotoFrame(f);
    if (initial) this.metrics.firstFrameMs = performance.now() - firstQueryAt;
    if (wasLive) await this.live.start();  // live mode follows the dataset chosen
  }

  frameAt(t) {
    const n = this.info.frame_count;
    return Math.min(Math.max(0, Math.round(t * this.info.fps)), Math.max(0, n - 1));
  }

  frameKey(f) { return FrameStore.frameKey(this.dataset, f, this.lod, this.box); }

  currentKey() {
    if (this.viewMode === 'slice') return `${this.dataset}|slice|${JSON.stringify(this.slice)}|l${this.lod}|${JSON.stringify(this.box)}`;
    return this.frameKey(this.frame);
  }

  // The region shown: the current frame's window (within the box), or the slice.
  currentRegion() {
    if (this.viewMode === 'slice') {
      const r = sliceRegion(this.slice.normal, this.slice.offset, this.slice.thickness);
      const times = this.slice.times;  // the timeline's in / out points (slice_tool.js)
      if (this.box || times) r.slice.clip = allTimeWindow(this.box).window;
      if (times) { r.slice.clip.lo[3] = times[0]; r.slice.clip.hi[3] = times[1]; }
      return r;
    }
    return frameWindow(this.frame / this.info.fps, this.box);
  }

  loadSpec() {
    return { dataset: this.dataset, frame: this.viewMode === 'slice' ? -1 : this.frame, region: this.currentRegion(), lod: this.lod };
  }

  // Shows frame i (drawn progressively as its batches arrive); resolves once it is complete
  // and drawn.
  async gotoFrame(i) {
    if (!this.info) throw new Error('no dataset open');
    const n = this.info.frame_count;
    if (!Number.isInteger(i) || i < 0 || i >= Math.max(1, n)) throw new Error(`frame ${i} is outside 0..${n - 1}`);
    if (this.viewMode !== 'frames') {
      this.sliceTool.restoreView();
      this.viewMode = 'frames';
    }
    this.frame = i;
    return this.showCurrent();
  }

  async showCurrent() {
    const key = this.currentKey();
    const d = this.store.load(key, this.loadSpec());
    this.target = d;
    this.store.pinned = new Set([key]);
    this.ui.setFrame(this.frame, this.info.frame_count, this.info.fps, this.viewMode === 'slice');
    if (d.chunks.length || d.done) this.shown = d;
    this.store.sweep();
    this.requestDraw();
    try {
      await d.promise;
    } catch (e) {
      if (this.target !== d) return d;  // superseded (a CANCELLED of a load nobody waits for)
      throw e;
    }
    if (this.target !== d) return d;  // superseded by a later request
    if (this.gaussian.active) {  // drawn once its records are in
      try {
        await this.gaussian.prepare(d);
      } catch (e) {
        if (this.target !== d) return d;
        throw e;
      }
      if (this.target !== d) return d;
    }
    // Following a live capture on a software rasteriser: drawn at playback's resolution, as
    // playing is (the page keeps up with the frames; a pause draws the still at full size).
    const following = this.live.on && this.live.following;
    this.showFrameData(d, this.frame, true, following ? this.playResolution : 1);
    await nextFrame();
    if (this.viewMode === 'frames') this.player.prefetch(this.frame, 2);
    return d;
  }

  onBatch(d) {
    if (this.store.maxLevel !== null) this.ui.setLodRange(this.lodMax(), this.lod);
    // A reload after an edit keeps the old picture until the new one is complete.
    if (d !== this.target || d.quiet) return;
    this.shown = d;
    // The coarse levels as they come (the first picture at once); with a software rasteriser
    // only that first one: the complete frame is drawn when its query is done.
    if (d.drawnBatches && this.renderer.software) return;
    d.drawnBatches = true;
    this.requestDraw();
  }

  // immediate: draw now (the caller needs the picture) instead of on the next animation frame;
  // at `resolution` of the canvas size (playback on a software rasteriser: 0.5).
  showFrameData(d, f, immediate = false, resolution = 1) {
    this.shown = d;
    this.target = d;
    if (f >= 0) this.frame = f;
    this.store.pinned = new Set([d.key]);
    this.store.sweep();
    if (d.done) this.metrics.lastQueryMs = d.loadMs;
    this.ui.setFrame(this.frame, this.info.frame_count, this.info.fps, this.viewMode === 'slice');
    if (this.live.on) this.live.updateUi();
    if (immediate) this.drawNow(resolution); else this.requestDraw();
  }

  stepFrame(delta) {
    this.player.stop();
    this.live.userSeek();
    const n = this.info.frame_count;
    return this.gotoFrame(((this.frame + delta) % n + n) % n);
  }

  // The coarsest level the slider offers: the dataset's, once a batch has said it; until then
  // the level shown (a level past the dataset's is the server's to refuse, with its range).
  lodMax() {
    return this.store.maxLevel !== null ? this.store.maxLevel : this.lod;
  }

  async setLod(l) {
    const lod = this.store.maxLevel !== null ? Math.min(Math.max(0, l), this.store.maxLevel) : Math.max(0, l);
    this.ui.setLodRange(Math.max(this.lodMax(), lod), lod);
    if (lod === this.lod) return;
    this.lod = lod;
    await this.showCurrent();
  }

  async setBox(box) {
    this.box = box;
    this.ui.setBoxInputs(box);
    await this.showCurrent();
  }

  // times: [t0, t1] seconds the slice is clipped to (in / out points), or null.
  async showSlice(normal, offset, thickness, times = null) {
    this.player.stop();
    this.slice = { normal, offset, thickness, times };
    this.viewMode = 'slice';
    await this.showCurrent();
  }

  async showFrames() {
    this.sliceTool.restoreView();
    this.viewMode = 'frames';
    await this.showCurrent();
  }

  setOverlay(on) {
    this.overlay = on;
    this.ui.setOverlay(on);
    this.requestDraw();
  }

  // After an edit every cached frame may be stale: re-query what is on screen (keeping the
  // old picture until the new one is complete), drop the rest (prefetch reloads them). Of
  // several reloads of a key only the newest replaces the cached entry (FrameStore.reload).
  // `labelFlips` ({flips, mask}: a select's reply): the frame on screen takes the new labels in
  // place instead (FrameData.applyFlips), where it can.
  async refreshAfterEdit(labelFlips = null) {
    const key = this.currentKey();
    if (labelFlips && this.refreshLabels(key, labelFlips)) {
      await nextFrame();
      return { loadMs: null, labelOnly: true };
    }
    this.store.invalidate(new Set([key]));
    const d = this.store.reload(key, this.loadSpec());
    const fresh = await d.promise;
    if (fresh.superseded) return null;  // a later edit's reload (or another dataset) took over
    if (this.currentKey() === key && this.store.map.get(key) === fresh) {
      // An edit's result is drawn as a move is: at once, at half resolution on a software
      // rasteriser (a full draw of 75k splats takes it ~300 ms), and in full once it rests.
      this.showFrameData(fresh, this.viewMode === 'slice' ? -1 : this.frame, true, this.playResolution);
      if (this.renderer.software) {
        clearTimeout(this.settleTimer);
        this.settleTimer = setTimeout(() => this.requestDraw(), 250);
      }
      await nextFrame();
    }
    if (this.viewMode === 'frames') this.player.prefetch(this.frame, 2);
    return fresh;
  }

  // A select's label-only refresh of the frame on screen: no query, no upload of positions.
  // Other cached views are dropped, as after any edit (prefetch reloads them). False: the
  // caller refreshes by querying (a slice, the gaussian mode's own records, a view still
  // loading or without ids).
  refreshLabels(key, { flips, mask }) {
    if (this.viewMode !== 'frames' || this.gaussian.active) return false;
    const d = this.store.map.get(key);
    if (!d || this.shown !== d || d.stale || this.store.reloads.has(key)) return false;
    let decoded;
    try {
      decoded = decodeFlips(flips);
    } catch (e) {
      // The commit is done: a reply whose flips do not decode costs a re-query, not the view.
      console.warn(`label-only refresh: ${e.message}; querying the frame again`);
      return false;
    }
    if (!decoded || !d.applyFlips(decoded, mask, this.renderer)) return false;
    this.store.invalidate(new Set([key]));
    this.showFrameData(d, this.frame, true, 1);
    this.player.prefetch(this.frame, 2);
    return true;
  }

  // A reload replaced `old` in the cache: if the page shows (or waits for) it, it shows the
  // fresh data instead (so `old` can be disposed).
  onReplace(old, fresh) {
    let changed = false;
    if (this.target === old) { this.target = fresh; changed = true; }
    if (this.shown === old) { this.shown = fresh; changed = true; }
    if (changed) this.requestDraw();
  }

  wireCamera() { return wireCamera(this.cam.camera(this.canvas.width, this.canvas.height)); }

  // Coalesces redraws into one per animation frame; a drawNow() in between makes it moot
  // (drawing 75k splats is the expensive part on software GL). `moving`: the camera is being
  // dragged; a software rasteriser then draws at half resolution, and at full resolution once
  // the view has rested for a moment.
  requestDraw(moving = false) {
    this.dirty = true;
    if (moving && this.renderer?.software) {
      this.dirtyRes = 0.5;
      clearTimeout(this.settleTimer);
      this.settleTimer = setTimeout(() => this.requestDraw(), 250);
    }
    if (this.drawPending) return;
    this.drawPending = true;
    requestAnimationFrame(() => {
      this.drawPending = false;
      if (!this.dirty) return;
      const res = this.dirtyRes || 1;
      this.dirtyRes = 0;
      try {
        this.drawNow(res);
      } catch (e) {
        this.showError(e);
      }
    });
  }

  // The resolution playback draws at: half on a software rasteriser.
  get playResolution() { return this.renderer?.software ? 0.5 : 1; }

  drawNow(resolution = 1) {
    this.dirty = false;
    if (!this.renderer || this.contextLost) return 0;
    const cam = this.cam.camera(this.canvas.width, this.canvas.height);
    const d = this.shown;
    const layers = d && !d.disposed ? [d.layer] : [];
    const opts = { selMask: (1 << this.bit) >>> 0, overlay: this.overlay, zFar: this.zFar(d), resolution, preview: this.preview };
    const n = this.gaussian.active ? this.gaussian.draw(d, cam, opts) : this.renderer.draw(layers, cam, opts);
    if (this.editor?.tool === 'transform' && (!this.editor.drag || this.editor.drag.gizmo)) this.editor.clearOverlay();  // the gizmo follows
    // A frame's first picture (its coarsest level, when it comes progressively): live mode's
    // "on screen" (window.hvdbLive.onScreen[].firstDrawnWall).
    // (In gaussian mode the frame before stays on screen until this one's records are in.)
    if (n > 0 && d && d.firstDrawnWall === undefined && (!this.gaussian.active || this.gaussian.drawn === d)) {
      d.firstDrawnWall = Date.now();
      d.firstDrawnMs = performance.now();
    }
    if (n > 0 && this.metrics.firstPictureMs === null && this.firstQueryAt !== null) {
      this.metrics.firstPictureMs = performance.now() - this.firstQueryAt;
    }
    this.setStatus('points', `${n.toLocaleString()} ${this.gaussian.active ? 'splats' : 'points'}${d && !d.done ? ' (loading)' : ''}`);
    if (this.info) this.setStatus('frame', this.viewMode === 'slice' ? 'slice' : `frame ${this.frame}`);
    if (d?.done) this.setStatus('query', `query ${d.loadMs.toFixed(0)} ms`);
    if (this.player?.playing) this.setStatus('fps', `${this.metrics.playFps.toFixed(1)} fps`);
    return n;
  }

  // Far end of the linear depth mapping: beyond the farthest corner of the points' box.
  zFar(d) {
    if (!d || !(d.bboxLo[0] <= d.bboxHi[0])) return 1000;
    let far = 0;
    for (let i = 0; i < 8; ++i) {
      const c = [i & 1 ? d.bboxHi[0] : d.bboxLo[0], i & 2 ? d.bboxHi[1] : d.bboxLo[1], i & 4 ? d.bboxHi[2] : d.bboxLo[2]];
      far = Math.max(far, Math.hypot(c[0] - this.cam.eye[0], c[1] - this.cam.eye[1], c[2] - this.cam.eye[2]));
    }
    return far * 1.5 + 1;
  }

  renderView() {
    return {
      look_at: {
        eye: this.cam.eye.slice(), target: this.cam.target.slice(), up: this.cam.up.slice(),
        fov_y_deg: this.cam.fovDeg, width: this.canvas.width, height: this.canvas.height,
      },
    };
  }

  async renderStill() {
    this.setStatus('edit', 'server render…');
    const reply = await this.conn.request({
      render: { dataset: this.dataset, region: this.currentRegion(), lod: this.lod, view: this.renderView(), renderer: 'RENDERER_CPU', ...this.exporter.shadowFields(), ...this.gaussian.renderFields() },
    });
    const png = reply.sections.png;
    if (!png) throw new Error('render reply without a png section');
    const url = await blobToDataUrl(new Blob([png], { type: 'image/png' }));
    const r = reply.render;
    // The server picks the frame's best picture (textured where it has photos) and says which.
    this.ui.showRender(url, `${r.width}×${r.height}, ${r.mode_used} (${r.mode_choice}), ${r.renderer_used}, ${Number(r.render_ms).toFixed(0)} ms, ${r.points} points, lod ${r.lod}`);
    this.setStatus('edit', `server render: ${r.mode_used}, ${Number(r.render_ms).toFixed(0)} ms`);
    return { png: url, reply };
  }

  // Every frame from the current camera, rendered by the server, then played as images.
  // Closing the panel (stopSequence) or starting another sequence cancels it.
  async renderSequence() {
    this.stopSequence();
    const n = this.info ? this.info.frame_count : 0;
    if (!(n > 0)) throw new Error('render sequence: the dataset has no frames');
    const view = this.renderView();
    const req = { render: { dataset: this.dataset, lod: this.lod, path: Array.from({ length: n }, () => view), frames: Array.from({ length: n }, (_, i) => i), renderer: 'RENDERER_CPU', ...this.gaussian.renderFields() } };
    if (this.box) req.render.region = allTimeWindow(this.box);
    const seq = { images: new Array(n), frames: [], timer: 0, requestId: 0, done: false, stopped: false };
    this.sequence = seq;
    let got = 0;
    this.setStatus('edit', `rendering ${n} frames…`);
    try {
      await this.conn.request(req, {
        onId: (id) => { seq.requestId = id; },
        onPart: (part) => {
          const png = part.sections.png;
          if (!png || seq.stopped) return;
          const i = Number(part.response.render.index || 0);
          if (seq.images[i]) URL.revokeObjectURL(seq.images[i]);
          seq.images[i] = URL.createObjectURL(new Blob([png], { type: 'image/png' }));
          this.setStatus('edit', `rendered ${++got} / ${n}`);
        },
      });
    } catch (e) {
      seq.done = true;
      if (seq.stopped) return { frames: 0, cancelled: true };
      this.stopSequence();
      throw e;
    }
    seq.done = true;
    if (seq.stopped) return { frames: 0, cancelled: true };
    const frames = seq.images.filter(Boolean);
    seq.frames = frames;
    if (!frames.length) {
      this.stopSequence();
      throw new Error('render sequence: the server sent no images');
    }
    let i = 0;
    const show = () => {
      this.ui.showRender(frames[i], `sequence: frame ${i + 1} / ${frames.length} (server CPU render)`);
      i = (i + 1) % frames.length;
    };
    show();
    seq.timer = setInterval(show, 1000 / (this.info.fps || 30));
    return { frames: frames.length };
  }

  // Stops the sequence shown or being rendered: cancels its request, frees its images.
  stopSequence() {
    const seq = this.sequence;
    if (!seq) return;
    this.sequence = null;
    seq.stopped = true;
    clearInterval(seq.timer);
    if (!seq.done && seq.requestId) this.conn.cancel(seq.requestId);
    for (const u of seq.images) if (u) URL.revokeObjectURL(u);
    seq.images = [];
    seq.frames = [];
  }

  setStatus(field, text, cls) { if (this.ui) this.ui.setStatus(field, text, cls); }

  showError(err, context = '') {
    const msg = `${context ? `${context}: ` : ''}${err && err.message ? err.message : String(err)}`;
    console.error('hvdb:', msg, err);
    this.lastError = msg;
    this.setStatus('error', msg);
  }
}

function blobToDataUrl(blob) {
  return new Promise((resolve, reject) => {
    const r = new FileReader();
    r.onload = () => resolve(r.result);
    r.onerror = () => reject(r.error);
    r.readAsDataURL(blob);
  });
}

// ---- window.hvdbApp: the hooks the browser tests use. ----
function exposeHooks(app, ready) {
  window.hvdbApp = {
    app,
    ready,
    metrics: app.metrics,
    get lastSelect() { return app.lastSelect; },
    get lastEditMs() { return app.lastEditMs; },
    get lastRequest() { return app.lastRequest || null; },
    get lastEditPhases() { return app.lastEditPhases || null; },
    // Resolves once the edits asked for so far (strokes included) are done and drawn.
    async idle() {
      let q;
      do {
        q = app.editor.queue;
        await q;
      } while (q !== app.editor.queue);
      return { undo: app.editor.undoStack.length, redo: app.editor.redoStack.length };
    },
    get lastError() { return app.lastError || null; },
    async setView(eye, target, fovDeg = app.cam.fovDeg) {
      app.cam.set(eye, target, fovDeg, app.cam.up);
      const d = app.target;
      if (d) {
        try {
          await d.promise;
        } catch (e) {
          if (app.target === d) throw e;  // a superseded load's failure is not this view's
        }
      }
      await app.gaussian.settle();  // gaussian mode: the order for this view is in
      app.drawNow();
      await nextFrame();
      return true;
    },
    async gotoFrame(i) {
      app.player.stop();
      app.live.userSeek();
      await app.gotoFrame(i);
      return true;
    },
    playFor: (seconds) => app.player.playFor(seconds),
    snapshot() {
      app.drawNow();
      return app.canvas.toDataURL('image/png');
    },
    camera: () => app.wireCamera(),
    marquee: (u0, v0, u1, v1, mode = 'SELECT_REPLACE') => app.editor.marquee(u0, v0, u1, v1, mode),
    selectedCount: () => (app.shown ? app.shown.countBit((1 << app.bit) >>> 0) : 0),
    selectedIds: () => (app.shown ? app.shown.selectedIds((1 << app.bit) >>> 0) : []),
    pointsShown: () => (app.shown ? app.shown.points : 0),
    rendererInfo: () => ({ name: app.renderer.rendererName, software: app.renderer.software, mode: app.renderer.mode, splats: app.renderer.sprites ? 'sprites' : 'quads', renderMode: app.gaussian.mode }),
    gaussianInfo: () => app.gaussian.info(),
    setRenderMode: (m) => app.gaussian.setMode(m).then(() => true),
    // The time one full-resolution draw takes, to the GPU's completion (gl.finish).
    timeDraw() {
      const t = performance.now();
      app.drawNow();
      app.renderer.waitForGpu();
      return performance.now() - t;
    },
    undo: () => app.editor.undo(),
    redo: () => app.editor.redo(),
    request: (obj) => app.conn.request(obj),
    renderStill: () => app.renderStill(),
    renderVideo: (opts) => app.exporter.renderVideo(opts),
    get lastVideo() { return app.exporter.lastVideo || null; },
    setShadows: (on) => { app.exporter.toggle.checked = on; app.exporter.shadows = on; },
  };
  // The slice, transform and brush hooks (transform.js).
  Object.defineProperties(window.hvdbApp, Object.getOwnPropertyDescriptors(editingHooks(app)));
}

function boot() {
  let app;
  let ready;
  try {
    app = new App(parseParams());
    ready = app.start().then(() => true);
  } catch (e) {
    ready = Promise.reject(e);
  }
  ready.catch((e) => {
    if (app) app.showError(e, 'start');
    else {
      const el = document.getElementById('status-error');
      if (el) el.textContent = `start: ${e.message}`;
      console.error('hvdb: start failed', e);
    }
  });
  if (app) {
    exposeHooks(app, ready);
    window.hvdbLive = app.live.hooks();
    // A page leaving (or frozen in the back/forward cache) gives its connection back to the
    // server; coming back from that cache starts afresh.
    window.addEventListener('pagehide', () => { if (app.conn) app.conn.close(); });
    window.addEventListener('pageshow', (e) => { if (e.persisted) location.reload(); });
  }
  else window.hvdbApp = { ready, metrics: {} };
}

if (document.readyState === 'loading') document.addEventListener('DOMContentLoaded', boot);
else boot();
