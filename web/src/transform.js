// Transforms of the selection (thesis 9.4): 4D affine maps over Y = (x, y, z, s t), s the
// dataset's space/time scale, so that a rotation can turn time into space. A transform is
// pending (previewed on the page, composed over several gizmo drags or numeric entries) until
// Apply sends it as ONE edit transaction (a Transform op on the selection's label bit, within
// the region on screen); the page's undo reverts it.
import { sliceBasis, FRAME_BASIS } from './slice_tool.js';

const I4 = () => [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]];
const mul4 = (A, B) => A.map((r) => [0, 1, 2, 3].map((j) => r[0] * B[0][j] + r[1] * B[1][j] + r[2] * B[2][j] + r[3] * B[3][j]));
const apply4 = (A, v) => A.map((r) => r[0] * v[0] + r[1] * v[1] + r[2] * v[2] + r[3] * v[3]);
const sub = (a, b) => a.map((x, i) => x - b[i]);
const add = (a, b) => a.map((x, i) => x + b[i]);

// A rotation by `deg` degrees in the plane of axes i, j of Y (0..3 = x, y, z, s t), from i to j.
export function rotation4(i, j, deg) {
  const M = I4(), r = (deg * Math.PI) / 180, c = Math.cos(r), s = Math.sin(r);
  M[i][i] = c; M[i][j] = -s; M[j][i] = s; M[j][j] = c;
  return M;
}

// {M, t} of Y' = M (Y - c) + c + d.
export function about(M, c, d = [0, 0, 0, 0]) { return { M, t: add(sub(c, apply4(M, c)), d) }; }

// The map `next` after `prev`.
export function compose(next, prev) { return { M: mul4(next.M, prev.M), t: add(apply4(next.M, prev.t), next.t) }; }

// A 3D affine of the displayed space (M3 row-major 3x3 about cD, then + d3) as a 4D map: the
// part along the slice normal stays, Y' = Y + B^T ((M3 - I)(B Y - cD) + d3).
export function fromDisplayed(B, M3, cD, d3) {
  const K = [0, 1, 2].map((r) => [0, 1, 2].map((c) => M3[r * 3 + c] - (r === c ? 1 : 0)));
  const M = I4();
  for (let a = 0; a < 4; ++a) {
    for (let b = 0; b < 4; ++b) {
      for (let r = 0; r < 3; ++r) for (let c = 0; c < 3; ++c) M[a][b] += B[r][a] * K[r][c] * B[c][b];
    }
  }
  const KcD = K.map((row) => row[0] * cD[0] + row[1] * cD[1] + row[2] * cD[2]);
  const v = d3.map((x, r) => x - KcD[r]);
  const t = [0, 1, 2, 3].map((a) => B[0][a] * v[0] + B[1][a] * v[1] + B[2][a] * v[2]);
  return { M, t };
}

// What the map does to the displayed space (the preview): D = B Y with Y = B^T D + P0.
export function toDisplayed(B, P0, { M, t }) {
  const m = [];
  for (let r = 0; r < 3; ++r) {
    for (let c = 0; c < 3; ++c) {
      let v = 0;
      for (let a = 0; a < 4; ++a) for (let b = 0; b < 4; ++b) v += B[r][a] * M[a][b] * B[c][b];
      m.push(v);
    }
  }
  const y = add(apply4(M, P0), t);
  return { m, t: [0, 1, 2].map((r) => B[r][0] * y[0] + B[r][1] * y[1] + B[r][2] * y[2] + B[r][3] * y[3]) };
}

// The wire Transform's matrix (16, row-major) and offset over (x, y, z, t): S^-1 M S, S^-1 t.
export function toWire({ M, t }, s) {
  const S = [1, 1, 1, s];
  const matrix = [];
  for (let a = 0; a < 4; ++a) for (let b = 0; b < 4; ++b) matrix.push((M[a][b] * S[b]) / S[a]);
  return { matrix, offset: t.map((x, a) => x / S[a]) };
}

const $ = (id) => document.getElementById(id);
const AXES = { x: 0, y: 1, z: 2, t: 3 };

// The pending transform of the page, its preview and its commit.
export class Transformer {
  constructor(app) {
    this.app = app;
    this.pending = null;  // {M, t} over Y, or null
    $('xf-apply').addEventListener('click', () => this.apply().catch((e) => app.showError(e)));
    $('xf-cancel').addEventListener('click', () => this.cancel());
    $('xf-add').addEventListener('click', () => { try { this.addNumeric(); } catch (e) { app.showError(e); } });
  }

  get scale() { return Number(this.app.info?.space_time_scale) || 1; }

  // The displayed space: its basis B and the point P0 of the centre plane (the frame's time).
  space() {
    const a = this.app, s = this.scale;
    if (a.viewMode === 'slice') {
      const n = a.slice.normal, len = Math.hypot(...n);
      return { B: sliceBasis(n), P0: n.map((x) => (x / len) * (a.slice.offset / len)) };
    }
    return { B: FRAME_BASIS, P0: [0, 0, 0, s * (a.frame / a.info.fps)] };
  }

  // The selection's centre, displayed (before the pending transform) and in Y.
  centre() {
    const d = this.app.shown;
    const { center, count } = d ? d.centroid((1 << this.app.bit) >>> 0) : { center: null, count: 0 };
    if (!count) return null;
    const { B, P0 } = this.space();
    const Y = [0, 1, 2, 3].map((a) => P0[a] + B[0][a] * center[0] + B[1][a] * center[1] + B[2][a] * center[2]);
    return { D: center, Y, count };
  }

  // Adds a map after the pending one and redraws the preview.
  push(map) {
    this.pending = this.pending ? compose(map, this.pending) : map;
    this.showPreview();
  }

  // The preview of pending (and of `extra`, a drag in progress) on the page.
  showPreview(extra = null) {
    const p = extra ? (this.pending ? compose(extra, this.pending) : extra) : this.pending;
    const { B, P0 } = this.space();
    this.app.preview = p ? toDisplayed(B, P0, p) : null;
    this.updatePanel(p);
    this.app.requestDraw();
  }

  updatePanel(p) {
    const w = p ? toWire(p, this.scale) : null;
    $('xf-pending').textContent = w ? `pending: matrix [${w.matrix.map((x) => +x.toFixed(4)).join(' ')}] offset [${w.offset.map((x) => +x.toFixed(4)).join(' ')}]` : 'no pending transform';
  }

  cancel() {
    this.pending = null;
    this.showPreview();
  }

  // The numeric entry: translate (dx dy dz m, dt s), rotate (degrees, in a plane of two of
  // x y z t, about the selection's centre), scale (factor on x y z about the centre).
  addNumeric() {
    const c = this.centre();
    if (!c) throw new Error('transform: select points first (nothing carries the selection bit here)');
    const num = (id, what) => {
      const v = Number($(id).value);
      if (!Number.isFinite(v)) throw new Error(`transform ${what}: not a number`);
      return v;
    };
    const tr = $('xf-translate').value.split(/[\s,]+/).filter(Boolean).map(Number);
    while (tr.length < 4) tr.push(0);
    if (tr.length > 4 || tr.some((x) => !Number.isFinite(x))) throw new Error('transform translate: give dx,dy,dz[,dt] (metres, seconds)');
    const plane = $('xf-plane').value;
    const deg = num('xf-angle', 'angle'), k = num('xf-scale', 'scale');
    if (!(k > 0)) throw new Error('transform scale: a factor > 0');
    return this.push(numericMap(c.Y, tr, plane, deg, k, this.scale));
  }

  // Sends the pending transform: one Edit with one Transform op on the selection bit.
  async apply() {
    const a = this.app;
    if (!this.pending) throw new Error('transform: nothing pending (drag the gizmo or add a numeric transform)');
    const { matrix, offset } = toWire(this.pending, this.scale);
    const selection = { region: a.currentRegion(), label_mask: (1 << a.bit) >>> 0 };
    const req = { edit: { dataset: a.dataset, ops: [{ transform: { selection, matrix, offset } }] } };
    this.pending = null;
    try {
      return await a.editor.commit('transform', req, (r) => r.commit);
    } finally {
      this.showPreview();
    }
  }
}

// translate [dx dy dz dt], then rotate deg in plane 'ij' (e.g. 'xt'), then scale k, about Y c.
export function numericMap(c, tr, plane, deg, k, s) {
  if (!/^[xyzt]{2}$/.test(plane) || plane[0] === plane[1]) throw new Error(`transform plane "${plane}": two of x y z t`);
  const R = rotation4(AXES[plane[0]], AXES[plane[1]], deg);
  const K = I4();
  for (let i = 0; i < 3; ++i) K[i][i] = k;
  const d = [tr[0], tr[1], tr[2], s * tr[3]];
  return about(mul4(K, R), c, d);
}

// window.hvdbApp's hooks for the ch. 9 tools (web/README.md, "Test hooks").
export function editingHooks(app) {
  return {
    // The region the page queries (and edits within): the frame's window or the slice.
    region: () => app.currentRegion(),
    // The pending transform ({matrix, offset} as Apply sends it) and the displayed preview.
    pendingTransform: () => (app.transformer.pending ? toWire(app.transformer.pending, app.transformer.scale) : null),
    get preview() { return app.preview; },
    gizmo: () => app.gizmo.layout(),
    applyTransform: () => app.transformer.apply(),
    get lastBrushRequest() { return app.lastBrushRequest || null; },
  };
}
