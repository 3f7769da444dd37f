// hvdb7 batches (Query.encoding HVDB7) decoded off the main thread: a small pool of module
// workers (hvdb7_worker.js) running the WebAssembly build of codec/. The page asks for the
// attributes it draws at a quantisation whose picture equals the COLUMNS one (web/README.md).

// What the page asks the server for (Query.codec): positions on a 2^30 grid over the batch's
// box (nanometres: the decoded floats are the stored ones, so the picture is the COLUMNS one
// pixel for pixel; 2^20 left 0.2 % of the pixels off by a little), exact colours, and only
// what renderer.js draws.
export const kHvdb7Codec = {
  position_bits: 30,
  color_bits: 8,
  covariance_bits: 12,
  attributes: 'position,color,covariance,label,flags',
};

// Points per HVDB7 batch (Query.batch_points).
export const kHvdb7BatchPoints = 4096;

export class Hvdb7Decoder {
  constructor(workers = Math.max(1, Math.min(2, (navigator.hardwareConcurrency || 2) - 1))) {
    this.workers = [];
    this.next = 0;
    this.nextId = 1;
    this.pending = new Map();  // id -> {resolve, reject}
    for (let i = 0; i < workers; ++i) {
      const w = new Worker(new URL('./hvdb7_worker.js', import.meta.url), { type: 'module' });
      w.onmessage = (ev) => this.settle(ev.data);
      // A worker that cannot start (its script or the wasm missing) fails what it was given.
      w.onerror = (ev) => {
        ev.preventDefault();
        this.failAll(new Error(`hvdb7 decoder worker failed: ${ev.message || 'could not load web/wasm/hvdb7.js (build the hvdb7_wasm target)'}`));
      };
      this.workers.push(w);
    }
  }

  // Decodes one stream (a Uint8Array; copied, the message buffer stays the caller's).
  // Resolves with {count, columns} in the format of connection.decodeBinary's columns.
  decode(bytes) {
    const id = this.nextId++;
    const copy = bytes.slice().buffer;
    const w = this.workers[this.next++ % this.workers.length];
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      w.postMessage({ id, bytes: copy }, [copy]);
    });
  }

  settle(msg) {
    const p = this.pending.get(msg.id);
    if (!p) return;
    this.pending.delete(msg.id);
    if (msg.error) p.reject(new Error(msg.error));
    else p.resolve({ count: msg.count, columns: msg.columns });
  }

  failAll(err) {
    const all = [...this.pending.values()];
    this.pending.clear();
    for (const p of all) p.reject(err);
  }
}
