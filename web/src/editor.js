// Editing tools (docs/PROTOCOL.md, "Editing"): marquee and lasso selections, foreground /
// background brush strokes, graph cut, clipboard, undo/redo. Every change is a transaction in
// the server; undo reverts its LSN, redo reverts the undo's LSN. LSNs are per dataset: each undo
// entry keeps its dataset. Edits, undo and redo run one at a time, in the order asked (queue).
import { allTimeWindow } from './connection.js';
import { combineOps, checkTarget, graphCutWithMode, SCRATCH_BIT } from './selection_modes.js';

export const TOOLS = ['navigate', 'marquee', 'lasso', 'brush-fg', 'brush-bg', 'slice', 'transform'];
export const FOREGROUND_BIT = 1;
export const BACKGROUND_BIT = 2;
const kClipboard = 'web';


export class Editor {
  constructor(app, canvas, overlay) {
    this.app = app;
    this.canvas = canvas;
    this.overlay = overlay;          // 2D canvas over the view for outlines
    this.ctx = overlay.getContext('2d');
    this.tool = 'navigate';
    this.undoStack = [];             // [{label, dataset, lsns: [...] }]
    this.redoStack = [];
    this.queue = Promise.resolve();  // the edit operations, one after another
    this.stroke = null;
    this.drag = null;
    this.brushPixelRadius = 12;
    this.brushRadius = 0.05;
    this.pasteOffset = [0, 0, 0, 0];
    this.graphCutAllFrames = false;
    this.mode = 'SELECT_REPLACE';    // the mode buttons' choice (modifier keys override it)
    this.brushNearest = false;       // brush depth: nearest z under the brush, else the median
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    window.addEventListener('pointermove', (e) => this.move(e));
    window.addEventListener('pointerup', (e) => this.up(e));
  }

  setTool(tool) {
    if (!TOOLS.includes(tool)) throw new Error(`unknown tool ${tool}`);
    this.tool = tool;
    this.canvas.style.cursor = tool === 'navigate' ? 'grab' : 'crosshair';
    this.app.ui?.setTool(tool);
    this.clearOverlay();  // the gizmo shows with the transform tool only
  }

  // Left drags belong to the tool unless navigating (or shift-dragging to pan).
  wantsPointer(e) { return this.tool !== 'navigate' && e.button === 0; }

  // Canvas pixel (device pixels: the camera's image) of a pointer event.
  pixel(e) {
    const r = this.canvas.getBoundingClientRect();
    const sx = this.canvas.width / Math.max(1, r.width), sy = this.canvas.height / Math.max(1, r.height);
    return [(e.clientX - r.left) * sx - 0.5 * (sx - 1), (e.clientY - r.top) * sy - 0.5 * (sy - 1)];
  }

  // Shift: add, Alt: subtract, Shift+Alt: intersect; no modifier: the mode buttons' choice.
  modeOf(e) {
    if (e.shiftKey && e.altKey) return 'SELECT_INTERSECT';
    if (e.shiftKey) return 'SELECT_ADD';
    if (e.altKey) return 'SELECT_SUBTRACT';
    return this.mode;
  }

  setMode(mode) {
    this.mode = selectMode(mode);
    this.app.ui?.setMode?.(this.mode);
  }

  down(e) {
    if (this.tool === 'navigate' || e.button !== 0) return;
    e.preventDefault();
    const p = this.pixel(e);
    if (this.tool === 'transform') {
      try {
        if (this.app.gizmo.down(p)) this.drag = { gizmo: true, start: p, points: [p], last: p };
      } catch (err) { this.app.showError(err); }
      return;
    }
    this.drag = { start: p, points: [p], mode: this.modeOf(e), last: p };
    if (this.tool.startsWith('brush')) this.startStroke(p, this.drag.mode);
    this.drawOutline();
  }

  move(e) {
    if (!this.drag) {
      if (this.tool.startsWith('brush') && e.target === this.canvas) this.drawBrushCursor(this.pixel(e));
      return;
    }
    const p = this.pixel(e);
    if (this.drag.gizmo) return this.app.gizmo.move(p);
    const last = this.drag.points[this.drag.points.length - 1];
    if (Math.hypot(p[0] - last[0], p[1] - last[1]) >= 2) this.drag.points.push(p);
    this.drag.last = p;
    if (this.tool.startsWith('brush')) this.strokeTo(p);
    this.drawOutline();
  }

  up(e) {
    if (!this.drag || e.button !== 0) return;
    const d = this.drag;
    this.drag = null;
    const p = this.pixel(e);
    if (d.gizmo) return this.app.gizmo.up(p);
    if (this.tool === 'slice') {
      if (Math.hypot(p[0] - d.start[0], p[1] - d.start[1]) >= 3) this.app.sliceTool.fromLine(d.start, p).catch((err) => this.app.showError(err));
    } else if (this.tool === 'marquee') {
      this.marquee(d.start[0], d.start[1], p[0], p[1], d.mode).catch((err) => this.app.showError(err));
    } else if (this.tool === 'lasso') {
      const poly = d.points.concat([p]);
      if (poly.length >= 3) this.lasso(poly.flat(), d.mode).catch((err) => this.app.showError(err));
    } else if (this.tool.startsWith('brush')) {
      this.endStroke().catch((err) => this.app.showError(err));
    }
    this.clearOverlay();
  }

  clearOverlay() {
    this.ctx.clearRect(0, 0, this.overlay.width, this.overlay.height);
    if (this.tool === 'transform') this.app.gizmo?.draw(this.ctx);
  }

  drawOutline() {
    const c = this.ctx, d = this.drag;
    this.clearOverlay();
    if (!d) return;
    c.save();
    c.lineWidth = 1.5;
    c.setLineDash([5, 4]);
    c.strokeStyle = '#ffb000';
    c.fillStyle = 'rgba(255, 176, 0, 0.12)';
    c.beginPath();
    if (this.tool === 'slice') {
      c.setLineDash([]);
      c.lineWidth = 2;
      c.strokeStyle = '#3c8cff';
      c.moveTo(d.start[0], d.start[1]);
      c.lineTo(d.last[0], d.last[1]);
    } else if (this.tool === 'marquee') {
      c.rect(Math.min(u0, u1), Math.min(v0, v1), Math.abs(u1 - u0), Math.abs(v1 - v0));
    } else if (this.tool === 'lasso') {
      d.points.forEach(([u, v], i) => (i ? c.lineTo(u, v) : c.moveTo(u, v)));
      c.closePath();
    } else {
      c.setLineDash([]);
      c.strokeStyle = this.tool === 'brush-fg' ? '#3cdc50' : '#e04040';
      d.points.forEach(([u, v]) => c.moveTo(u + this.brushPixelRadius, v) || c.arc(u, v, this.brushPixelRadius, 0, 2 * Math.PI));
    }
    c.fill();
    c.stroke();
    c.restore();
  }

  drawBrushCursor([u, v]) {
    const c = this.ctx;
    this.clearOverlay();
    c.strokeStyle = this.tool === 'brush-fg' ? '#3cdc50' : '#e04040';
    c.beginPath();
    c.arc(u, v, this.brushPixelRadius, 0, 2 * Math.PI);
    c.stroke();
  }

  // Runs fn() after every edit operation asked before it has finished (failed or not).
  enqueue(fn) {
    const run = this.queue.then(() => fn());
    this.queue = run.catch(() => {});
    return run;
  }

  // Another dataset: its LSNs mean nothing for the history kept so far.
  resetHistory() {
    this.undoStack = [];
    this.redoStack = [];
    this.app.ui?.updateEditButtons();
  }

  // Records an undoable change (not if the page has moved to another dataset meanwhile).
  record(label, dataset, lsns) {
    if (dataset !== this.app.dataset || !lsns.length) return;
    this.undoStack.push({ label, dataset, lsns });
    this.redoStack = [];
  }

  // ---- Requests. ----

  async select(shape, mode, bit = this.app.bit) {
    checkTarget(bit);
    // return_flips: the reply lists the points whose bit changed, and the page redraws
    // their labels in place (main.js refreshLabels) instead of querying the frame again; a
    // slice or the gaussian mode's records are queried again, so they do not ask.
    const flips = this.app.viewMode === 'frames' && !this.app.gaussian.active;
    const req = { select: { dataset: this.app.dataset, region: this.app.currentRegion(), bit, mode: selectMode(mode), return_flips: flips, ...shape } };
    return this.commit('select', req, (r) => r.selected);
  }

  // A rectangle (u0, v0)-(u1, v1) in canvas pixels: a four-vertex lasso.
  marquee(u0, v0, u1, v1, mode = 'SELECT_REPLACE') {
    const polygon = [u0, v0, u1, v0, u1, v1, u0, v1];
    return this.select({ lasso: { camera: this.app.wireCamera(), polygon } }, mode);
  }

  lasso(polygon, mode = 'SELECT_REPLACE') {
    return this.select({ lasso: { camera: this.app.wireCamera(), polygon } }, mode);
  }

  // Runs an edit request (built now, sent when the edits before it are done), records its LSN
  // for undo, re-queries the frames, and times the whole round trip (sent -> reply -> frame
  // reloaded -> redrawn).
  commit(label, req, pick, { record = true } = {}) {
    return this.enqueue(() => this.commitNow(label, req, pick, record));
  }

  async commitNow(label, req, pick, record) {
    const t0 = performance.now();
    const dataset = Object.values(req)[0].dataset;
    this.app.lastRequest = req;
    this.app.setStatus('edit', `${label}…`);
    const reply = await this.app.conn.request(req);
    // A transform is now in the data: its preview must not move the refreshed points again.
    if (label === 'transform') this.app.preview = null;
    const body = pick(reply);
    const lsn = body && body.lsn !== undefined ? String(body.lsn) : '0';
    if (record && lsn !== '0') this.record(label, dataset, [lsn]);
    this.app.ui?.updateEditButtons();
    const t1 = performance.now();
    const flips = label === 'select' && req.select.return_flips
      ? { flips: (body && body.flips) || [], mask: (1 << req.select.bit) >>> 0 } : null;
    const fresh = await this.app.refreshAfterEdit(flips);
    const t2 = performance.now();
    this.app.renderer.waitForGpu();  // the round trip ends with the overlay on screen
    this.app.lastEditMs = performance.now() - t0;
    // Where the time went: the request (server: the edit's commit), the frame's re-query,
    // and the draw until the GPU is done with it.
    this.app.lastEditPhases = {
      request_ms: t1 - t0,
      requery_ms: fresh && fresh.loadMs !== null ? fresh.loadMs : null,
      label_only: !!(fresh && fresh.labelOnly),
      refresh_ms: t2 - t1,
      gpu_ms: performance.now() - t2,
    };
    if (label === 'select' || label === 'brush') this.app.lastSelect = body;
    this.app.setStatus('edit', `${label}: ${describe(body)} (${this.app.lastEditMs.toFixed(0)} ms)`);
    this.app.ui?.updateEditButtons();
    return reply;
  }

  // ---- Brush strokes: one brush select per stamp, one undo entry per stroke. ----

  // Stamps go out as the pointer moves (one in flight per stroke); the stroke's undo entry and
  // refresh run in the edit queue.
  // mode: add (and replace: strokes accumulate, as the graph cut wants more of them; Clear
  // strokes drops them), subtract (erases), or intersect (painted into a scratch bit, combined
  // when the stroke ends).
  startStroke(p, mode = 'SELECT_ADD') {
    const bit = this.tool === 'brush-fg' ? FOREGROUND_BIT : BACKGROUND_BIT;
    const intersect = mode === 'SELECT_INTERSECT';
    const s = {
      lsns: [], busy: null, pending: null, error: null, ended: false, dataset: this.app.dataset,
      bit, writeBit: intersect ? SCRATCH_BIT : bit, intersect, nearest: this.brushNearest,
      mode: mode === 'SELECT_SUBTRACT' ? mode : 'SELECT_ADD',
      firstMode: intersect ? 'SELECT_REPLACE' : (mode === 'SELECT_SUBTRACT' ? mode : 'SELECT_ADD'),
    };
    this.stroke = s;
    this.stamp(s, p);
  }

  strokeTo(p) {
    const s = this.stroke;
    if (!s || s.ended) return;
    if (s.busy) s.pending = p;  // only the newest position waits
    else this.stamp(s, p);
  }

  stamp(s, [u, v]) {
    const req = {
      select: {
        dataset: s.dataset, region: this.app.currentRegion(), bit: s.writeBit, mode: s.stamped ? s.mode : s.firstMode,
        brush: { camera: this.app.wireCamera(), u, v, pixel_radius: this.brushPixelRadius, radius: this.brushRadius, nearest: s.nearest },
      },
    };
    s.stamped = true;
    this.app.lastBrushRequest = req;
    s.busy = this.app.conn.request(req).then((r) => {
      if (r.selected && String(r.selected.lsn) !== '0') s.lsns.push(String(r.selected.lsn));
      this.app.lastSelect = r.selected;
      s.stampedSurface = true;
    }, (err) => {
      // A stamp over empty space (no surface under the brush) paints nothing, as in any paint
      // tool; the stroke goes on, and its first stamp on a surface is its first (firstMode).
      if (err && err.code === 'NOT_FOUND' && /no surface under pixel/.test(err.message)) {
        if (!s.stampedSurface) s.stamped = false;
        return;
      }
      s.error = err;
    }).then(() => {
      s.busy = null;
      if (s.pending && !s.error) {
        const next = s.pending;
        s.pending = null;
        this.stamp(s, next);
      }
    });
  }

  endStroke() {
    const s = this.stroke;
    if (!s || s.ended) return Promise.resolve();
    s.ended = true;  // its last pending position is still stamped
    const t0 = performance.now();
    return this.enqueue(async () => {
      while (s.busy) await s.busy;
      if (this.stroke === s) this.stroke = null;  // a stroke started meanwhile stays
      // An intersect stroke that met no surface leaves the selection as it was (its scratch
      // bit is empty: combining would clear the selection).
      if (s.intersect && !s.error && s.stampedSurface) {
        try {
          const r = await this.app.conn.request({ edit: { dataset: s.dataset, ops: combineOps(s.bit, 'SELECT_INTERSECT') } });
          if (String(r.commit.lsn) !== '0') s.lsns.push(String(r.commit.lsn));
        } catch (err) { s.error = err; }
      }
      this.record(s.bit === FOREGROUND_BIT ? 'foreground stroke' : 'background stroke', s.dataset, s.lsns);
      this.app.ui?.updateEditButtons();
      if (s.error) throw s.error;
      await this.app.refreshAfterEdit();
      this.app.renderer.waitForGpu();  // the round trip ends with the overlay on screen
      this.app.lastEditMs = performance.now() - t0;
      this.app.setStatus('edit', `stroke: ${s.lsns.length} stamps`);
      this.app.ui?.updateEditButtons();
    });
  }

  // ---- Graph cut, clipboard, labels. ----

  // The cut's result combines with the selection bit by the mode buttons' choice.
  graphCut(allFrames = this.graphCutAllFrames, mode = this.mode) {
    const roi = allFrames ? allTimeWindow(this.app.box) : this.app.currentRegion();
    if (selectMode(mode) !== 'SELECT_REPLACE') return graphCutWithMode(this, roi, FOREGROUND_BIT, BACKGROUND_BIT, selectMode(mode));
    const req = { graph_cut: { dataset: this.app.dataset, roi, foreground_bit: FOREGROUND_BIT, background_bit: BACKGROUND_BIT, out_bit: this.app.bit } };
    return this.commit('graph cut', req, (r) => r.graph_cut);
  }

  copy(cut = false) {
    const req = { copy: { dataset: this.app.dataset, bit: this.app.bit, clipboard: kClipboard, cut } };
    return this.commit(cut ? 'cut' : 'copy', req, (r) => r.copied, { record: cut });
  }

  paste(offset = this.pasteOffset) {
    const req = { paste: { dataset: this.app.dataset, clipboard: kClipboard, offset: offset.map(Number) } };
    return this.commit('paste', req, (r) => r.commit);
  }

  // Clears the selection bit on every point that has it.
  clearSelection(bits = 1 << this.app.bit) {
    const mask = bits >>> 0;
    const req = { edit: { dataset: this.app.dataset, ops: [{ set_label: { selection: { label_mask: mask }, bits: mask, set: false } }] } };
    return this.commit('clear selection', req, (r) => r.commit);
  }

  clearStrokes() { return this.clearSelection((1 << FOREGROUND_BIT) | (1 << BACKGROUND_BIT)); }

  // Undo: revert each LSN of the entry, newest first; redo reverts those undos.
  // The stacks are looked at when the operation's turn comes (after the edits before it).
  undo() { return this.enqueue(() => this.revertEntry('undoStack', 'redoStack', 'undo')); }

  redo() { return this.enqueue(() => this.revertEntry('redoStack', 'undoStack', 'redo')); }

  async revertEntry(fromName, toName, what) {
    const entry = this[fromName].pop();
    if (!entry) throw new Error(`nothing to ${what}`);
    this.app.ui?.updateEditButtons();
    const t0 = performance.now();
    const done = [];
    let last = null;
    // A dataset switch clears the stacks meanwhile: then nothing is pushed back.
    const push = (name, lsns) => {
      if (lsns.length && entry.dataset === this.app.dataset) this[name].push({ label: entry.label, dataset: entry.dataset, lsns });
    };
    try {
      for (const lsn of [...entry.lsns].reverse()) {
        last = await this.app.conn.request({ revert: { dataset: entry.dataset, lsn } });
        done.push(String(last.commit.lsn));
      }
    } catch (err) {
      // Keep what was reverted undoable; the rest stays where it was.
      push(toName, done);
      push(fromName, entry.lsns.slice(0, entry.lsns.length - done.length));
      this.app.ui?.updateEditButtons();
      throw err;
    }
    push(toName, done);
    this.app.ui?.updateEditButtons();
    if (entry.dataset !== this.app.dataset) return last;  // nothing of it is on screen
    await this.app.refreshAfterEdit();
    this.app.renderer.waitForGpu();  // the round trip ends with the overlay on screen
    this.app.lastEditMs = performance.now() - t0;
    this.app.setStatus('edit', `${what} ${entry.label} (lsn ${done.join(', ')})`);
    this.app.ui?.updateEditButtons();
    return last;
  }
}

// Accepts the enum names and their short forms ('replace', 'add', 'subtract', 'intersect').
export function selectMode(mode) {
  if (!mode) return 'SELECT_REPLACE';
  const m = String(mode).toUpperCase();
  const full = m.startsWith('SELECT_') ? m : `SELECT_${m}`;
  if (!['SELECT_REPLACE', 'SELECT_ADD', 'SELECT_SUBTRACT', 'SELECT_INTERSECT'].includes(full)) throw new Error(`unknown selection mode ${mode}`);
  return full;
}

function describe(body) {
  if (!body) return 'done';
  return Object.entries(body).filter(([k]) => !k.endsWith('_ms') && k !== 'brush_center')
    .map(([k, v]) => `${k} ${Array.isArray(v) ? v.length : v}`).join(', ');
}
