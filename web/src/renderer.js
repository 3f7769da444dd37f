// WebGL2 EWA splatting in the "visibility" mode of the server's CPU renderer
// (render/cpu_renderer.cc, RasteriseVisibility; render/splat.cc, ProjectSplat):
//   pass 1: nearest splat depth per pixel (camera z + depth slope) into a float depth texture;
//   pass 2: every fragment adds exp(-q/2) to the coverage, and those within dz of the nearest
//           depth add w * linear colour and w (additive blending into float targets);
//   pass 3: colour = sum / w, coverage min(1, a), over the background, linear -> sRGB.
// The per-point maths follow ProjectSplat step by step so that the picture matches the
// server's render of the same camera. Without float render targets (or with
// renderer=points) it falls back to depth-tested gl.POINTS.
import { viewTransform } from './camera.js';

const kCommonVS = `#version 300 es
precision highp float;
precision highp int;
layout(location = 0) in vec3 aPos;
layout(location = 1) in vec3 aColor;   // u8 sRGB, normalised
layout(location = 2) in vec3 aCov0;    // xx xy xz
layout(location = 3) in vec3 aCov1;    // yy yz zz
layout(location = 4) in uint aLabel;
layout(location = 5) in uint aFlags;
uniform vec3 uR0, uR1, uR2, uT;        // camera_from_world rows and translation
uniform vec4 uK;                       // fx fy cx cy
uniform vec2 uSize;                    // image width, height (pixels)
uniform float uScale2, uFilter, uCutoff2, uDefaultVar, uNear, uMaxPointSize;
uniform uint uSelMask;
uniform bool uOverlay;
uniform bool uPreview;                 // a transform's preview: selected points moved
uniform mat3 uPM;                      // (gizmo.js) by P' = uPM P + uPT, V' = uPM V uPM^T
uniform vec3 uPT;
flat out vec3 vConic;   // ca cb cc: inverse screen covariance
flat out vec2 vCenter;  // u v (pixel centres at integers, v down)
flat out vec3 vDepth;   // z, dz/dx, dz/dy
flat out vec3 vColor;   // linear rgb
const uint kFlagHasCovariance = 2u;
float srgbToLinear(float v) { return v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4); }
void cull() { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); gl_PointSize = 0.0; }
void main() {
  bool moved = uPreview && (aLabel & uSelMask) != 0u;
  vec3 pos = moved ? uPM * aPos + uPT : aPos;
  float xc = dot(uR0, pos) + uT.x;
  float yc = dot(uR1, pos) + uT.y;
  float zc = dot(uR2, pos) + uT.z;
  if (!(zc >= uNear)) { cull(); return; }
  float invZ = 1.0 / zc;
  float a = xc * invZ, b = yc * invZ;
  float u = uK.x * a + uK.z;
  float v = uK.y * b + uK.w;
  vec3 t0 = uK.x * ((uR0 - a * uR2) * invZ);
  vec3 t1 = uK.y * ((uR1 - b * uR2) * invZ);
  vec3 c0 = aCov0, c1 = aCov1;
  if ((aFlags & kFlagHasCovariance) == 0u) { c0 = vec3(uDefaultVar, 0.0, 0.0); c1 = vec3(uDefaultVar, 0.0, uDefaultVar); }
  mat3 V = mat3(c0.x, c0.y, c0.z,  c0.y, c1.x, c1.y,  c0.z, c1.y, c1.z);
  if (moved) V = uPM * V * transpose(uPM);
  vec3 vt0 = V * t0, vt1 = V * t1;
  float s00 = dot(t0, vt0) * uScale2 + uFilter;
  float s01 = dot(t0, vt1) * uScale2;
  float s11 = dot(t1, vt1) * uScale2 + uFilter;
  float det = s00 * s11 - s01 * s01;
  if (!(det > 0.0) || isinf(det)) { cull(); return; }
  float ex = sqrt(uCutoff2 * s00), ey = sqrt(uCutoff2 * s11);
  float x0 = max(ceil(u - ex), 0.0), x1 = min(floor(u + ex), uSize.x - 1.0);
  float y0 = max(ceil(v - ey), 0.0), y1 = min(floor(v + ey), uSize.y - 1.0);
  if (!(x0 <= x1) || !(y0 <= y1)) { cull(); return; }
  float invDet = 1.0 / det;
  vConic = vec3(s11 * invDet, -s01 * invDet, s00 * invDet);
  vCenter = vec2(u, v);
  float s02 = dot(uR2, vt0) * uScale2, s12 = dot(uR2, vt1) * uScale2;
  vDepth = vec3(zc, vConic.x * s02 + vConic.y * s12, vConic.y * s02 + vConic.z * s12);
  vec3 lin = vec3(srgbToLinear(aColor.r), srgbToLinear(aColor.g), srgbToLinear(aColor.b));
  if (uOverlay && (aLabel & uSelMask) != 0u) lin = mix(lin, vec3(1.0, 0.32, 0.0), 0.5);
  vColor = lin;
#if defined(SPRITES)
  // One point sprite a splat, its square covering the cutoff ellipse's bounding box (and a
  // pixel more against rounding); the fragment shader's kernel test cuts it to the ellipse.
  gl_PointSize = min(2.0 * max(ex, ey) + 2.0, uMaxPointSize);
  gl_Position = vec4((u + 0.5) / uSize.x * 2.0 - 1.0, 1.0 - (v + 0.5) / uSize.y * 2.0, 0.0, 1.0);
#elif defined(POINTS)
  gl_PointSize = clamp(2.0 * sqrt(max(s00, s11)), 1.0, 64.0);
  gl_Position = vec4((u + 0.5) / uSize.x * 2.0 - 1.0, 1.0 - (v + 0.5) / uSize.y * 2.0, clamp(zc / 1e4, 0.0, 1.0) * 2.0 - 1.0, 1.0);
#else
  // The quad is the cutoff ellipse's oriented bounding box, half a pixel larger against
  // rounding (the CPU renderer visits the same pixels: its box rows, cut to the ellipse;
  // the kernel test in the fragment shader decides). Elongated splats then cost far fewer
  // fragments than their axis-aligned box, which matters on software GL.
  float mid = 0.5 * (s00 + s11), h = sqrt(0.25 * (s00 - s11) * (s00 - s11) + s01 * s01);
  float l1 = mid + h, l2 = max(mid - h, 0.0);
  vec2 e1 = vec2(l1 - s11, s01);
  float e1n = length(e1);
  e1 = e1n > 1e-20 ? e1 / e1n : (s00 >= s11 ? vec2(1.0, 0.0) : vec2(0.0, 1.0));
  vec2 e2 = vec2(-e1.y, e1.x);
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
  vec2 p = vec2(u, v) + corner.x * (sqrt(uCutoff2 * l1) + 0.5) * e1 + corner.y * (sqrt(uCutoff2 * l2) + 0.5) * e2;
  gl_Position = vec4((p.x + 0.5) / uSize.x * 2.0 - 1.0, 1.0 - (p.y + 0.5) / uSize.y * 2.0, 0.0, 1.0);
#endif
}`;

const kFragmentHead = `#version 300 es
precision highp float;
precision highp int;
flat in vec3 vConic;
flat in vec2 vCenter;
flat in vec3 vDepth;
flat in vec3 vColor;
uniform vec2 uSize;
uniform float uCutoff2, uZFar, uDz;
float linearToSrgb(float v) { return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055; }
`;

// The kernel exponent and the fragment depth, as Evaluate() in cpu_renderer.cc.
const kKernel = `
  vec2 d = vec2(gl_FragCoord.x - 0.5, uSize.y - gl_FragCoord.y - 0.5) - vCenter;
  float q = vConic.x * d.x * d.x + (2.0 * vConic.y * d.y) * d.x + vConic.z * d.y * d.y;
  if (!(q <= uCutoff2)) discard;
  float z = max(vDepth.x + vDepth.y * d.x + vDepth.z * d.y, 0.0);
`;

const kDepthFS = `${kFragmentHead}
void main() {${kKernel}
  gl_FragDepth = clamp(z / uZFar, 0.0, 1.0);
}`;

const kAccumFS = `${kFragmentHead}
uniform highp sampler2D uDepthTex;
layout(location = 0) out vec4 oAccum;
layout(location = 1) out vec4 oCover;
void main() {${kKernel}
  float zmin = texelFetch(uDepthTex, ivec2(gl_FragCoord.xy), 0).r * uZFar;
  float a = exp(-0.5 * q);
  oAccum = (z - uDz <= zmin) ? vec4(vColor * a, a) : vec4(0.0);  // the fuzzy depth test
  oCover = vec4(a, 0.0, 0.0, 0.0);
}`;

const kPointsFS = `${kFragmentHead}
out vec4 o;
void main() {
  o = vec4(linearToSrgb(vColor.r), linearToSrgb(vColor.g), linearToSrgb(vColor.b), 1.0);
}`;

// A triangle over the whole target (the resolve passes of both renderers).
export const kResolveVS = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) * 4 - 1), float((gl_VertexID >> 1) * 4 - 1));
  gl_Position = vec4(p, 0.0, 1.0);
}`;

const kResolveFS = `#version 300 es
precision highp float;
uniform highp sampler2D uAccum;
uniform highp sampler2D uCover;
uniform vec4 uBg;  // linear, straight alpha
uniform vec2 uResolve;  // target size / canvas size (below 1 while drawing at reduced resolution)
uniform ivec2 uTargetMax;
out vec4 o;
float linearToSrgb(float v) { return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055; }
void main() {
  ivec2 p = min(ivec2(gl_FragCoord.xy * uResolve), uTargetMax);
  vec4 acc = texelFetch(uAccum, p, 0);
  float a = texelFetch(uCover, p, 0).r;
  vec3 col = vec3(0.0);
  float c = 0.0;
  if (a > 0.0 && acc.a > 0.0) { col = acc.rgb / acc.a; c = min(1.0, a); }
  float keep = (1.0 - c) * uBg.a;  // render::internal::Composite
  vec3 rgb = clamp(c * col + keep * uBg.rgb, 0.0, 1.0);
  o = vec4(linearToSrgb(rgb.r), linearToSrgb(rgb.g), linearToSrgb(rgb.b), c + keep);
}`;

function compile(gl, type, src, what) {
  const s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
    const log = gl.getShaderInfoLog(s);
    gl.deleteShader(s);
    throw new Error(`WebGL: ${what} shader does not compile: ${log}`);
  }
  return s;
}

// A linked program and its uniforms' locations by name (an array's also without its "[0]");
// shared with gaussian_renderer.js.
export function program(gl, vs, fs, what) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs, what));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs, what));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`WebGL: ${what} program does not link: ${gl.getProgramInfoLog(p)}`);
  const uniforms = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; ++i) {
    const info = gl.getActiveUniform(p, i);
    const loc = gl.getUniformLocation(p, info.name);
    uniforms[info.name] = loc;
    uniforms[info.name.replace(/\[0\]$/, '')] = loc;
  }
  return { p, u: uniforms };
}

// The exact sRGB curve of render::LinearToSrgb.
export function linearToSrgb(v) {
  const c = Math.min(1, Math.max(0, v));
  return c <= 0.0031308 ? 12.92 * c : 1.055 * Math.pow(c, 1 / 2.4) - 0.055;
}

export const RENDER_DEFAULTS = {
  depthThreshold: 0.02,  // dz of the fuzzy depth test (m)
  cutoffRadius: 2.5,     // standard deviations
  filterVariance: 1.0,   // pixels^2
  defaultSigma: 0.005,   // metres, points without a covariance
  nearPlane: 0.01,
};

export class SplatRenderer {
  constructor(canvas, { mode = 'splats', primitive = 'auto' } = {}) {
    this.canvas = canvas;
    const gl = canvas.getContext('webgl2', { preserveDrawingBuffer: true, antialias: false, depth: true, alpha: true, premultipliedAlpha: true });
    if (!gl) throw new Error('WebGL2 is not available in this browser');
    this.gl = gl;
    this.mode = mode;
    const cbf = gl.getExtension('EXT_color_buffer_float');
    this.floatBlend = !!gl.getExtension('EXT_float_blend');
    if (!cbf && this.mode === 'splats') {
      console.warn('hvdb: EXT_color_buffer_float missing: drawing points instead of splats');
      this.mode = 'points';
    }
    this.fallbackReason = cbf ? '' : 'no EXT_color_buffer_float';
    // A software rasteriser (SwiftShader, llvmpipe) takes about a second for a 75k-point frame
    // at 960x540 on two cores: the page then draws at reduced resolution while the view moves or
    // plays, and skips progressive redraws (each would hold up the batches behind it).
    const dbg = gl.getExtension('WEBGL_debug_renderer_info');
    this.rendererName = String(gl.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    this.software = /swiftshader|llvmpipe|softpipe|software/i.test(this.rendererName);
    // Splats as point sprites (one vertex each) or as instanced quads (four vertices each, the
    // quad fitted to the ellipse). Software rasterisers draw instances one by one, 15x slower
    // than plain vertices (SwiftShader: 450 vs 30 ms for 75k points), so they get sprites;
    // GPUs get quads, which have no point-size limit. `splats=sprites|quads` in the address
    // overrides the choice.
    this.maxPointSize = gl.getParameter(gl.ALIASED_POINT_SIZE_RANGE)[1];
    this.sprites = primitive === 'sprites' || (primitive !== 'quads' && this.software);
    const withDefine = (name) => kCommonVS.replace('#version 300 es', `#version 300 es\n#define ${name}`);
    this.progPoints = program(gl, withDefine('POINTS'), kPointsFS, 'points');
    if (this.mode === 'splats') {
      const vs = this.sprites ? withDefine('SPRITES') : kCommonVS;
      this.progDepth = program(gl, vs, kDepthFS, 'splat depth');
      this.progAccum = program(gl, vs, kAccumFS, 'splat accumulate');
      this.progResolve = program(gl, kResolveVS, kResolveFS, 'resolve');
    }
    this.emptyVao = gl.createVertexArray();
    this.chunkSerial = 0;  // numbers chunks: the depth pass's reuse key names them
    this.divisor = this.mode === 'points' || this.sprites ? 0 : 1;
    this.background = [0, 0, 0, 1];
    this.lastStats = { points: 0, ms: 0 };
  }

  // GPU buffers for one batch of point columns (the views of connection.decodeBinary).
  createChunk(columns, count) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const buffers = [];
    const upload = (data) => {
      const b = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      buffers.push(b);
      return b;
    };
    upload(columns.position);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 12, 0);
    gl.vertexAttribDivisor(0, this.divisor);
    if (columns.color) {
      // Padded to 4 bytes a point: WebGL on Vulkan (ANGLE) converts vertex formats whose stride
      // is not a multiple of 4 on the CPU, which made software GL draws several times slower.
      const rgba = new Uint8Array(count * 4);
      const rgb = columns.color;
      for (let i = 0; i < count; ++i) {
        rgba[4 * i] = rgb[3 * i];
        rgba[4 * i + 1] = rgb[3 * i + 1];
        rgba[4 * i + 2] = rgb[3 * i + 2];
      }
      upload(rgba);
      gl.enableVertexAttribArray(1);
      gl.vertexAttribPointer(1, 3, gl.UNSIGNED_BYTE, true, 4, 0);
      gl.vertexAttribDivisor(1, this.divisor);
    } else {
      gl.disableVertexAttribArray(1);
      gl.vertexAttrib3f(1, 0.8, 0.8, 0.8);
    }
    const hasCov = !!columns.covariance;
    if (hasCov) {
      upload(columns.covariance);
      for (const [loc, off] of [[2, 0], [3, 12]]) {
        gl.enableVertexAttribArray(loc);
        gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 24, off);
        gl.vertexAttribDivisor(loc, this.divisor);
      }
    } else {
      gl.disableVertexAttribArray(2);
      gl.disableVertexAttribArray(3);
    }
    let labelBuffer = null;
    if (columns.label) {
      labelBuffer = upload(columns.label);
      gl.enableVertexAttribArray(4);
      gl.vertexAttribIPointer(4, 1, gl.UNSIGNED_INT, 4, 0);
      gl.vertexAttribDivisor(4, this.divisor);
    } else {
      gl.disableVertexAttribArray(4);
    }
    if (columns.flags) {
      upload(Uint32Array.from(columns.flags));  // 4-byte stride, as the colours
      gl.enableVertexAttribArray(5);
      gl.vertexAttribIPointer(5, 1, gl.UNSIGNED_INT, 4, 0);
      gl.vertexAttribDivisor(5, this.divisor);
    } else {
      gl.disableVertexAttribArray(5);
    }
    gl.bindVertexArray(null);
    // Constant values of disabled integer attributes are per context, not per VAO: keep them
    // with the chunk and set them before drawing it.
    return { vao, buffers, count, labelBuffer, serial: ++this.chunkSerial, constLabel: columns.label ? null : 0, constFlags: columns.flags ? null : (hasCov ? 2 : 0) };
  }

  // New labels for a chunk's points (a selection's label-only refresh): one buffer update;
  // positions, colours and covariances stay where they are.
  updateLabels(chunk, labels) {
    if (!chunk.labelBuffer) throw new Error('updateLabels: the chunk was drawn without labels');
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, chunk.labelBuffer);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, labels);
  }

  // Blocks until the GPU has finished what was drawn (a one-pixel read of the canvas: gl.finish
  // does not wait in every browser), so that timings include the picture being there.
  waitForGpu() {
    const gl = this.gl;
    const px = new Uint8Array(4);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
  }

  deleteChunk(chunk) {
    const gl = this.gl;
    for (const b of chunk.buffers) gl.deleteBuffer(b);
    gl.deleteVertexArray(chunk.vao);
    chunk.buffers = [];
  }

  // Render targets per size: the canvas's, and the reduced one used while moving (kept both,
  // so that switching does not reallocate).
  ensureTargets(w, h) {
    this.targetCache = this.targetCache || new Map();
    const key = `${w}x${h}`;
    const hit = this.targetCache.get(key);
    if (hit) return hit;
    const gl = this.gl;
    if (this.targetCache.size >= 2) {
      const [oldKey, old] = this.targetCache.entries().next().value;
      for (const t of old.textures) gl.deleteTexture(t);
      gl.deleteFramebuffer(old.depthFbo);
      gl.deleteFramebuffer(old.accumFbo);
      this.targetCache.delete(oldKey);
    }
    const tex = (internal, format, type) => {
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, internal, w, h);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      return t;
    };
    // 32-bit float blending needs EXT_float_blend; half floats blend with EXT_color_buffer_float.
    const accumFormat = this.floatBlend ? gl.RGBA32F : gl.RGBA16F;
    const coverFormat = this.floatBlend ? gl.R32F : gl.R16F;
    const depth = tex(gl.DEPTH_COMPONENT32F);
    const accum = tex(accumFormat);
    const cover = tex(coverFormat);
    const depthFbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, depthFbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, depth, 0);
    gl.drawBuffers([gl.NONE]);
    gl.readBuffer(gl.NONE);
    let status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
    if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`WebGL: depth target incomplete (0x${status.toString(16)})`);
    const accumFbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, accumFbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, accum, 0);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT1, gl.TEXTURE_2D, cover, 0);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0, gl.COLOR_ATTACHMENT1]);
    status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
    if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`WebGL: float accumulation target incomplete (0x${status.toString(16)})`);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    const targets = { w, h, depth, accum, cover, depthFbo, accumFbo, textures: [depth, accum, cover] };
    this.targetCache.set(key, targets);
    return targets;
  }

  setCommonUniforms(prog, cam, layerScale, opts, w, h) {
    const gl = this.gl;
    const u = prog.u;
    const { rot, trans } = viewTransform(cam);
    gl.uniform3f(u.uR0, rot[0], rot[1], rot[2]);
    gl.uniform3f(u.uR1, rot[3], rot[4], rot[5]);
    gl.uniform3f(u.uR2, rot[6], rot[7], rot[8]);
    gl.uniform3f(u.uT, trans[0], trans[1], trans[2]);
    gl.uniform4f(u.uK, cam.fx, cam.fy, cam.cx, cam.cy);
    gl.uniform2f(u.uSize, w, h);
    gl.uniform1f(u.uScale2, layerScale * layerScale);
    gl.uniform1f(u.uFilter, RENDER_DEFAULTS.filterVariance);
    gl.uniform1f(u.uCutoff2, RENDER_DEFAULTS.cutoffRadius ** 2);
    gl.uniform1f(u.uDefaultVar, RENDER_DEFAULTS.defaultSigma ** 2);
    gl.uniform1f(u.uNear, RENDER_DEFAULTS.nearPlane);
    if (u.uMaxPointSize) gl.uniform1f(u.uMaxPointSize, this.maxPointSize);
    gl.uniform1ui(u.uSelMask, opts.selMask >>> 0);
    gl.uniform1i(u.uOverlay, opts.overlay ? 1 : 0);
    // opts.preview: {m: row-major 3x3, t: 3} moving the selected points (a transform's preview).
    const pv = opts.preview;
    gl.uniform1i(u.uPreview, pv ? 1 : 0);
    if (pv) {
      const m = pv.m;
      gl.uniformMatrix3fv(u.uPM, false, [m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8]]);
      gl.uniform3f(u.uPT, pv.t[0], pv.t[1], pv.t[2]);
    }
    if (u.uZFar) gl.uniform1f(u.uZFar, opts.zFar);
    if (u.uDz) gl.uniform1f(u.uDz, RENDER_DEFAULTS.depthThreshold);
  }

  drawLayers(prog, layers, cam, opts, w, h, primitive) {
    const gl = this.gl;
    let n = 0;
    for (const layer of layers) {
      this.setCommonUniforms(prog, cam, layer.scale, opts, w, h);
      for (const c of layer.chunks) {
        if (!c.count) continue;
        if (c.constLabel !== null) gl.vertexAttribI4ui(4, c.constLabel, 0, 0, 0);
        if (c.constFlags !== null) gl.vertexAttribI4ui(5, c.constFlags, 0, 0, 0);
        gl.bindVertexArray(c.vao);
        if (primitive === gl.POINTS) gl.drawArrays(gl.POINTS, 0, c.count);
        else gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, c.count);
        n += c.count;
      }
    }
    gl.bindVertexArray(null);
    return n;
  }

  // Draws `layers` ([{chunks, scale}]) from `cam` (camera.lookAtCamera, sized like the
  // drawing buffer). opts: {selMask, overlay, zFar, resolution}: splats are drawn into targets
  // of `resolution` (0, 1] times the canvas size with the camera scaled alike (as
  // render::Camera::Resized), then resolved to the canvas. Returns the number of points submitted.
  draw(layers, cam, opts) {
    const gl = this.gl;
    const t0 = performance.now();
    const cw = gl.drawingBufferWidth, ch = gl.drawingBufferHeight;
    const res = this.mode === 'points' ? 1 : Math.min(1, Math.max(0.1, opts.resolution || 1));
    const w = Math.max(1, Math.round(cw * res)), h = Math.max(1, Math.round(ch * res));
    if (w !== cw || h !== ch) {
      const sx = w / cw, sy = h / ch;
      cam = { ...cam, fx: cam.fx * sx, fy: cam.fy * sy, cx: (cam.cx + 0.5) * sx - 0.5, cy: (cam.cy + 0.5) * sy - 0.5 };
    }
    const bg = this.background;
    let n = 0;
    if (this.mode === 'points') {
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, w, h);
      gl.clearColor(...bg.slice(0, 3).map(linearToSrgb), bg[3]);
      gl.clearDepth(1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      gl.depthMask(true);
      gl.disable(gl.BLEND);
      gl.useProgram(this.progPoints.p);
      n = this.drawLayers(this.progPoints, layers, cam, opts, w, h, gl.POINTS);
      gl.disable(gl.DEPTH_TEST);
    } else {
      const t = this.ensureTargets(w, h);
      gl.viewport(0, 0, w, h);
      const splat = this.sprites ? gl.POINTS : gl.TRIANGLE_STRIP;
      // Pass 1: nearest depth. It depends on the splats' geometry and the camera, not on labels
      // or colours: when neither changed since this target's last draw (a selection's
      // label-only refresh, an overlay toggle) its depth texture is still right and the pass
      // (about half of a draw on a software rasteriser) is skipped. A transform's preview moves
      // selected points, so it always redraws.
      const depthKey = opts.preview ? null : JSON.stringify([cam, w, h, opts.zFar, this.sprites,
        layers.map((l) => [l.scale, l.chunks.map((c) => c.serial)])]);
      if (depthKey !== null && depthKey === t.depthKey) {
        for (const l of layers) for (const c of l.chunks) n += c.count;
      } else {
        gl.bindFramebuffer(gl.FRAMEBUFFER, t.depthFbo);
        gl.disable(gl.BLEND);
        gl.enable(gl.DEPTH_TEST);
        gl.depthFunc(gl.LESS);
        gl.depthMask(true);
        gl.clearDepth(1);
        gl.clear(gl.DEPTH_BUFFER_BIT);
        gl.useProgram(this.progDepth.p);
        n = this.drawLayers(this.progDepth, layers, cam, opts, w, h, splat);
        t.depthKey = depthKey;
      }
      // Pass 2: accumulate; the depth test is done in the shader against pass 1's texture
      // because the coverage must also count the occluded fragments.
      gl.bindFramebuffer(gl.FRAMEBUFFER, t.accumFbo);
      gl.disable(gl.DEPTH_TEST);
      gl.depthMask(false);
      gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 0]);
      gl.clearBufferfv(gl.COLOR, 1, [0, 0, 0, 0]);
      gl.enable(gl.BLEND);
      gl.blendEquation(gl.FUNC_ADD);
      gl.blendFunc(gl.ONE, gl.ONE);
      gl.useProgram(this.progAccum.p);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, t.depth);
      gl.uniform1i(this.progAccum.u.uDepthTex, 0);
      this.drawLayers(this.progAccum, layers, cam, opts, w, h, splat);
      gl.disable(gl.BLEND);
      // Pass 3: resolve into the canvas.
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, cw, ch);
      gl.useProgram(this.progResolve.p);
      gl.uniform2f(this.progResolve.u.uResolve, w / cw, h / ch);
      gl.uniform2i(this.progResolve.u.uTargetMax, w - 1, h - 1);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, t.accum);
      gl.activeTexture(gl.TEXTURE1);
      gl.bindTexture(gl.TEXTURE_2D, t.cover);
      gl.uniform1i(this.progResolve.u.uAccum, 0);
      gl.uniform1i(this.progResolve.u.uCover, 1);
      gl.uniform4f(this.progResolve.u.uBg, bg[0], bg[1], bg[2], bg[3]);
      gl.bindVertexArray(this.emptyVao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
      gl.activeTexture(gl.TEXTURE0);
    }
    const err = gl.getError();
    if (err !== gl.NO_ERROR && err !== this.lastGlError) {
      this.lastGlError = err;
      throw new Error(`WebGL error 0x${err.toString(16)} while drawing`);
    }
    this.lastStats = { points: n, ms: performance.now() - t0, resolution: w / cw };
    return n;
  }
}
