// The EGL renderer's GLSL programs (egl_renderer.cc): the splat pass (vertex shader pulling the
// 64-byte Point records from a storage buffer and doing splat.cc's EWA set-up; fragment shader
// evaluating the kernel) and the full-screen resolve. Keep in step with splat.h / splat.cc and
// cpu_renderer.cc: the CPU renderer is the reference these must match.
#ifndef HVDB_RENDER_EGL_SHADERS_H_
#define HVDB_RENDER_EGL_SHADERS_H_

namespace hvdb::render::shaders {

inline constexpr const char* kSplatVertexShader = R"(#version 430 core
layout(std430, binding = 0) readonly buffer PointBuffer { uint words[]; };  // 16 per Point
// [0, 256): sRGB 8 bit -> linear; [256, 256 + u_num_weights): view weight by camera id.
layout(std430, binding = 1) readonly buffer TableBuffer { float table[]; };
uniform vec3 u_rot0, u_rot1, u_rot2, u_trans;
uniform vec4 u_intr;  // fx fy cx cy
uniform float u_k[5];
uniform int u_distorted;
uniform float u_max_r2, u_near, u_cutoff2, u_filter, u_scale2, u_default_var;
uniform vec2 u_size;
uniform int u_num_weights;
flat out vec2 v_centre;
flat out vec3 v_conic;
flat out vec3 v_colour;
flat out float v_z;
flat out vec2 v_slope;
flat out float v_w;

void Cull() {
  gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // the whole quad lies outside the clip volume
  v_centre = vec2(0.0); v_conic = vec3(0.0); v_colour = vec3(0.0); v_z = 0.0; v_slope = vec2(0.0);
  v_w = 0.0;
}

void main() {
  uint base = uint(gl_InstanceID) * 16u;
  float px = uintBitsToFloat(words[base + 2u]);
  float py = uintBitsToFloat(words[base + 3u]);
  float pz = uintBitsToFloat(words[base + 4u]);
  float xc = u_rot0.x * px + u_rot0.y * py + u_rot0.z * pz + u_trans.x;
  float yc = u_rot1.x * px + u_rot1.y * py + u_rot1.z * pz + u_trans.y;
  float zc = u_rot2.x * px + u_rot2.y * py + u_rot2.z * pz + u_trans.z;
  if (!(zc >= u_near)) { Cull(); return; }
  float inv_z = 1.0 / zc;
  float a = xc * inv_z, b = yc * inv_z;
  float ad = a, bd = b, j00 = 1.0, j01 = 0.0, j10 = 0.0, j11 = 1.0;
  if (u_distorted != 0) {
    float r2 = a * a + b * b;
    if (!(r2 <= u_max_r2)) { Cull(); return; }
    float radial = 1.0 + r2 * (u_k[0] + r2 * (u_k[1] + r2 * u_k[4]));
    float drad = u_k[0] + r2 * (2.0 * u_k[1] + 3.0 * u_k[4] * r2);
    ad = a * radial + 2.0 * u_k[2] * a * b + u_k[3] * (r2 + 2.0 * a * a);
    bd = b * radial + u_k[2] * (r2 + 2.0 * b * b) + 2.0 * u_k[3] * a * b;
    j00 = radial + 2.0 * a * a * drad + 2.0 * u_k[2] * b + 6.0 * u_k[3] * a;
    j01 = 2.0 * a * b * drad + 2.0 * u_k[2] * a + 2.0 * u_k[3] * b;
    j10 = j01;
    j11 = radial + 2.0 * b * b * drad + 6.0 * u_k[2] * b + 2.0 * u_k[3] * a;
    if (!(j00 * j11 - j01 * j10 > 0.0)) { Cull(); return; }
  }
  float u = u_intr.x * ad + u_intr.z;
  float v = u_intr.y * bd + u_intr.w;
  vec3 p0 = (u_rot0 - a * u_rot2) * inv_z;
  vec3 p1 = (u_rot1 - b * u_rot2) * inv_z;
  vec3 t0 = u_intr.x * (j00 * p0 + j01 * p1);
  vec3 t1 = u_intr.y * (j10 * p0 + j11 * p1);
  // V: xx xy xz yy yz zz (no arrays: llvmpipe keeps those in memory, not registers).
  vec3 vd = vec3(u_default_var), vo = vec3(0.0);  // diagonal (xx yy zz), off (xy xz yz)
  uint flags = (words[base + 14u] >> 24) & 0xffu;
  if ((flags & 2u) != 0u) {  // kFlagHasCovariance
    vd = vec3(uintBitsToFloat(words[base + 6u]), uintBitsToFloat(words[base + 9u]),
              uintBitsToFloat(words[base + 11u]));
    vo = vec3(uintBitsToFloat(words[base + 7u]), uintBitsToFloat(words[base + 8u]),
              uintBitsToFloat(words[base + 10u]));
  }
  vec3 vt0 = vec3(vd.x * t0.x + vo.x * t0.y + vo.y * t0.z,
                  vo.x * t0.x + vd.y * t0.y + vo.z * t0.z,
                  vo.y * t0.x + vo.z * t0.y + vd.z * t0.z);
  vec3 vt1 = vec3(vd.x * t1.x + vo.x * t1.y + vo.y * t1.z,
                  vo.x * t1.x + vd.y * t1.y + vo.z * t1.z,
                  vo.y * t1.x + vo.z * t1.y + vd.z * t1.z);
  float s00 = (t0.x * vt0.x + t0.y * vt0.y + t0.z * vt0.z) * u_scale2 + u_filter;
  float s01 = (t0.x * vt1.x + t0.y * vt1.y + t0.z * vt1.z) * u_scale2;
  float s11 = (t1.x * vt1.x + t1.y * vt1.y + t1.z * vt1.z) * u_scale2 + u_filter;
  float det = s00 * s11 - s01 * s01;
  if (!(det > 0.0) || isinf(det)) { Cull(); return; }
  float ex = sqrt(u_cutoff2 * s00), ey = sqrt(u_cutoff2 * s11);
  float x0 = max(ceil(u - ex), 0.0), x1 = min(floor(u + ex), u_size.x - 1.0);
  float y0 = max(ceil(v - ey), 0.0), y1 = min(floor(v + ey), u_size.y - 1.0);
  if (!(x0 <= x1) || !(y0 <= y1)) { Cull(); return; }
  // The quad covers exactly the pixels x0..x1, y0..y1: in window coordinates pixel i spans
  // [i, i + 1]. Image row v is framebuffer row v (no flip), so read-back is top-down.
  int vid = gl_VertexID;
  vec2 lo = vec2(x0, y0), hi = vec2(x1 + 1.0, y1 + 1.0);
  vec2 corner = vec2((vid & 1) != 0 ? hi.x : lo.x, (vid & 2) != 0 ? hi.y : lo.y);
  gl_Position = vec4(corner / u_size * 2.0 - 1.0, 0.0, 1.0);
  float inv_det = 1.0 / det;
  v_centre = vec2(u, v);
  v_conic = vec3(s11 * inv_det, -s01 * inv_det, s00 * inv_det);
  uint rgb = words[base + 14u];
  v_colour = vec3(table[rgb & 0xffu], table[(rgb >> 8) & 0xffu], table[(rgb >> 16) & 0xffu]);
  uint cam = words[base + 15u] & 0xffffu;
  v_w = int(cam) < u_num_weights ? table[256u + cam] : 1.0;
  v_z = zc;
  float s02 = (u_rot2.x * vt0.x + u_rot2.y * vt0.y + u_rot2.z * vt0.z) * u_scale2;
  float s12 = (u_rot2.x * vt1.x + u_rot2.y * vt1.y + u_rot2.z * vt1.z) * u_scale2;
  v_slope = vec2(v_conic.x * s02 + v_conic.y * s12, v_conic.y * s02 + v_conic.z * s12);
}
)";

inline constexpr const char* kSplatFragmentShader = R"(#version 430 core
flat in vec2 v_centre;
flat in vec3 v_conic;
flat in vec3 v_colour;
flat in float v_z;
flat in vec2 v_slope;
flat in float v_w;
uniform int u_pass;  // 0: visibility depth, 1: visibility blend, 2: probabilistic
uniform float u_cutoff2, u_dz;
layout(binding = 0) uniform sampler2D t_zmin;  // pass 1's result, read in pass 2
layout(location = 0) out vec4 o_acc;
layout(location = 1) out vec4 o_aux;

void main() {
  vec2 d = gl_FragCoord.xy - vec2(0.5) - v_centre;  // pixel centres at integers
  float q = v_conic.x * d.x * d.x + 2.0 * v_conic.y * d.x * d.y + v_conic.z * d.y * d.y;
  if (q > u_cutoff2) discard;
  float a = exp(-0.5 * q);
  float z = max(v_z + v_slope.x * d.x + v_slope.y * d.y, 0.0);  // FragmentDepth()
  if (u_pass == 0) {
    o_acc = vec4(z, 0.0, 0.0, 0.0);  // GL_MIN blending keeps the nearest
    o_aux = vec4(0.0);
  } else if (u_pass == 1) {
    float zmin = texelFetch(t_zmin, ivec2(gl_FragCoord.xy), 0).r;
    float wa = v_w * a;
    // The fuzzy depth test: only fragments within dz of the nearest blend their colour.
    o_acc = z - u_dz <= zmin ? vec4(v_colour * wa, wa) : vec4(0.0);
    o_aux = vec4(a, 0.0, 0.0, 0.0);  // coverage counts every fragment
  } else {
    o_acc = vec4(v_colour, min(1.0, v_w * a));
    o_aux = vec4(z, 0.0, 0.0, 0.0);
  }
}
)";

inline constexpr const char* kResolveVertexShader = R"(#version 430 core
void main() {
  // One triangle that covers the viewport.
  vec2 p = vec2((gl_VertexID & 1) != 0 ? 3.0 : -1.0, (gl_VertexID & 2) != 0 ? 3.0 : -1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}
)";

inline constexpr const char* kResolveFragmentShader = R"(#version 430 core
layout(binding = 0) uniform sampler2D t_acc;
layout(binding = 1) uniform sampler2D t_aux;
layout(binding = 2) uniform sampler2D t_depth;
uniform int u_probabilistic;
uniform vec4 u_bg;
layout(location = 0) out vec4 o_rgba;
layout(location = 1) out vec2 o_cov_depth;

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 s = texelFetch(t_acc, p, 0);
  float inf = uintBitsToFloat(0x7f800000u);
  vec3 colour = vec3(0.0);
  float cov = 0.0, depth = inf;
  if (u_probabilistic != 0) {
    if (s.a > 0.0) { colour = s.rgb / s.a; cov = s.a; }
    depth = texelFetch(t_aux, p, 0).r;
  } else {
    float a = texelFetch(t_aux, p, 0).r;
    if (a > 0.0) {
      colour = s.rgb / s.a;  // normalisation (fig. 5.2, lines 15-18)
      cov = min(1.0, a);
      depth = texelFetch(t_depth, p, 0).r;
    }
  }
  float keep = (1.0 - cov) * u_bg.a;
  o_rgba = vec4(cov * colour + keep * u_bg.rgb, cov + keep);
  o_cov_depth = vec2(cov, depth);
}
)";

}  // namespace hvdb::render::shaders

#endif  // HVDB_RENDER_EGL_SHADERS_H_
