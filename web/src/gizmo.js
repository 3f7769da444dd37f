// The transform gizmo drawn over the canvas at the selection's centre (transform tool, T):
// three axis arrows of the displayed space (drag: translate along the axis), a centre square
// (drag: translate in the view plane), a ring (drag around it: rotate about the view
// direction) and a corner square (drag: scale uniformly). A drag previews the map; it joins
// the pending transform (transform.js) that Apply sends as one edit.
import { fromDisplayed } from './transform.js';

const kArrowPx = 90, kRingPx = 110, kHandlePx = 7;
const COLORS = ['#e04040', '#3cdc50', '#4080ff'];

// Pixel of a displayed point through the page's camera (render::Camera: v down), and depth.
function project(cam, p) {
  const m = cam.world_from_camera;  // R | e, row-major; camera = R^T (p - e)
  const q = [p[0] - m[3], p[1] - m[7], p[2] - m[11]];
  const c = [0, 1, 2].map((k) => m[k] * q[0] + m[4 + k] * q[1] + m[8 + k] * q[2]);
  const [fx, fy, cx, cy] = cam.intrinsics;
  return { u: (fx * c[0]) / c[2] + cx, v: (fy * c[1]) / c[2] + cy, z: c[2] };
}
const camAxis = (cam, k) => [cam.world_from_camera[k], cam.world_from_camera[4 + k], cam.world_from_camera[8 + k]];

export class Gizmo {
  constructor(app, transformer) {
    this.app = app;
    this.xf = transformer;
    this.drag = null;
  }

  // Where the gizmo is: the selection's centre moved by the pending transform, on screen.
  layout() {
    const c = this.xf.centre();
    if (!c) return null;
    const cam = this.app.wireCamera();
    const pv = this.app.preview;
    const D = pv ? [0, 1, 2].map((r) => pv.m[3 * r] * c.D[0] + pv.m[3 * r + 1] * c.D[1] + pv.m[3 * r + 2] * c.D[2] + pv.t[r]) : c.D;
    const o = project(cam, D);
    if (!(o.z > 0)) return null;
    const metresPerPx = o.z / cam.intrinsics[0];
    const L = kArrowPx * metresPerPx;
    const axes = [0, 1, 2].map((k) => {
      const e = D.slice();
      e[k] += L;
      const q = project(cam, e);
      return { u: q.u, v: q.v, du: q.u - o.u, dv: q.v - o.v };
    });
    return { cam, D, o, L, axes, metresPerPx, scaleAt: [o.u + kRingPx * 0.7071, o.v - kRingPx * 0.7071] };
  }

  draw(ctx) {
    const g = this.layout();
    if (!g) return;
    ctx.save();
    ctx.lineWidth = 2;
    g.axes.forEach((a, k) => {
      ctx.strokeStyle = ctx.fillStyle = COLORS[k];
      ctx.beginPath(); ctx.moveTo(g.o.u, g.o.v); ctx.lineTo(a.u, a.v); ctx.stroke();
      ctx.beginPath(); ctx.arc(a.u, a.v, kHandlePx, 0, 2 * Math.PI); ctx.fill();
    });
    ctx.strokeStyle = '#ffb000';
    ctx.beginPath(); ctx.arc(g.o.u, g.o.v, kRingPx, 0, 2 * Math.PI); ctx.stroke();
    ctx.strokeStyle = '#ffffff';
    ctx.strokeRect(g.o.u - kHandlePx, g.o.v - kHandlePx, 2 * kHandlePx, 2 * kHandlePx);
    ctx.fillStyle = '#ffffff';
    ctx.fillRect(g.scaleAt[0] - kHandlePx, g.scaleAt[1] - kHandlePx, 2 * kHandlePx, 2 * kHandlePx);
    ctx.restore();
  }

  // Which handle is under pixel p: 'x' 'y' 'z' (arrow tips), 'move', 'scale', 'rotate'.
  hit(g, [u, v]) {
    const near = (a, b, r = kHandlePx + 4) => Math.hypot(u - a, v - b) <= r;
    for (let k = 0; k < 3; ++k) if (near(g.axes[k].u, g.axes[k].v)) return 'xyz'[k];
    if (near(g.scaleAt[0], g.scaleAt[1])) return 'scale';
    if (near(g.o.u, g.o.v)) return 'move';
    if (Math.abs(Math.hypot(u - g.o.u, v - g.o.v) - kRingPx) <= 6) return 'rotate';
    return null;
  }

  down(p) {
    const g = this.layout();
    if (!g) throw new Error('transform: select points first (nothing carries the selection bit on screen)');
    const handle = this.hit(g, p);
    if (!handle) return false;
    this.drag = { handle, g, start: p };
    return true;
  }

  move(p) {
    if (!this.drag) return;
    this.xf.showPreview(this.mapOf(this.drag, p));
  }

  up(p) {
    const d = this.drag;
    if (!d) return;
    this.drag = null;
    this.xf.push(this.mapOf(d, p));
  }

  // The drag from d.start to p as a 4D map (transform.js, fromDisplayed).
  mapOf(d, [u, v]) {
    const { g, handle } = d;
    const du = u - d.start[0], dv = v - d.start[1];
    const { B } = this.xf.space();
    const I3 = [1, 0, 0, 0, 1, 0, 0, 0, 1];
    if ('xyz'.includes(handle)) {
      const k = 'xyz'.indexOf(handle), a = g.axes[k];
      const len2 = a.du * a.du + a.dv * a.dv;
      const metres = len2 > 1e-9 ? ((du * a.du + dv * a.dv) / len2) * g.L : 0;
      const d3 = [0, 0, 0];
      d3[k] = metres;
      return fromDisplayed(B, I3, g.D, d3);
    }
    if (handle === 'move') {
      // In the view plane through the centre: camera x right, y down.
      const ax = camAxis(g.cam, 0), ay = camAxis(g.cam, 1);
      const d3 = [0, 1, 2].map((i) => g.metresPerPx * (du * ax[i] + dv * ay[i]));
      return fromDisplayed(B, I3, g.D, d3);
    }
    if (handle === 'scale') {
      const r0 = Math.hypot(d.start[0] - g.o.u, d.start[1] - g.o.v), r1 = Math.hypot(u - g.o.u, v - g.o.v);
      const k = Math.max(1e-3, r1 / Math.max(1, r0));
      return fromDisplayed(B, [k, 0, 0, 0, k, 0, 0, 0, k], g.D, [0, 0, 0]);
    }
    // Rotate about the view direction by the angle swept around the centre on screen (from
    // camera x towards camera y, as u towards v).
    const phi = Math.atan2(v - g.o.v, u - g.o.u) - Math.atan2(d.start[1] - g.o.v, d.start[0] - g.o.u);
    const c = Math.cos(phi), s = Math.sin(phi);
    const ax = camAxis(g.cam, 0), ay = camAxis(g.cam, 1), az = camAxis(g.cam, 2);
    // R = W Rc W^T with W = (ax ay az) as columns, Rc the rotation in the camera's xy plane.
    const M3 = [];
    for (let i = 0; i < 3; ++i) {
      for (let j = 0; j < 3; ++j) {
        M3.push(ax[i] * (c * ax[j] - s * ay[j]) + ay[i] * (s * ax[j] + c * ay[j]) + az[i] * az[j]);
      }
    }
    return fromDisplayed(B, M3, g.D, [0, 0, 0]);
  }
}
