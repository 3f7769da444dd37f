// The page's controls: toolbar, side panel, timeline, status bar, help panel and keyboard
// shortcuts. Everything here calls into the App (main.js); errors go to the status bar.
import { isTyping, isTextField, isFormControl } from './camera.js';

const $ = (id) => {
  const el = document.getElementById(id);
  if (!el) throw new Error(`index.html lacks #${id}`);
  return el;
};

export class UI {
  constructor(app) {
    this.app = app;
    this.bindToolbar();
    this.bindSide();
    this.bindTimeline();
    this.bindKeys();
    this.updateEditButtons();
  }

  // Runs an action, showing its failure (never swallowing it).
  run(fn) {
    return (...args) => {
      try {
        const r = fn(...args);
        if (r && typeof r.catch === 'function') r.catch((e) => this.app.showError(e));
      } catch (e) {
        this.app.showError(e);
      }
    };
  }

  bindToolbar() {
    const a = this.app;
    for (const b of document.querySelectorAll('[data-tool]')) {
      b.addEventListener('click', this.run(() => a.editor.setTool(b.dataset.tool)));
    }
    for (const b of document.querySelectorAll('[data-mode]')) {
      b.addEventListener('click', this.run(() => a.editor.setMode(b.dataset.mode)));
    }
    $('graph-cut').addEventListener('click', this.run(() => a.editor.graphCut()));
    $('graph-cut-all').addEventListener('change', (e) => { a.editor.graphCutAllFrames = e.target.checked; });
    $('clear-strokes').addEventListener('click', this.run(() => a.editor.clearStrokes()));
    $('undo').addEventListener('click', this.run(() => a.editor.undo()));
    $('redo').addEventListener('click', this.run(() => a.editor.redo()));
    $('cut').addEventListener('click', this.run(() => a.editor.copy(true)));
    $('copy').addEventListener('click', this.run(() => a.editor.copy(false)));
    $('paste').addEventListener('click', this.run(() => a.editor.paste(this.pasteOffset())));
    $('clear-selection').addEventListener('click', this.run(() => a.editor.clearSelection()));
    $('bit').value = a.bit;
    $('bit').addEventListener('change', this.run((e) => {
      const b = Number(e.target.value);
      if (!Number.isInteger(b) || b < 0 || b > 31) throw new Error('selection bit must be 0..31');
      a.bit = b;
      a.requestDraw();
    }));
    $('overlay').addEventListener('change', (e) => a.setOverlay(e.target.checked));
    $('fly').addEventListener('click', () => this.toggleFly());
    $('render-still').addEventListener('click', this.run(() => a.renderStill()));
    $('render-sequence').addEventListener('click', this.run(() => a.renderSequence()));
    $('render-close').addEventListener('click', () => { $('render-panel').hidden = true; a.stopSequence(); });
    $('help-button').addEventListener('click', () => this.toggleHelp());
    $('help-close').addEventListener('click', () => this.toggleHelp(false));
    $('dataset').addEventListener('change', this.run((e) => a.openDataset(e.target.value)));
  }

  pasteOffset() {
    const v = $('paste-offset').value.split(/[\s,]+/).filter(Boolean).map(Number);
    while (v.length < 4) v.push(0);
    if (v.length > 4 || v.some((x) => !Number.isFinite(x))) throw new Error('paste offset: give dx,dy,dz[,dt] as numbers');
    return v;
  }

  bindSide() {
    const a = this.app;
    $('lod').addEventListener('input', (e) => { $('lod-value').textContent = e.target.value; });
    $('lod').addEventListener('change', this.run((e) => a.setLod(Number(e.target.value))));
    $('slice-apply').addEventListener('click', this.run(() => {
      const normal = ['nx', 'ny', 'nz', 'nt'].map((k) => Number($(`slice-${k}`).value));
      const offset = Number($('slice-offset').value), thickness = Number($('slice-thickness').value);
      if (normal.some((x) => !Number.isFinite(x)) || normal.every((x) => x === 0)) throw new Error('slice normal: four numbers, not all zero');
      if (!Number.isFinite(offset) || !(thickness >= 0)) throw new Error('slice: offset must be a number and thickness >= 0');
      return a.sliceTool.show({ normal, offset, thickness }, false);
    }));
    $('slice-back').addEventListener('click', this.run(() => a.showFrames()));
    $('box-apply').addEventListener('click', this.run(() => {
      const read = (k) => Number($(`box-${k}`).value);
      const lo = ['x0', 'y0', 'z0'].map(read), hi = ['x1', 'y1', 'z1'].map(read);
      if ([...lo, ...hi].some((x) => !Number.isFinite(x)) || lo.some((v, i) => v > hi[i])) throw new Error('box: lo and hi need three numbers each, lo <= hi');
      return a.setBox({ lo, hi });
    }));
    $('box-clear').addEventListener('click', this.run(() => a.setBox(null)));
    $('brush-pixels').addEventListener('change', (e) => { a.editor.brushPixelRadius = Math.max(1, Number(e.target.value) || 12); });
    $('brush-radius').addEventListener('change', (e) => { a.editor.brushRadius = Math.max(0, Number(e.target.value) || 0.05); });
    $('brush-depth').addEventListener('change', (e) => { a.editor.brushNearest = e.target.value === 'nearest'; });
  }

  bindTimeline() {
    const a = this.app;
    $('play').addEventListener('click', () => this.togglePlay());
    $('step-back').addEventListener('click', this.run(() => a.stepFrame(-1)));
    $('step-forward').addEventListener('click', this.run(() => a.stepFrame(1)));
    $('frame-slider').addEventListener('input', this.run((e) => { a.player.stop(); a.live.userSeek(); return a.gotoFrame(Number(e.target.value)); }));
    $('live').addEventListener('click', this.run(() => a.live.toggle()));
    $('live-pause').addEventListener('click', () => a.live.pause());
    $('live-return').addEventListener('click', this.run(() => a.live.goLive()));
  }

  // Playback moves in time: live mode pauses rather than pull the play head back.
  togglePlay() {
    const a = this.app;
    if (!a.player.playing) a.live.userSeek();
    a.player.toggle();
  }

  bindKeys() {
    const a = this.app;
    const fail = (x) => a.showError(x);
    // Server-side copy / cut only when the page's own text is not what the user copies.
    const pageTextSelected = () => {
      const sel = window.getSelection ? window.getSelection() : null;
      return !!sel && !sel.isCollapsed && sel.toString().length > 0;
    };
    window.addEventListener('keydown', this.run((e) => {
      if (isTyping(e)) return;
      const k = e.key;
      const ctrl = e.ctrlKey || e.metaKey;
      const lower = k.toLowerCase();
      // Keys a focused control handles itself: a slider's arrows, a checkbox's Space.
      const type = e.target?.tagName === 'INPUT' ? String(e.target.type).toLowerCase() : '';
      if (type === 'range' && ['ArrowLeft', 'ArrowRight', 'ArrowUp', 'ArrowDown', 'Home', 'End', 'PageUp', 'PageDown'].includes(k)) return;
      if ((type === 'checkbox' || type === 'radio') && k === ' ') return;
      const edit = (fn) => { if (!e.repeat) fn().catch(fail); };  // auto-repeat starts no edits
      const clipboardOk = () => !pageTextSelected() && !isTextField(document.activeElement);
      let handled = true;
      if (ctrl && lower === 'z' && e.shiftKey) edit(() => a.editor.redo());
      else if (ctrl && lower === 'z') edit(() => a.editor.undo());
      else if (ctrl && lower === 'y') edit(() => a.editor.redo());
      else if (ctrl && lower === 'c') { if (clipboardOk()) edit(() => a.editor.copy(false)); else handled = false; }
      else if (ctrl && lower === 'x') { if (clipboardOk()) edit(() => a.editor.copy(true)); else handled = false; }
      else if (ctrl && lower === 'v') edit(() => a.editor.paste(this.pasteOffset()));
      else if (ctrl) handled = false;
      else if (k === 'Tab') { if (!e.shiftKey && !e.altKey && !isFormControl(document.activeElement)) this.toggleFly(); else handled = false; }
      else if (a.cam.fly && 'wasdqe'.includes(lower) && lower.length === 1) handled = false;  // flying
      else if (k === ' ') { if (!e.repeat) this.togglePlay(); }
      else if (k === 'ArrowLeft') a.stepFrame(-1).catch(fail);
      else if (k === 'ArrowRight') a.stepFrame(1).catch(fail);
      else if (k === 'Home') { a.player.stop(); a.live.userSeek(); a.gotoFrame(0).catch(fail); }
      else if (k === 'End') { if (a.live.on) a.live.goLive().catch(fail); else handled = false; }
      else if (k === 'Delete') { if (clipboardOk()) edit(() => a.editor.copy(true)); else handled = false; }
      else if (k === '?' || lower === 'h') this.toggleHelp();
      else if (k === 'Escape') { this.toggleHelp(false); a.transformer.cancel(); }
      else if (k === 'Enter' && a.transformer.pending) edit(() => a.transformer.apply());
      else if (lower === 'k') a.editor.setTool('slice');
      else if (lower === 't') a.editor.setTool('transform');
      else if (lower === 'i') (e.shiftKey ? a.sliceTool.markOut() : a.sliceTool.markIn()).catch(fail);
      else if (lower === 'n') a.editor.setTool('navigate');
      else if (lower === 'm') a.editor.setTool('marquee');
      else if (lower === 'l') a.editor.setTool('lasso');
      else if (lower === 'f') a.editor.setTool('brush-fg');
      else if (lower === 'g') a.editor.setTool('brush-bg');
      else if (lower === 'c') edit(() => a.editor.graphCut());
      else if (lower === 'r') { if (!e.repeat) a.renderStill().catch(fail); }
      else if (k === '[') a.setLod(a.lod - 1).catch(fail);
      else if (k === ']') a.setLod(a.lod + 1).catch(fail);
      else if (lower === 'o') a.setOverlay(!a.overlay);
      else handled = false;
      if (handled) e.preventDefault();
    }));
  }

  toggleFly() {
    const a = this.app;
    a.cam.fly = !a.cam.fly;
    $('fly').classList.toggle('active', a.cam.fly);
    a.setStatus('edit', a.cam.fly ? 'fly mode: W A S D, Q / E; drag to look around' : 'orbit mode');
  }

  toggleHelp(show) {
    const h = $('help');
    h.hidden = show === undefined ? !h.hidden : !show;
  }

  setTool(tool) {
    for (const b of document.querySelectorAll('[data-tool]')) b.classList.toggle('active', b.dataset.tool === tool);
  }

  setMode(mode) {
    for (const b of document.querySelectorAll('[data-mode]')) b.classList.toggle('active', b.dataset.mode === mode);
  }

  setPlaying(playing) { $('play').textContent = playing ? 'Pause' : 'Play'; }

  setOverlay(on) { $('overlay').checked = on; }

  // Live mode's buttons: on (subscribed), following the newest frame or paused `behind` it.
  setLive(on, following, behind) {
    $('live').classList.toggle('active', on);
    $('live').textContent = on ? '● Live' : 'Live';
    $('live').title = on ? 'Live mode on: click to leave it' : 'Live: follow the newest frame as it is committed';
    $('live-pause').hidden = $('live-return').hidden = !on;
    $('live-pause').disabled = !following;
    $('live-return').disabled = following;
    $('live-return').textContent = !following && behind > 0 ? `Return to live (+${behind})` : 'Return to live';
  }

  setDatasets(names, current) {
    const sel = $('dataset');
    sel.replaceChildren(...names.map((n) => new Option(n, n, n === current, n === current)));
  }

  setFrameRange(count) {
    $('frame-slider').max = Math.max(0, count - 1);
  }

  setLodRange(max, value) {
    $('lod').max = max;
    $('lod').value = value;
    $('lod-value').textContent = String(value);
  }

  setFrame(frame, count, fps, sliceMode) {
    const s = $('frame-slider');
    s.value = frame;
    s.disabled = sliceMode;
    // Frames are numbered from 0, as everywhere else in hvdb (frame 5 is t = 5 / fps).
    $('frame-label').textContent = sliceMode ? 'slice' : `frame ${frame} of ${count}`;
    $('time-label').textContent = sliceMode ? '' : `${(frame / fps).toFixed(3)} s`;
  }

  setBoxInputs(box) {
    const keys = ['x0', 'y0', 'z0', 'x1', 'y1', 'z1'];
    const vals = box ? [...box.lo, ...box.hi] : ['', '', '', '', '', ''];
    keys.forEach((k, i) => { $(`box-${k}`).value = vals[i]; });
  }

  updateEditButtons() {
    const e = this.app.editor;
    if (!e) return;
    $('undo').disabled = e.undoStack.length === 0;
    $('redo').disabled = e.redoStack.length === 0;
    const top = (s) => (s.length ? ` (${s[s.length - 1].label})` : '');
    $('undo').title = `Undo${top(e.undoStack)} (Ctrl+Z)`;
    $('redo').title = `Redo${top(e.redoStack)} (Ctrl+Shift+Z)`;
  }

  setStatus(field, text, cls) {
    const el = $(`status-${field}`);
    el.textContent = text;
    if (cls !== undefined) el.className = cls;
  }

  showRender(url, info, downloadUrl = url) {
    $('render-panel').hidden = false;
    $('render-image').src = url;
    $('render-info').textContent = info;
    $('render-download').href = downloadUrl;
  }
}
