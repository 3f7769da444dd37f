// The view camera: orbit and fly navigation, and the exact pinhole model of
// render::Camera::LookAt (render/splat.cc), so that the browser's picture, the server's
// renders and the lasso/brush requests all use the same projection.
import { mat4, vec3 } from '../node_modules/gl-matrix/esm/index.js';

export const DEFAULT_UP = [0, -1, 0];  // positions are metres with y pointing down

// The camera of render::Camera::LookAt, in doubles: {width, height, fx, fy, cx, cy, wfc}
// with wfc the row-major world_from_camera (columns right, down, forward, eye).
export function lookAtCamera(eye, target, up, fovYDeg, width, height) {
  const half = Math.tan((fovYDeg * Math.PI) / 360);
  const f = half > 0 ? (0.5 * height) / half : 0;
  // In doubles, as the server does (gl-matrix's vec3 is a Float32Array): the wire camera
  // must be orthonormal to 1e-4 and match the server's renders.
  const f0 = [target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]];
  const fn = Math.hypot(f0[0], f0[1], f0[2]);
  const Rr = [f0[1] * up[2] - f0[2] * up[1], f0[2] * up[0] - f0[0] * up[2], f0[0] * up[1] - f0[1] * up[0]];
  const rn = Math.hypot(Rr[0], Rr[1], Rr[2]);
  if (fn === 0 || rn === 0) throw new Error('camera: eye equals target, or up is parallel to the view');
  const F = f0.map((v) => v / fn);
  const R = Rr.map((v) => v / rn);
  const D = [F[1] * R[2] - F[2] * R[1], F[2] * R[0] - F[0] * R[2], F[0] * R[1] - F[1] * R[0]];
  const wfc = [R[0], D[0], F[0], eye[0],
    R[1], D[1], F[1], eye[1],
    R[2], D[2], F[2], eye[2],
    0, 0, 0, 1];
  return { width, height, fx: f, fy: f, cx: 0.5 * width - 0.5, cy: 0.5 * height - 0.5, wfc };
}

// The wire Camera of hvdb.proto for lasso and brush requests.
export function wireCamera(c) {
  return {
    width: c.width,
    height: c.height,
    intrinsics: [c.fx, c.fy, c.cx, c.cy],
    world_from_camera: c.wfc.slice(),
  };
}

// camera_from_world = [R^T | -R^T c] as render::internal::PrepareView computes it: rows of the
// rotation (row-major 3x3) and the translation, for the shaders.
export function viewTransform(c) {
  const m = c.wfc;
  const rot = new Float32Array(9);
  const trans = new Float32Array(3);
  for (let i = 0; i < 3; ++i) {
    for (let j = 0; j < 3; ++j) rot[i * 3 + j] = m[j * 4 + i];
    trans[i] = -(m[0 * 4 + i] * m[3] + m[1 * 4 + i] * m[7] + m[2 * 4 + i] * m[11]);
  }
  return { rot, trans };
}

// Orbit / pan / dolly around a target, or fly with WASD; up is fixed (default (0, -1, 0)).
export class ViewCamera {
  constructor() {
    this.eye = [0, 0, -3];
    this.target = [0, 0, 0];
    this.up = DEFAULT_UP.slice();
    this.fovDeg = 40;
    this.fly = false;
    this.version = 0;  // bumped on every change; the renderer redraws when it moves
  }

  set(eye, target, fovDeg = this.fovDeg, up = this.up) {
    this.eye = eye.map(Number);
    this.target = target.map(Number);
    this.fovDeg = Number(fovDeg);
    this.up = up.map(Number);
    this.changed();
  }

  // A copy of the view (slice_tool.js restores it when the page goes back to frames).
  state() { return { eye: this.eye.slice(), target: this.target.slice(), fovDeg: this.fovDeg, up: this.up.slice() }; }

    changed() { this.version++; }

  // Frames an axis-aligned box: look along +z at its centre from in front of it.
  frameBounds(lo, hi, fovDeg = 40, aspect = 16 / 9) {
    const c = [0, 1, 2].map((i) => 0.5 * (lo[i] + hi[i]));
    const ext = [0, 1, 2].map((i) => Math.max(1e-3, hi[i] - lo[i]));
    const halfTan = Math.tan((fovDeg * Math.PI) / 360);
    // Distance at which both the height and the width of the box fit, plus half its depth.
    const dist = Math.max(ext[1] / 2 / halfTan, ext[0] / 2 / (halfTan * aspect)) * 1.1 + ext[2] / 2;
    this.set([c[0], c[1], c[2] - dist], c, fovDeg, DEFAULT_UP);
  }

  // The render::Camera for a canvas of width x height device pixels.
  camera(width, height) {
    return lookAtCamera(this.eye, this.target, this.up, this.fovDeg, width, height);
  }

  basis() {
    const fwd = vec3.normalize(vec3.create(), vec3.sub(vec3.create(), this.target, this.eye));
    const right = vec3.normalize(vec3.create(), vec3.cross(vec3.create(), fwd, this.up));
    const down = vec3.cross(vec3.create(), fwd, right);
    return { fwd, right, down };
  }

  // Mouse drag of (dx, dy) CSS pixels: orbit about the target (or, flying, turn the head).
  rotate(dx, dy) {
    const yaw = -dx * 0.005, pitch = dy * 0.005;
    const { right } = this.basis();
    const pivot = this.fly ? this.eye : this.target;
    const moving = this.fly ? this.target : this.eye;
    let off = vec3.sub(vec3.create(), moving, pivot);
    const rYaw = mat4.fromRotation(mat4.create(), yaw, this.up);
    vec3.transformMat4(off, off, rYaw);
    const rPitch = mat4.fromRotation(mat4.create(), this.fly ? -pitch : pitch, right);
    const tried = vec3.transformMat4(vec3.create(), off, rPitch);
    // Refuse pitches that would cross the up axis (the look-at would flip).
    const upN = vec3.normalize(vec3.create(), this.up);
    if (Math.abs(vec3.dot(vec3.normalize(vec3.create(), tried), upN)) < 0.995) off = tried;
    const moved = [pivot[0] + off[0], pivot[1] + off[1], pivot[2] + off[2]];
    if (this.fly) this.target = moved; else this.eye = moved;
    this.changed();
  }

  // Pan by (dx, dy) pixels of a canvas `height` pixels tall: the target stays under the cursor.
  pan(dx, dy, height) {
    const { right, down } = this.basis();
    const dist = vec3.distance(this.eye, this.target);
    const perPixel = (2 * dist * Math.tan((this.fovDeg * Math.PI) / 360)) / Math.max(1, height);
    for (let i = 0; i < 3; ++i) {
      const d = -right[i] * dx * perPixel - down[i] * dy * perPixel;
      this.eye[i] += d;
      this.target[i] += d;
    }
    this.changed();
  }

  // Wheel: move the eye towards the target by a factor (never through it).
  dolly(factor) {
    const off = vec3.sub(vec3.create(), this.eye, this.target);
    const len = vec3.length(off);
    const next = Math.max(0.02, len * factor);
    vec3.scale(off, off, next / len);
    this.eye = [this.target[0] + off[0], this.target[1] + off[1], this.target[2] + off[2]];
    this.changed();
  }

  // Fly: move eye and target together along the view (forward, right, down) by metres.
  move(forward, rightward, downward) {
    const { fwd, right, down } = this.basis();
    for (let i = 0; i < 3; ++i) {
      const d = fwd[i] * forward + right[i] * rightward + down[i] * downward;
      this.eye[i] += d;
      this.target[i] += d;
    }
    this.changed();
  }

  distance() { return vec3.distance(this.eye, this.target); }
}

// Mouse and keyboard navigation on the canvas. `shouldNavigate(ev)` lets the editor keep
// left-button drags for its tools.
export class NavigationController {
  constructor(canvas, cam, { shouldNavigate = () => true, onChange = () => {} } = {}) {
    this.canvas = canvas;
    this.cam = cam;
    this.shouldNavigate = shouldNavigate;
    this.onChange = onChange;
    this.drag = null;
    this.keys = new Set();
    this.flySpeed = 1.0;  // m/s
    this.lastTick = 0;
    canvas.addEventListener('contextmenu', (e) => e.preventDefault());
    canvas.addEventListener('pointerdown', (e) => this.down(e));
    window.addEventListener('pointermove', (e) => this.moveEv(e));
    window.addEventListener('pointerup', () => { this.drag = null; });
    canvas.addEventListener('wheel', (e) => {
      e.preventDefault();
      if (this.cam.fly) this.cam.move(-Math.sign(e.deltaY) * 0.1 * this.flySpeed, 0, 0);
      else this.cam.dolly(Math.exp(Math.sign(e.deltaY) * 0.1));
      this.onChange();
    }, { passive: false });
    window.addEventListener('keydown', (e) => {
      if (!this.cam.fly || isTyping(e)) return;
      const k = e.key.toLowerCase();
      if ('wasdqe'.includes(k) && !e.ctrlKey && !e.metaKey) {
        this.keys.add(k);
        e.preventDefault();
        this.startTicking();
      }
    });
    window.addEventListener('keyup', (e) => this.keys.delete(e.key.toLowerCase()));
    window.addEventListener('blur', () => this.keys.clear());
  }

  down(e) {
    const pan = e.button === 2 || (e.button === 0 && e.shiftKey && this.shouldNavigate(e));
    if (e.button === 0 && !pan && !this.shouldNavigate(e)) return;
    if (e.button !== 0 && e.button !== 2) return;
    this.drag = { x: e.clientX, y: e.clientY, pan };
    e.preventDefault();
  }

  moveEv(e) {
    if (!this.drag) return;
    const dx = e.clientX - this.drag.x, dy = e.clientY - this.drag.y;
    this.drag.x = e.clientX;
    this.drag.y = e.clientY;
    if (dx === 0 && dy === 0) return;
    if (this.drag.pan) this.cam.pan(dx, dy, this.canvas.clientHeight);
    else this.cam.rotate(dx, dy);
    this.onChange();
  }

  startTicking() {
    if (this.ticking) return;
    this.ticking = true;
    this.lastTick = performance.now();
    const tick = (now) => {
      const dt = Math.min(0.1, (now - this.lastTick) / 1000);
      this.lastTick = now;
      if (!this.cam.fly || this.keys.size === 0) {
        this.ticking = false;
        return;
      }
      const s = this.flySpeed * dt * Math.max(0.2, this.cam.distance() / 2);
      const k = this.keys;
      this.cam.move((k.has('w') ? s : 0) - (k.has('s') ? s : 0),
        (k.has('d') ? s : 0) - (k.has('a') ? s : 0),
        (k.has('e') ? s : 0) - (k.has('q') ? s : 0));
      this.onChange();
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }
}

// Input types whose keys are text (a range slider or a checkbox is not typing).
const kTextInputTypes = new Set(['text', 'number', 'search', 'email', 'password', 'tel', 'url',
  'date', 'time', 'datetime-local', 'month', 'week']);

// Whether the element takes typed text: text-like inputs, textareas, selects, contenteditable.
export function isTextField(t) {
  if (!t || t.nodeType !== 1) return false;
  if (t.isContentEditable || t.tagName === 'TEXTAREA' || t.tagName === 'SELECT') return true;
  return t.tagName === 'INPUT' && kTextInputTypes.has((t.type || 'text').toLowerCase());
}

// Whether a key event goes to a text field (then the page's single-key shortcuts stay out).
export function isTyping(e) {
  return isTextField(e.target) || isTextField(document.activeElement);
}

// Whether the element is a form control (or link) that keyboard focus navigation belongs to.
export function isFormControl(t) {
  if (!t || t.nodeType !== 1) return false;
  if (isTextField(t)) return true;
  return ['INPUT', 'BUTTON', 'SELECT', 'TEXTAREA'].includes(t.tagName) || (t.tagName === 'A' && t.hasAttribute('href'));
}
