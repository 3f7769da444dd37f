// A frame's Gaussian records (docs/PROTOCOL.md, "Gaussian records"): read with ReadGaussians
// by point id, and packed with the points' own columns into the per-splat arrays that
// gaussian_renderer.js keeps in float textures.
//
// The renderer needs, per splat, the position and covariance (the point's: for a stored
// record it is R S S^T R^T of the record, computed in double by the server), the opacity logit
// and the SH coefficients. Points without a stored record (found bit 0, and every point of a
// plain dataset) get storage/gaussian_column.cc DeriveGaussian's: opacity logit(0.99),
// dc = (colour / 255 - 0.5) / C0, no higher degrees, and the point's covariance (1 mm
// isotropic for a point without one).

export const kMaxIdsPerRequest = 32768;  // ReadGaussians' limit (service/requests.h)
export const kShC0 = 0.28209479177387814;
const kDerivedLogit = Math.fround(Math.log(0.99 / 0.01));  // float, as DeriveGaussian stores it
const kDerivedVariance = 1e-6;
const kFlagHasCovariance = 2;

export const restPerChannel = (d) => (d + 1) * (d + 1) - 1;
export const recordFloats = (d) => 11 + 3 * restPerChannel(d);
// Texels (RGBA) of SH a splat: (d + 1)^2 RGB coefficients, dc first.
export const shTexels = (d) => Math.ceil((3 * (d + 1) * (d + 1)) / 4);
export const kSplatTexels = 3;  // x y z logit | xx xy xz yy | yz zz label-low label-high

function toBase64(bytes) {
  if (bytes.toBase64) return bytes.toBase64();
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

function fromBase64(text) {
  if (!text) return new Uint8Array(0);
  if (Uint8Array.fromBase64) return Uint8Array.fromBase64(text);
  const s = atob(text);
  const out = new Uint8Array(s.length);
  for (let i = 0; i < s.length; ++i) out[i] = s.charCodeAt(i);
  return out;
}

// The point indices of a frame ordered by id (ascending runs touch the fewest record blocks).
function byId(idWords, n) {
  const keys = new Float64Array(n);  // exact below 2^53
  for (let i = 0; i < n; ++i) keys[i] = idWords[2 * i + 1] * 4294967296 + idWords[2 * i];
  const order = new Uint32Array(n);
  for (let i = 0; i < n; ++i) order[i] = i;
  let sorted = true;
  for (let i = 1; i < n && sorted; ++i) sorted = keys[i - 1] <= keys[i];
  if (!sorted) order.sort((a, b) => keys[a] - keys[b]);
  return order;
}

// Reads the records of the points whose ids are `idWords` (u64 as u32 pairs, little endian):
// requests of at most 32 768 ids in ascending runs, one at a time; a run refused with
// LIMIT_EXCEEDED (its ids touch too many blocks) is asked again in halves. Resolves with
// [{indices, degree, antialiased, values, found}], `indices` the points each part answers.
// `alive()` false stops it (the frame was dropped meanwhile).
export async function readGaussians(conn, dataset, idWords, n, alive = () => true) {
  const order = byId(idWords, n);
  const parts = [];
  const ask = async (lo, hi) => {
    if (!alive()) return;
    const indices = order.subarray(lo, hi);
    const ids = new Uint32Array(2 * indices.length);
    for (let k = 0; k < indices.length; ++k) {
      ids[2 * k] = idWords[2 * indices[k]];
      ids[2 * k + 1] = idWords[2 * indices[k] + 1];
    }
    let reply;
    try {
      reply = await conn.request({ read_gaussians: { dataset, ids: toBase64(new Uint8Array(ids.buffer)) } });
    } catch (e) {
      if (e.code === 'LIMIT_EXCEEDED' && hi - lo > 1) {
        const mid = lo + Math.floor((hi - lo) / 2);
        await ask(lo, mid);
        await ask(mid, hi);
        return;
      }
      throw e;
    }
    const g = reply.gaussians;
    if (!g) throw new Error('read_gaussians: a reply without records');
    const count = Number(g.count), degree = Number(g.sh_degree);
    const bytes = fromBase64(g.values);
    if (count !== indices.length || !(degree >= 0 && degree <= 3) || bytes.length !== 4 * count * recordFloats(degree)) {
      throw new Error(`read_gaussians: ${count} records of degree ${degree} in ${bytes.length} bytes for ${indices.length} ids`);
    }
    parts.push({
      indices,
      degree,
      antialiased: !!g.antialiased,
      values: new Float32Array(bytes.buffer, bytes.byteOffset, bytes.length / 4),
      found: fromBase64(g.found),
    });
  };
  for (let lo = 0; lo < n; lo += kMaxIdsPerRequest) await ask(lo, Math.min(n, lo + kMaxIdsPerRequest));
  return parts;
}

// R S S^T R^T of a record (storage/gaussian_column.h GaussianCovariance, in double): for a
// stored record whose point came without a covariance.
function recordCovariance(v, r, out, at) {
  let [w, x, y, z] = [v[r + 4], v[r + 5], v[r + 6], v[r + 7]];
  const q = Math.hypot(w, x, y, z);
  if (q > 0) { w /= q; x /= q; y /= q; z /= q; } else { w = 1; x = y = z = 0; }
  const s = [Math.exp(v[r + 1]), Math.exp(v[r + 2]), Math.exp(v[r + 3])];
  const R = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)];
  const m = R.map((e, k) => e * s[k % 3]);
  const dot = (a, b) => m[3 * a] * m[3 * b] + m[3 * a + 1] * m[3 * b + 1] + m[3 * a + 2] * m[3 * b + 2];
  [[0, 0], [0, 1], [0, 2], [1, 1], [1, 2], [2, 2]].forEach(([a, b], k) => { out[at + k] = dot(a, b); });
}

// The per-splat arrays of a frame. cols: {positions, ids, covariance, color, flags, labels}
// (concatenated columns of n points; covariance/color/flags may be null), parts: what
// readGaussians returned (empty for a plain dataset: every record derived). texWidth: texels a
// row of the textures. Returns {n, degree, antialiased, splat, sh, shTexels, rows, stored}.
export function packSplats(cols, parts, n, texWidth) {
  let degree = 0, antialiased = false;
  for (const p of parts) {
    degree = Math.max(degree, p.degree);
    antialiased = antialiased || p.antialiased;
  }
  const kSh = shTexels(degree);
  const splatRows = Math.max(1, Math.ceil((n * kSplatTexels) / texWidth));
  const shRows = Math.max(1, Math.ceil((n * kSh) / texWidth));
  const splat = new Float32Array(splatRows * texWidth * 4);
  const sh = new Float32Array(shRows * texWidth * 4);
  const { positions, covariance, color, flags, labels } = cols;
  const shStride = 4 * kSh;
  for (let i = 0; i < n; ++i) {
    const s = 12 * i;
    splat[s] = positions[3 * i];
    splat[s + 1] = positions[3 * i + 1];
    splat[s + 2] = positions[3 * i + 2];
    splat[s + 3] = kDerivedLogit;
    if (covariance && (!flags || (flags[i] & kFlagHasCovariance))) {
      for (let k = 0; k < 6; ++k) splat[s + 4 + k] = covariance[6 * i + k];
    } else {
      splat[s + 4] = splat[s + 7] = splat[s + 9] = kDerivedVariance;
    }
    const label = labels ? labels[i] : 0;
    splat[s + 10] = label & 0xffff;
    splat[s + 11] = label >>> 16;
    const o = shStride * i;
    for (let c = 0; c < 3; ++c) {
      const v = color ? color[3 * i + c] : 204;  // 0.8 grey, as renderer.js draws a point without colour
      sh[o + c] = Math.fround((v / 255 - 0.5) / kShC0);
    }
  }
  let stored = 0;
  for (const p of parts) {
    const stride = recordFloats(p.degree), pc = restPerChannel(p.degree);
    const { values, found, indices } = p;
    for (let k = 0; k < indices.length; ++k) {
      if (!(found[k >> 3] & (1 << (k & 7)))) continue;
      ++stored;
      const i = indices[k], r = k * stride, o = shStride * i;
      splat[12 * i + 3] = values[r];  // opacity logit; scale and rotation: the point's covariance
      if (!covariance || (flags && !(flags[i] & kFlagHasCovariance))) recordCovariance(values, r, splat, 12 * i + 4);
      for (let c = 0; c < 3; ++c) {
        sh[o + c] = values[r + 8 + c];
        // The rest is channel-major in the record: coefficient j of channel c at 11 + c pc + j.
        for (let j = 0; j < pc; ++j) sh[o + 3 * (j + 1) + c] = values[r + 11 + c * pc + j];
      }
    }
  }
  return { n, degree, antialiased, splat, sh, shTexels: kSh, splatRows, shRows, stored };
}
