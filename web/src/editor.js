// Editing tools (docs/PROTOCOL.md, "Editing"): marquee and lasso selections, foreground /
// background brush strokes, graph cut, clipboard, undo/redo. Every change is a transaction in
// the server; undo reverts its LSN, redo reverts the undo's LSN.
import { allTimeWindow } from './connection.js';

export const TOOLS = ['navigate', 'marquee', 'lasso', 'brush-fg', 'brush-bg'];
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
    this.undoStack = [];             // [{label, lsns: [...] }]
    this.redoStack = [];
    this.drag = null;
    this.brushPixelRadius = 12;
    this.brushRadius = 0.05;
    this.pasteOffset = [0, 0, 0, 0];
    this.graphCutAllFrames = false;
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    window.addEventListener('pointermove', (e) => this.move(e));
    window.addEventListener('pointerup', (e) => this.up(e));
  }

  setTool(tool) {
    if (!TOOLS.includes(tool)) throw new Error(`unknown tool ${tool}`);
    this.tool = tool;
    this.canvas.style.cursor = tool === 'navigate' ? 'grab' : 'crosshair';
    this.app.ui?.setTool(tool);
  }

  // Left drags belong to the tool unless navigating (or shift-dragging to pan).
  wantsPointer(e) { return this.tool !== 'navigate' && e.button === 0; }

  // Canvas pixel (device pixels: the camera's image) of a pointer event.
  pixel(e) {
    const r = this.canvas.getBoundingClientRect();
    const sx = this.canvas.width / Math.max(1, r.width), sy = this.canvas.height / Math.max(1, r.height);
    return [(e.clientX - r.left) * sx - 0.5 * (sx - 1), (e.clientY - r.top) * sy - 0.5 * (sy - 1)];
  }

  modeOf(e) {
    if (e.shiftKey) return 'SELECT_ADD';
    if (e.altKey) return 'SELECT_SUBTRACT';
    return 'SELECT_REPLACE';
  }

  down(e) {
    if (this.tool === 'navigate' || e.button !== 0) return;
    e.preventDefault();
    const p = this.pixel(e);
    this.drag = { start: p, points: [p], mode: this.modeOf(e), last: p };
    if (this.tool.startsWith('brush')) this.startStroke(p);
    this.drawOutline();
  }

  move(e) {
    if (!this.drag) {
      if (this.tool.startsWith('brush') && e.target === this.canvas) this.drawBrushCursor(this.pixel(e));
      return;
    }
    const p = this.pixel(e);
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
    if (this.tool === 'marquee') {
      this.marquee(d.start[0], d.start[1], p[0], p[1], d.mode).catch((err) => this.app.showError(err));
    } else if (this.tool === 'lasso') {
      const poly = d.points.concat([p]);
      if (poly.length >= 3) this.lasso(poly.flat(), d.mode).catch((err) => this.app.showError(err));
    } else if (this.tool.startsWith('brush')) {
      this.endStroke().catch((err) => this.app.showError(err));
    }
    this.clearOverlay();
  }

  clearOverlay() { this.ctx.clearRect(0, 0, this.overlay.width, this.overlay.height); }

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
    if (this.tool === 'marquee') {
      const [u0, v0] = d.start, [u1, v1] = d.last;
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

  // ---- Requests. ----

  async select(shape, mode, bit = this.app.bit) {
    const req = { select: { dataset: this.app.dataset, region: this.app.currentRegion(), bit, mode: selectMode(mode), ...shape } };
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

  // Runs an edit request, records its LSN for undo, re-queries the frames, and times the
  // whole round trip (sent -> reply -> frame reloaded -> redrawn).
  async commit(label, req, pick, { record = true } = {}) {
    const t0 = performance.now();
    this.app.lastRequest = req;
    this.app.setStatus('edit', `${label}…`);
    const reply = await this.app.conn.request(req);
    const body = pick(reply);
    const lsn = body && body.lsn !== undefined ? String(body.lsn) : '0';
    if (record && lsn !== '0') {
      this.undoStack.push({ label, lsns: [lsn] });
      this.redoStack = [];
    }
    await this.app.refreshAfterEdit();
    this.app.renderer.waitForGpu();  // the round trip ends with the overlay on screen
    this.app.lastEditMs = performance.now() - t0;
    if (label === 'select' || label === 'brush') this.app.lastSelect = body;
    this.app.setStatus('edit', `${label}: ${describe(body)} (${this.app.lastEditMs.toFixed(0)} ms)`);
    this.app.ui?.updateEditButtons();
    return reply;
  }

  // ---- Brush strokes: one brush select per stamp, one undo entry per stroke. ----

  startStroke(p) {
    this.stroke = { lsns: [], busy: null, pending: null, bit: this.tool === 'brush-fg' ? FOREGROUND_BIT : BACKGROUND_BIT, error: null };
    this.stamp(p);
  }

  strokeTo(p) {
    if (!this.stroke) return;
    if (this.stroke.busy) this.stroke.pending = p;  // only the newest position waits
    else this.stamp(p);
  }

  stamp([u, v]) {
    const s = this.stroke;
    const req = {
      select: {
        dataset: this.app.dataset, region: this.app.currentRegion(), bit: s.bit, mode: 'SELECT_ADD',
        brush: { camera: this.app.wireCamera(), u, v, pixel_radius: this.brushPixelRadius, radius: this.brushRadius, nearest: false },
      },
    };
    s.busy = this.app.conn.request(req).then((r) => {
      if (r.selected && String(r.selected.lsn) !== '0') s.lsns.push(String(r.selected.lsn));
      this.app.lastSelect = r.selected;
    }, (err) => { s.error = err; }).then(() => {
      s.busy = null;
      if (s.pending && !s.error) {
        const next = s.pending;
        s.pending = null;
        this.stamp(next);
      }
    });
  }

  async endStroke() {
    const s = this.stroke;
    if (!s) return;
    const t0 = performance.now();
    while (s.busy) await s.busy;
    this.stroke = null;
    if (s.lsns.length) {
      this.undoStack.push({ label: s.bit === FOREGROUND_BIT ? 'foreground stroke' : 'background stroke', lsns: s.lsns });
      this.redoStack = [];
    }
    if (s.error) throw s.error;
    await this.app.refreshAfterEdit();
    this.app.renderer.waitForGpu();  // the round trip ends with the overlay on screen
    this.app.lastEditMs = performance.now() - t0;
    this.app.setStatus('edit', `stroke: ${s.lsns.length} stamps`);
    this.app.ui?.updateEditButtons();
  }

  // ---- Graph cut, clipboard, labels. ----

  graphCut(allFrames = this.graphCutAllFrames) {
    const roi = allFrames ? allTimeWindow(this.app.box) : this.app.currentRegion();
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
  async undo() { return this.revertEntry(this.undoStack, this.redoStack, 'undo'); }

  async redo() { return this.revertEntry(this.redoStack, this.undoStack, 'redo'); }

  async revertEntry(from, to, what) {
    const entry = from.pop();
    if (!entry) throw new Error(`nothing to ${what}`);
    const t0 = performance.now();
    const done = [];
    let last = null;
    try {
      for (const lsn of [...entry.lsns].reverse()) {
        last = await this.app.conn.request({ revert: { dataset: this.app.dataset, lsn } });
        done.push(String(last.commit.lsn));
      }
    } catch (err) {
      // Keep what was reverted undoable; the rest stays where it was.
      if (done.length) to.push({ label: entry.label, lsns: done });
      const left = entry.lsns.slice(0, entry.lsns.length - done.length);
      if (left.length) from.push({ label: entry.label, lsns: left });
      this.app.ui?.updateEditButtons();
      throw err;
    }
    to.push({ label: entry.label, lsns: done });
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
