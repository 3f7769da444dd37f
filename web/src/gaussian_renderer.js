// WebGL2 3D Gaussian splatting: the forward pass of the 3DGS reference rasteriser as the
// server's CPU rasteriser computes it (render/gaussian_raster.h, render/gaussian_raster_kernels.h
// PrepareGroup and Alpha2 — the shader follows them line by line), drawn as one primitive a
// splat in a back-to-front order (gaussian_sort_worker.js) with premultiplied "over" blending
// (ONE, ONE_MINUS_SRC_ALPHA): the same sum as the reference's front-to-back C += c a T.
// The one rule it cannot follow is the reference's early termination (a pixel stops before the
// splat that would bring T below 1e-4): blending cannot read the pixel; what is added behind
// that point is below 1 % of the colour where it happens at all.
//
// Per-splat data lives in float textures (gaussian_records.js packSplats): 3 texels of
// position, opacity logit, covariance and label, and 1-12 texels of SH coefficients; the
// vertex attribute is the splat's index, from the sorted index buffer. Colours accumulate in
// an RGBA32F (or RGBA16F) target when EXT_color_buffer_float exists (8-bit blending of
// hundreds of layers loses several levels), then a resolve pass adds the background.
import { viewTransform } from './camera.js';
// The background is linear, the splats are not: linearToSrgb brings it to their values.
import { kResolveVS, linearToSrgb, program } from './renderer.js';

const kVS = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
layout(location = 0) in uint aIndex;
uniform sampler2D uSplat;     // 3 texels a splat
uniform sampler2D uSh;        // SH_TEXELS texels a splat: (deg + 1)^2 rgb coefficients, dc first
uniform int uTexShift;
uniform bool uAntialiased;
uniform vec3 uR0, uR1, uR2, uT, uEye; // camera_from_world rows, translation; camera centre
uniform vec4 uK;                      // fx fy cx cy
uniform vec2 uSize, uLim;             // image size; 1.3 tan(half fov) in x and y
uniform float uMaxPointSize;
uniform uint uSelMask;
uniform bool uOverlay;
uniform vec4 uHighlight;              // display rgb, amount (the server's highlight_color)
uniform bool uPreview;                // a transform's preview: selected splats moved
uniform mat3 uPM;
uniform vec3 uPT;
flat out vec2 vCenter;
flat out vec3 vConic;
flat out float vOpacity;
flat out vec3 vColor;
flat out vec4 vBox;                   // x0 x1 y0 y1: the pixels it may touch
const float kC0 = 0.28209479177387814;
vec4 fetch(sampler2D s, int i) { return texelFetch(s, ivec2(i & ((1 << uTexShift) - 1), i >> uTexShift), 0); }
void cull() { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); gl_PointSize = 0.0; }
bool bad(float x) { return isnan(x) || isinf(x); }
void main() {
  int i = int(aIndex);
  vec4 t0 = fetch(uSplat, 3 * i), t1 = fetch(uSplat, 3 * i + 1), t2 = fetch(uSplat, 3 * i + 2);
  vec3 p = t0.xyz;
  mat3 V = mat3(t1.x, t1.y, t1.z,  t1.y, t1.w, t2.x,  t1.z, t2.x, t2.y);
  uint label = uint(t2.z) | (uint(t2.w) << 16);
  bool selected = (label & uSelMask) != 0u;
  if (uPreview && selected) { p = uPM * p + uPT; V = uPM * V * transpose(uPM); }
  // PrepareGroup: view-space centre, culled at z <= 0.2.
  float tx = uR0.x * p.x + uR0.y * p.y + uR0.z * p.z + uT.x;
  float ty = uR1.x * p.x + uR1.y * p.y + uR1.z * p.z + uT.y;
  float tz = uR2.x * p.x + uR2.y * p.y + uR2.z * p.z + uT.z;
  if (!(tz > 0.2)) { cull(); return; }
  // EWA: J W V W^T J^T, the Jacobian clamped to 1.3 times the field of view; + 0.3 px^2.
  float invZ = 1.0 / tz;
  float xc = min(uLim.x, max(-uLim.x, tx * invZ)) * tz;
  float yc = min(uLim.y, max(-uLim.y, ty * invZ)) * tz;
  float j00 = uK.x * invZ, j02 = -(uK.x * xc) * (invZ * invZ);
  float j11 = uK.y * invZ, j12 = -(uK.y * yc) * (invZ * invZ);
  vec3 r0 = j00 * uR0 + j02 * uR2, r1 = j11 * uR1 + j12 * uR2;
  vec3 s0 = V * r0, s1 = V * r1;
  float cxx = dot(r0, s0), cxy = dot(r1, s0), cyy = dot(r1, s1);
  float det0 = cxx * cyy - cxy * cxy;
  cxx += 0.3;
  cyy += 0.3;
  float det = cxx * cyy - cxy * cxy;
  if (det == 0.0) { cull(); return; }
  float detInv = 1.0 / det;
  float opacity = 1.0 / (1.0 + exp(min(-t0.w, 80.0)));
  if (uAntialiased) opacity *= sqrt(max(0.0, det0 / det));
  float mid = 0.5 * (cxx + cyy);
  float root3 = 3.0 * sqrt(mid + sqrt(max(0.1, mid * mid - det)));
  float u = uK.x * tx * invZ + uK.z, w = uK.y * ty * invZ + uK.w;
  vec3 conic = vec3(cyy * detInv, -cxy * detInv, cxx * detInv);
  if (bad(u) || bad(w) || bad(root3) || bad(conic.x + conic.y + conic.z) || bad(cxx + cyy) || bad(opacity)) { cull(); return; }
  // getRect: the reference draws a splat in the 16x16 tiles its square of radius
  // ceil(3 sqrt(lambda_max)) touches. Within those, the pixels where alpha can reach 1/255:
  // the box of that ellipse (widened as PrepareGroup widens it), cut to the tiles. Not just
  // the 3-sigma square: opaque splats reach 1/255 up to 3.3 sigma, in the tiles' margin.
  float radius = ceil(min(root3, 1e9));
  vec2 tiles = ceil(uSize / 16.0);
  vec2 rlo = trunc(clamp((vec2(u, w) - radius) * (1.0 / 16.0), vec2(0.0), tiles));
  vec2 rhi = trunc(clamp((vec2(u, w) + radius + 15.0) * (1.0 / 16.0), vec2(0.0), tiles));
  if ((rhi.x - rlo.x) * (rhi.y - rlo.y) == 0.0 || !(opacity >= 1.0 / 255.0)) { cull(); return; }
  float kq = 2.0 * log(max(255.0 * opacity, 1.0)) * 1.001 + 0.01;
  float ex = sqrt(kq * max(cxx, 0.0)) * 1.001 + 0.01, ey = sqrt(kq * max(cyy, 0.0)) * 1.001 + 0.01;
  float x0 = max(ceil(clamp(u - ex, -1.0, uSize.x)), rlo.x * 16.0);
  float x1 = min(min(floor(clamp(u + ex, -1.0, uSize.x)), rhi.x * 16.0 - 1.0), uSize.x - 1.0);
  float y0 = max(ceil(clamp(w - ey, -1.0, uSize.y)), rlo.y * 16.0);
  float y1 = min(min(floor(clamp(w + ey, -1.0, uSize.y)), rhi.y * 16.0 - 1.0), uSize.y - 1.0);
  if (!(x0 <= x1) || !(y0 <= y1)) { cull(); return; }
  // Colour: the SH for the direction from the camera centre, + 0.5, clamped below at 0. The
  // program is made per degree with the sum written out (vertexShader): only the degree's
  // texels are fetched, and no array is indexed at run time (compilers may put one in memory).
  vec4 s[SH_TEXELS];
  for (int k = 0; k < SH_TEXELS; ++k) s[k] = fetch(uSh, SH_TEXELS * i + k);
  vec3 dir = p - uEye;
  dir *= 1.0 / sqrt(dot(dir, dir));
  float x = dir.x, y = dir.y, z = dir.z;
  float xx = x * x, yy = y * y, zz = z * z;
  vec3 col = kC0 * vec3(s[0].x, s[0].y, s[0].z);
SH_CODE
  col += 0.5;
  // The server's highlight: base colour toward the highlight, view-dependent part faded alike.
  if (uOverlay && selected) col = mix(col, uHighlight.rgb, uHighlight.a);
  if (bad(col.r + col.g + col.b)) { cull(); return; }
  vCenter = vec2(u, w);
  vConic = conic;
  vOpacity = opacity;
  vColor = max(col, 0.0);
  vBox = vec4(x0, x1, y0, y1);
#if defined(SPRITES)
  // A square sprite centred on the box (inside the image: a point whose centre leaves the
  // viewport is clipped whole), a pixel larger against rounding; the fragment cuts the box.
  gl_PointSize = min(max(x1 - x0, y1 - y0) + 1.0, uMaxPointSize);
  vec2 m = vec2(0.5 * (x0 + x1) + 0.5, 0.5 * (y0 + y1) + 0.5);
  gl_Position = vec4(m.x / uSize.x * 2.0 - 1.0, 1.0 - m.y / uSize.y * 2.0, 0.0, 1.0);
#else
  // The box's pixels exactly: pixel x spans [x, x + 1) in window coordinates.
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));
  vec2 q = mix(vec2(x0, y0), vec2(x1 + 1.0, y1 + 1.0), corner);
  gl_Position = vec4(q.x / uSize.x * 2.0 - 1.0, 1.0 - q.y / uSize.y * 2.0, 0.0, 1.0);
#endif
}`;

// Alpha2 of gaussian_raster_kernels.h for one pixel (its centre at integer coordinates, v down).
const kFS = `#version 300 es
precision highp float;
flat in vec2 vCenter;
flat in vec3 vConic;
flat in float vOpacity;
flat in vec3 vColor;
flat in vec4 vBox;
uniform vec2 uSize;
out vec4 o;
void main() {
  vec2 px = vec2(gl_FragCoord.x - 0.5, uSize.y - gl_FragCoord.y - 0.5);
  if (px.x < vBox.x || px.x > vBox.y || px.y < vBox.z || px.y > vBox.w) discard;
  vec2 d = vCenter - px;
  float power = (-0.5 * vConic.x * d.x - vConic.y * d.y) * d.x - 0.5 * (vConic.z * d.y * d.y);
  if (power > 0.0) discard;
  float alpha = min(0.99, vOpacity * exp(max(power, -20.0)));
  if (alpha < 1.0 / 255.0) discard;
  o = vec4(vColor * alpha, alpha);
}`;

// C + T background (display values, as DrawGaussians in render/job/gaussian.cc), alpha 1 - T
// plus the background's behind it; premultiplied for the canvas.
const kResolveFS = `#version 300 es
precision highp float;
uniform highp sampler2D uAccum;
uniform vec4 uBg;      // display rgb times alpha, alpha
uniform vec2 uResolve;
uniform ivec2 uTargetMax;
out vec4 o;
void main() {
  vec4 acc = texelFetch(uAccum, min(ivec2(gl_FragCoord.xy * uResolve), uTargetMax), 0);
  float t = 1.0 - acc.a;
  float a = clamp(acc.a + t * uBg.a, 0.0, 1.0);
  o = vec4(clamp(acc.rgb + t * uBg.rgb, vec3(0.0), vec3(a)), a);
}`;

// The SH basis of render/gaussian_raster_kernels.h (signs folded in), coefficient j >= 1.
const kBasis = [
  '-0.4886025119029199 * y', '0.4886025119029199 * z', '-0.4886025119029199 * x',
  '1.0925484305920792 * x * y', '-1.0925484305920792 * y * z', '0.31539156525252005 * (2.0 * zz - xx - yy)',
  '-1.0925484305920792 * x * z', '0.5462742152960396 * (xx - yy)',
  '-0.5900435899266435 * y * (3.0 * xx - yy)', '2.890611442640554 * x * y * z',
  '-0.4570457994644658 * y * (4.0 * zz - xx - yy)', '0.3731763325901154 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)',
  '-0.4570457994644658 * x * (4.0 * zz - xx - yy)', '1.445305721320277 * z * (xx - yy)',
  '-0.5900435899266435 * x * (xx - 3.0 * yy)',
];

// The vertex shader for SH degree `degree`: the texels per splat and the sum, unrolled.
function vertexShader(degree, sprites) {
  const texels = Math.ceil((3 * (degree + 1) ** 2) / 4);
  const at = (f) => `s[${f >> 2}].${'xyzw'[f & 3]}`;
  const lines = [];
  for (let j = 1; j < (degree + 1) ** 2; ++j) {
    lines.push(`  col += (${kBasis[j - 1]}) * vec3(${at(3 * j)}, ${at(3 * j + 1)}, ${at(3 * j + 2)});`);
  }
  let src = kVS.replace('SH_CODE', lines.join('\n')).replace(/SH_TEXELS/g, String(texels));
  if (sprites) src = src.replace('#version 300 es', '#version 300 es\n#define SPRITES');
  return src;
}


export const kHighlight = [1, 0.45, 0, 0.5];  // hvdb render's default --highlight-color

export class GaussianRenderer {
  // splats: the SplatRenderer of the page (its context, and its sprites-or-quads choice).
  constructor(splats) {
    const gl = splats.gl;
    this.gl = gl;
    this.software = splats.software;
    // Sprites on a software rasteriser, as renderer.js: SwiftShader draws instances one at a
    // time, and a sprite is one vertex (one set of 4-15 texel fetches) where a quad is four
    // (29 k degree-3 splats at 640x360: 200 ms as sprites, 450 ms as quads; at half size 80
    // and 350 ms). Their cost: a square instead of the box, and boxes wider than the largest
    // point size (SwiftShader: 1023 px) cut. GPUs get instanced quads of the box.
    this.sprites = splats.sprites;
    this.maxPointSize = gl.getParameter(gl.ALIASED_POINT_SIZE_RANGE)[1];
    this.floatTargets = !!gl.getExtension('EXT_color_buffer_float');
    this.floatBlend = !!gl.getExtension('EXT_float_blend');
    const maxTex = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    this.texShift = Math.min(12, Math.floor(Math.log2(maxTex)));
    this.texWidth = 1 << this.texShift;
    this.maxRows = maxTex;
    this.progs = [];  // per SH degree, made when a frame of that degree is first drawn
    this.resolve = program(gl, kResolveVS, kResolveFS, 'gaussian resolve');
    this.vao = gl.createVertexArray();
    this.emptyVao = gl.createVertexArray();
    this.targets = new Map();
    this.background = [0, 0, 0, 1];  // linear RGBA, as SplatRenderer's
    this.lastStats = { splats: 0, ms: 0 };
  }

  get accumFormat() { return this.floatTargets ? (this.floatBlend ? 'RGBA32F' : 'RGBA16F') : 'canvas (8 bits)'; }

  texture(data, rows) {
    const gl = this.gl;
    if (rows > this.maxRows) throw new Error(`gaussian mode: ${rows} texture rows pass this GPU's ${this.maxRows}: too many splats in one frame`);
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, this.texWidth, rows, 0, gl.RGBA, gl.FLOAT, data);
    gl.bindTexture(gl.TEXTURE_2D, null);
    return t;
  }

  // GPU copy of a frame's packed splats (gaussian_records.js packSplats); its order is set later.
  createFrame(packed) {
    const gl = this.gl;
    const f = {
      n: packed.n,
      degree: packed.degree,
      antialiased: packed.antialiased,
      shTexels: packed.shTexels,
      splat: this.texture(packed.splat, packed.splatRows),
      sh: this.texture(packed.sh, packed.shRows),
      order: gl.createBuffer(),
      count: 0,
      bytes: (packed.splat.length + packed.sh.length) * 4,
    };
    return f;
  }

  setOrder(f, order) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, f.order);
    gl.bufferData(gl.ARRAY_BUFFER, order, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, null);
    f.count = order.length;
  }

  deleteFrame(f) {
    const gl = this.gl;
    gl.deleteTexture(f.splat);
    gl.deleteTexture(f.sh);
    gl.deleteBuffer(f.order);
    f.count = 0;
  }

  target(w, h) {
    const key = `${w}x${h}`;
    let t = this.targets.get(key);
    if (t) return t;
    const gl = this.gl;
    if (this.targets.size >= 2) {  // the canvas's size and playback's
      const [k, old] = this.targets.entries().next().value;
      gl.deleteTexture(old.tex);
      gl.deleteFramebuffer(old.fbo);
      this.targets.delete(k);
    }
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texStorage2D(gl.TEXTURE_2D, 1, this.floatBlend ? gl.RGBA32F : gl.RGBA16F, w, h);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
    const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`WebGL: gaussian accumulation target incomplete (0x${status.toString(16)})`);
    t = { tex, fbo };
    this.targets.set(key, t);
    return t;
  }

  // Draws frame `f` (createFrame, with an order) from `cam` (camera.lookAtCamera of the drawing
  // buffer's size). opts: {resolution, selMask, overlay, preview}. f null: the background only.
  draw(f, cam, opts = {}) {
    const gl = this.gl;
    const t0 = performance.now();
    const cw = gl.drawingBufferWidth, ch = gl.drawingBufferHeight;
    const direct = !this.floatTargets;  // no float targets: blended straight into the canvas
    const res = direct ? 1 : Math.min(1, Math.max(0.1, opts.resolution || 1));
    const w = Math.max(1, Math.round(cw * res)), h = Math.max(1, Math.round(ch * res));
    if (w !== cw || h !== ch) {
      const sx = w / cw, sy = h / ch;  // render::Camera::Resized
      cam = { ...cam, width: w, height: h, fx: cam.fx * sx, fy: cam.fy * sy, cx: (cam.cx + 0.5) * sx - 0.5, cy: (cam.cy + 0.5) * sy - 0.5 };
    }
    const bg = this.background;
    const bgDisplay = [0, 1, 2].map((c) => linearToSrgb(bg[c]) * bg[3]);
    gl.disable(gl.DEPTH_TEST);
    gl.depthMask(false);
    if (direct) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, w, h);
      gl.clearColor(bgDisplay[0], bgDisplay[1], bgDisplay[2], bg[3]);
      gl.clear(gl.COLOR_BUFFER_BIT);
    } else {
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.target(w, h).fbo);
      gl.viewport(0, 0, w, h);
      gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
    }
    let n = 0;
    if (f && f.count > 0) {
      const prog = this.progs[f.degree] || (this.progs[f.degree] = program(gl, vertexShader(f.degree, this.sprites), kFS, `gaussian splat (degree ${f.degree})`));
      const u = prog.u;
      gl.useProgram(prog.p);
      const { rot, trans } = viewTransform(cam);
      const m = cam.wfc;
      gl.uniform3f(u.uR0, rot[0], rot[1], rot[2]);
      gl.uniform3f(u.uR1, rot[3], rot[4], rot[5]);
      gl.uniform3f(u.uR2, rot[6], rot[7], rot[8]);
      gl.uniform3f(u.uT, trans[0], trans[1], trans[2]);
      gl.uniform3f(u.uEye, m[3], m[7], m[11]);
      gl.uniform4f(u.uK, cam.fx, cam.fy, cam.cx, cam.cy);
      gl.uniform2f(u.uSize, w, h);
      // MakeView: tan of the half field of view from the size and focal length, in double.
      gl.uniform2f(u.uLim, Math.fround(1.3) * Math.fround(w / (2 * cam.fx)), Math.fround(1.3) * Math.fround(h / (2 * cam.fy)));
      gl.uniform1f(u.uMaxPointSize, this.maxPointSize);
      gl.uniform1i(u.uTexShift, this.texShift);
      gl.uniform1i(u.uAntialiased, f.antialiased ? 1 : 0);
      gl.uniform1ui(u.uSelMask, (opts.selMask || 0) >>> 0);
      gl.uniform1i(u.uOverlay, opts.overlay ? 1 : 0);
      gl.uniform4f(u.uHighlight, ...kHighlight);
      const pv = opts.preview;
      gl.uniform1i(u.uPreview, pv ? 1 : 0);
      if (pv) {
        const a = pv.m;
        gl.uniformMatrix3fv(u.uPM, false, [a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8]]);
        gl.uniform3f(u.uPT, pv.t[0], pv.t[1], pv.t[2]);
      }
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, f.splat);
      gl.activeTexture(gl.TEXTURE1);
      gl.bindTexture(gl.TEXTURE_2D, f.sh);
      gl.uniform1i(u.uSplat, 0);
      gl.uniform1i(u.uSh, 1);
      gl.bindVertexArray(this.vao);
      gl.bindBuffer(gl.ARRAY_BUFFER, f.order);
      gl.enableVertexAttribArray(0);
      gl.vertexAttribIPointer(0, 1, gl.UNSIGNED_INT, 4, 0);
      gl.vertexAttribDivisor(0, this.sprites ? 0 : 1);
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
      if (this.sprites) gl.drawArrays(gl.POINTS, 0, f.count);
      else gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, f.count);
      gl.disable(gl.BLEND);
      gl.bindVertexArray(null);
      gl.bindBuffer(gl.ARRAY_BUFFER, null);
      n = f.count;
    }
    if (!direct) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, cw, ch);
      const r = this.resolve;
      gl.useProgram(r.p);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.target(w, h).tex);
      gl.uniform1i(r.u.uAccum, 0);
      gl.uniform4f(r.u.uBg, bgDisplay[0], bgDisplay[1], bgDisplay[2], bg[3]);
      gl.uniform2f(r.u.uResolve, w / cw, h / ch);
      gl.uniform2i(r.u.uTargetMax, w - 1, h - 1);
      gl.bindVertexArray(this.emptyVao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
    }
    gl.activeTexture(gl.TEXTURE0);
    const err = gl.getError();
    if (err !== gl.NO_ERROR && err !== this.lastGlError) {
      this.lastGlError = err;
      throw new Error(`WebGL error 0x${err.toString(16)} while drawing Gaussians`);
    }
    this.lastStats = { splats: n, ms: performance.now() - t0, resolution: w / cw };
    return n;
  }
}
