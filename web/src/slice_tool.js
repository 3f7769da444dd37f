// Hyperslices drawn on screen (thesis 9.2, figs. 9.3/9.4): a line drawn on the canvas defines
// the hyperslice whose centre plane projects onto it; a slider moves it along its normal; in
// and out points on the timeline bound it in time (or, for frames, set the slab's thickness).
//
// The formula (also in web/README.md, "Hyperslices"): with the wire camera (fx fy cx cy and
// world_from_camera R | e), the pixels p0, p1 of the line give the rays
//   d_i = R ((u_i - cx) / fx, (v_i - cy) / fy, 1);
// the plane through the eye containing both rays has the normal n = (d0 x d1) / |d0 x d1| and
// offset b = n . e in the displayed 3D space. The displayed space is D = B Y, Y = (x, y, z, s t),
// with B the 3x4 rows of the shown slice's frame (V2, V3, V4 of storage/hyperslice.cc; for a
// frame B = [I3 | 0]), so the 4D hyperplane n . B Y = b has the normal B^T n and the offset b.
// It contains the old slice's normal (time, when a frame is shown): the new slice reveals it.

// The rows V2, V3, V4 of R_H for a normal, as storage/hyperslice.cc's SliceGeometry::Make.
export function sliceBasis(normal) {
  const len = Math.hypot(...normal);
  const n = normal.map((x) => x / len);
  let drop = 0;
  for (let i = 1; i < 4; ++i) if (Math.abs(n[i]) > Math.abs(n[drop])) drop = i;
  const basis = [n];
  for (let axis = 0; axis < 4; ++axis) {
    if (axis === drop) continue;
    const v = [0, 0, 0, 0];
    v[axis] = 1;
    for (const b of basis) {
      const d = v[0] * b[0] + v[1] * b[1] + v[2] * b[2] + v[3] * b[3];
      for (let c = 0; c < 4; ++c) v[c] -= d * b[c];
    }
    const vl = Math.hypot(...v);
    basis.push(v.map((x) => x / vl));
  }
  return basis.slice(1);
}

export const FRAME_BASIS = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]];

const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

// World direction of the ray through pixel (u, v) of a wire camera, and the camera's eye.
export function pixelRay(cam, u, v) {
  const [fx, fy, cx, cy] = cam.intrinsics;
  const m = cam.world_from_camera;
  const c = [(u - cx) / fx, (v - cy) / fy, 1];
  return [0, 1, 2].map((r) => m[r * 4] * c[0] + m[r * 4 + 1] * c[1] + m[r * 4 + 2] * c[2]);
}
export const cameraEye = (cam) => [cam.world_from_camera[3], cam.world_from_camera[7], cam.world_from_camera[11]];

// The hyperslice {normal, offset} whose centre plane projects onto the line p0-p1.
export function sliceFromLine(cam, p0, p1, basis = FRAME_BASIS) {
  const n = cross(pixelRay(cam, p0[0], p0[1]), pixelRay(cam, p1[0], p1[1]));
  const len = Math.hypot(...n);
  if (!(len > 1e-12)) throw new Error('slice line: draw a line of a few pixels (its ends are the same point)');
  const n3 = n.map((x) => x / len);
  const normal = [0, 1, 2, 3].map((c) => basis[0][c] * n3[0] + basis[1][c] * n3[1] + basis[2][c] * n3[2]);
  return { normal, offset: dot3(n3, cameraEye(cam)) };
}

const unit4 = (v) => { const l = Math.hypot(...v); return v.map((x) => x / l); };
const $ = (id) => document.getElementById(id);

// The Slice panel: the drawn slice, its slider, the in / out points and the typed entry.
export class SliceTool {
  constructor(app) {
    this.app = app;
    this.base = null;     // the drawn (or typed) slice: {normal, offset, thickness}
    this.inOut = null;    // [t_in, t_out] seconds, or null (the whole video)
    $('slice-move').addEventListener('input', () => this.move().catch((e) => app.showError(e)));
    $('slice-in').addEventListener('click', () => this.markIn().catch((e) => app.showError(e)));
    $('slice-out').addEventListener('click', () => this.markOut().catch((e) => app.showError(e)));
    $('slice-clear-in-out').addEventListener('click', () => this.clearInOut().catch((e) => app.showError(e)));
  }

  get scale() { return Number(this.app.info?.space_time_scale) || 1; }

  // The basis of what is on screen (the displayed 3D space in terms of (x, y, z, s t)).
  shownBasis() { return this.app.viewMode === 'slice' ? sliceBasis(this.app.slice.normal) : FRAME_BASIS; }

  // A line drawn with the slice tool (canvas pixels): the new slice, shown.
  fromLine(p0, p1, cam = this.app.wireCamera()) {
    const s = sliceFromLine(cam, p0, p1, this.shownBasis());
    this.lastLine = { p0, p1, camera: cam };  // (a test hook: the formula's inputs)
    const thickness = Number($('slice-thickness').value);
    if (!(thickness >= 0)) throw new Error('slice thickness: a number >= 0 (metres along the normal)');
    // The new view looks along the ray through the line's middle (it lies in the new slice);
    // the line keeps its angle on screen and the old slice's normal (time, for a frame) takes
    // the place of the direction across the line: screen down = sin(a) L + cos(a) T.
    const B = this.shownBasis();
    const to4 = (d) => [0, 1, 2, 3].map((c) => B[0][c] * d[0] + B[1][c] * d[1] + B[2][c] * d[2]);
    const mid = pixelRay(cam, 0.5 * (p0[0] + p1[0]), 0.5 * (p0[1] + p1[1]));
    const du = p1[0] - p0[0], dv = p1[1] - p0[1], len = Math.hypot(du, dv);
    const m = cam.world_from_camera;
    const L = to4([0, 1, 2].map((i) => (du * m[4 * i] + dv * m[4 * i + 1]) / len));
    const T = this.app.viewMode === 'slice' ? unit4(this.app.slice.normal) : [0, 0, 0, 1];
    const up = L.map((x, i) => -(dv * x + du * T[i]) / len);
    if (this.app.viewMode === 'frames') this.savedView = this.app.cam.state();
    return this.show({ ...s, thickness }, { look: to4(mid), up });
  }

  // Shows a slice and makes it the slider's origin; reframe: {look, up} (4D directions) to
  // point the camera at the new slice's points along.
  async show(slice, reframe = null) {
    this.base = slice;
    const slider = $('slice-move');
    const b = this.app.info?.bounds_min, e = this.app.info?.bounds_max;
    const extent = b && e ? Math.hypot(...[0, 1, 2].map((i) => Number(e[i]) - Number(b[i]))) : 2;
    slider.min = String(-extent);
    slider.max = String(extent);
    slider.step = String(extent / 1000);
    slider.value = '0';
    this.syncInputs(slice);
    await this.app.showSlice(slice.normal, slice.offset, slice.thickness, this.timesFor(slice));
    if (reframe && this.app.shown?.points) this.fit(this.app.shown, reframe);
  }

  // Looks at the slice's points along the displayed image of reframe.look, up as reframe.up.
  fit(d, { look, up }) {
    const B = sliceBasis(this.app.slice.normal);
    const disp = (v) => B.map((r) => r[0] * v[0] + r[1] * v[1] + r[2] * v[2] + r[3] * v[3]);
    const unit = (v) => { const l = Math.hypot(...v); return l > 1e-9 ? v.map((x) => x / l) : null; };
    const dir = unit(disp(look));
    if (!dir) return;
    const u = disp(up), k = dot3(u, dir);
    const upv = unit(u.map((x, i) => x - k * dir[i])) || (Math.abs(dir[1]) < 0.9 ? [0, -1, 0] : [0, 0, 1]);
    const c = [0, 1, 2].map((i) => 0.5 * (d.bboxLo[i] + d.bboxHi[i]));
    const diag = Math.hypot(...[0, 1, 2].map((i) => d.bboxHi[i] - d.bboxLo[i]));
    const dist = (0.55 * diag) / Math.tan((this.app.cam.fovDeg * Math.PI) / 360) + 1e-3;
    this.app.cam.set(c.map((x, i) => x - dist * dir[i]), c, this.app.cam.fovDeg, upv);
    this.app.requestDraw();
  }

  // Back to frames: the view the first drawn slice replaced.
  restoreView() {
    const v = this.savedView;
    this.savedView = null;
    if (v) this.app.cam.set(v.eye, v.target, v.fovDeg, v.up);
  }

  // The slider moves the slice along its normal: offset = the drawn offset + the slider's value.
  move() {
    if (!this.base) throw new Error('slice slider: draw or show a slice first');
    const offset = this.base.offset + Number($('slice-move').value);
    this.syncInputs({ ...this.base, offset });
    return this.app.showSlice(this.base.normal, offset, this.base.thickness, this.timesFor(this.base));
  }

  syncInputs(s) {
    ['nx', 'ny', 'nz', 'nt'].forEach((k, i) => { $(`slice-${k}`).value = String(s.normal[i]); });
    $('slice-offset').value = String(s.offset);
    $('slice-thickness').value = String(s.thickness);
  }

  // The clip window's time range: the in / out points (not for their own t-slab).
  timesFor(slice) { return slice.fromInOut ? null : this.inOut; }

  markIn() { return this.setInOut(this.app.frame / this.app.info.fps, this.inOut ? this.inOut[1] : null); }
  markOut() { return this.setInOut(this.inOut ? this.inOut[0] : null, this.app.frame / this.app.info.fps); }
  clearInOut() { return this.setInOut(null, null); }

  // In and out points (seconds; null: the video's start / end). With frames on screen they
  // show frames in..out at once (thesis 9.2: a t-slab of thickness s (out - in) / 2); with a
  // slice, they bound it in time.
  async setInOut(tIn, tOut) {
    const a = this.app;
    const last = Math.max(0, a.info.frame_count - 1) / a.info.fps;
    if (tIn === null && tOut === null) this.inOut = null;
    else {
      let lo = tIn === null ? 0 : tIn, hi = tOut === null ? last : tOut;
      if (lo > hi) [lo, hi] = [hi, lo];
      this.inOut = [lo, hi];
    }
    $('slice-in-out').textContent = this.inOut ? `in ${this.inOut[0].toFixed(3)} s, out ${this.inOut[1].toFixed(3)} s` : 'whole video';
    if (a.viewMode === 'slice' && this.base && !this.base.fromInOut) return a.showSlice(a.slice.normal, a.slice.offset, a.slice.thickness, this.inOut);
    if (!this.inOut) return a.showFrames();
    // Half a frame more on either side: the frames at the in and out points are inside.
    const s = this.scale, half = 0.5 / a.info.fps;
    const slab = { normal: [0, 0, 0, 1], offset: s * 0.5 * (this.inOut[0] + this.inOut[1]), thickness: s * (0.5 * (this.inOut[1] - this.inOut[0]) + half), fromInOut: true };
    return this.show(slab, false);
  }
}
