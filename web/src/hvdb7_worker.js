// A module worker decoding hvdb7 batches (docs/CODEC.md) with the WebAssembly build of the
// server's own decoder (codec/, compiled by codec/wasm.cmake into web/wasm/). It gets a
// batch's stream bytes and answers with the columns the renderer draws (renderer.js
// createChunk: position, color, covariance, label, flags; those the stream does not carry are
// left out), as new buffers transferred to the page.
//
//   in:  {id, bytes: ArrayBuffer}
//   out: {id, count, columns: {position: Float32Array, ...}} or {id, error: string}
import createHvdb7 from '../wasm/hvdb7.js';

// Compiles the module once; a failure (the wasm missing, a refused compile) fails every
// decode with the reason, so that the page shows it instead of an empty picture.
const ready = createHvdb7();

// Offsets in the result header of codec/wasm_decoder.cc: [column, typed array, values a point].
const kColumns = [
  ['position', Float32Array, 3, 2],
  ['color', Uint8Array, 3, 3],
  ['covariance', Float32Array, 6, 4],
  ['label', Uint32Array, 1, 5],
  ['flags', Uint8Array, 1, 6],
];

function cString(heap, ptr) {
  let end = ptr;
  while (heap[end] !== 0) ++end;
  return new TextDecoder().decode(heap.subarray(ptr, end));
}

function decode(m, bytes) {
  const src = new Uint8Array(bytes);
  const input = m._hvdb7_buffer(src.length);
  m.HEAPU8.set(src, input);
  const res = m._hvdb7_decode(input, src.length);
  const heap = m.HEAPU8;  // after the call: decoding may have grown the memory
  if (!res) throw new Error(`hvdb7: ${cString(heap, m._hvdb7_error())}`);
  const head = new Uint32Array(heap.buffer, res, 8);
  const count = head[0];
  const columns = {};
  for (const [name, T, per, slot] of kColumns) {
    const off = head[slot];
    if (!off) continue;
    const begin = res + off;
    columns[name] = new T(heap.buffer.slice(begin, begin + count * per * T.BYTES_PER_ELEMENT));
  }
  return { count, columns };
}

self.onmessage = async (ev) => {
  const { id, bytes } = ev.data;
  try {
    const { count, columns } = decode(await ready, bytes);
    self.postMessage({ id, count, columns }, Object.values(columns).map((c) => c.buffer));
  } catch (e) {
    self.postMessage({ id, error: String(e && e.message || e) });
  }
};
