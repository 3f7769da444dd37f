// A module worker sorting a frame's splats back to front for gaussian_renderer.js, off the
// main thread so that the camera stays interactive while a new order is computed (the page
// keeps drawing with the last one meanwhile).
//
// The order is render/gaussian_raster.cc's, reversed: the view depth z (float, culled at
// z <= 0.2 as the reference does) radix-sorted on its 32 bits (positive floats order as their
// bits; stable, so ties keep index order front to back), then read back to front. A full-
// precision sort rather than the 16-bit depth buckets of common WebGL viewers: splats closer
// than a bucket would otherwise blend in another order than the reference's.
//
//   in:  {type: 'frame', id, positions: Float32Array (3n)} | {type: 'drop', id}
//        | {type: 'sort', id, seq, r: [3] (the camera's third rotation row), t (its z), near}
//   out: {type: 'sorted', id, seq, order: Uint32Array (indices, back to front)} or {..., missing: true}

const frames = new Map();  // id -> positions
let scratch = null;        // reused buffers: depth bits and indices, twice

function buffers(n) {
  if (!scratch || scratch.n < n) {
    const m = Math.max(n, scratch ? scratch.n * 1.25 : 0) | 0;
    scratch = { n: m, depth: new Float32Array(m), keyA: new Uint32Array(m), keyB: new Uint32Array(m), idxA: new Uint32Array(m), idxB: new Uint32Array(m) };
  }
  return scratch;
}

function sortBackToFront(p, r, t, near) {
  const n = (p.length / 3) | 0;
  const b = buffers(n);
  const depth = b.depth;
  const bits = new Uint32Array(depth.buffer);
  let keys = b.keyA, idx = b.idxA, keys2 = b.keyB, idx2 = b.idxB;
  let m = 0;
  const r0 = Math.fround(r[0]), r1 = Math.fround(r[1]), r2 = Math.fround(r[2]), tz = Math.fround(t);
  for (let i = 0; i < n; ++i) {
    depth[0] = r0 * p[3 * i] + r1 * p[3 * i + 1] + r2 * p[3 * i + 2] + tz;  // rounded to float
    if (!(depth[0] > near)) continue;
    keys[m] = bits[0];
    idx[m] = i;
    ++m;
  }
  // LSD radix sort, 11 bits a pass; a pass where every key has the same digit is skipped.
  const kBits = 11, kBuckets = 1 << kBits, mask = kBuckets - 1;
  const count = new Uint32Array(kBuckets);
  for (let shift = 0; shift < 32; shift += kBits) {
    count.fill(0);
    for (let i = 0; i < m; ++i) ++count[(keys[i] >>> shift) & mask];
    let one = false;
    let sum = 0;
    for (let d = 0; d < kBuckets; ++d) {
      const c = count[d];
      one = one || c === m;
      count[d] = sum;
      sum += c;
    }
    if (one) continue;
    for (let i = 0; i < m; ++i) {
      const at = count[(keys[i] >>> shift) & mask]++;
      keys2[at] = keys[i];
      idx2[at] = idx[i];
    }
    [keys, keys2] = [keys2, keys];
    [idx, idx2] = [idx2, idx];
  }
  const order = new Uint32Array(m);
  for (let i = 0; i < m; ++i) order[i] = idx[m - 1 - i];
  return order;
}

self.onmessage = (ev) => {
  const msg = ev.data;
  if (msg.type === 'frame') {
    frames.set(msg.id, msg.positions);
  } else if (msg.type === 'drop') {
    frames.delete(msg.id);
  } else if (msg.type === 'sort') {
    const p = frames.get(msg.id);
    if (!p) {
      self.postMessage({ type: 'sorted', id: msg.id, seq: msg.seq, missing: true });
      return;
    }
    const t0 = performance.now();
    const order = sortBackToFront(p, msg.r, msg.t, msg.near);
    self.postMessage({ type: 'sorted', id: msg.id, seq: msg.seq, order, ms: performance.now() - t0 }, [order.buffer]);
  }
};
