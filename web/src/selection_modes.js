// Selection modes for what the server writes whole: a brush stroke (intersect) and a graph
// cut (add, subtract, intersect) are written into a scratch label bit, then combined into the
// target bit by one Edit of set_label ops (applied in order, atomically), which also clears
// the scratch bits. Marquee and lasso use the server's own SelectMode.

// Scratch label bits (the selection bit must not be one of them).
export const SCRATCH_BIT = 30, SCRATCH_BIT2 = 31;

// The ops that make `target` = target (mode) scratch, leaving both scratch bits clear.
export function combineOps(target, mode, scratch = SCRATCH_BIT, spare = SCRATCH_BIT2) {
  const T = (1 << target) >>> 0, X = (1 << scratch) >>> 0, U = (1 << spare) >>> 0;
  const set = (mask, bits, on) => ({ set_label: { selection: { label_mask: mask }, bits, set: on } });
  const clearX = set(X, X, false);
  switch (mode) {
    case 'SELECT_REPLACE': return [set(T, T, false), set(X, T, true), clearX];
    case 'SELECT_ADD': return [set(X, T, true), clearX];
    case 'SELECT_SUBTRACT': return [set(X, T, false), clearX];
    // T and not X -> U; clear T on U; clear U.
    case 'SELECT_INTERSECT': return [set(T, U, true), set(X, U, false), set(U, T, false), set(U, U, false), clearX];
    default: throw new Error(`unknown selection mode ${mode}`);
  }
}

// The selection bit may not be a scratch bit.
export function checkTarget(bit) {
  if (bit === SCRATCH_BIT || bit === SCRATCH_BIT2) throw new Error(`selection bit ${bit} is a scratch bit of the selection modes (${SCRATCH_BIT}, ${SCRATCH_BIT2}): choose another bit`);
}

// A graph cut combined with the selection bit by `mode`: one undo entry of its two LSNs.
export function graphCutWithMode(editor, roi, fgBit, bgBit, mode) {
  const app = editor.app, bit = app.bit, dataset = app.dataset;
  checkTarget(bit);
  return editor.enqueue(async () => {
    const lsns = [];
    const req = { graph_cut: { dataset, roi, foreground_bit: fgBit, background_bit: bgBit, out_bit: SCRATCH_BIT } };
    const cut = await editor.commitNow('graph cut', req, (r) => r.graph_cut, false);
    if (String(cut.graph_cut.lsn) !== '0') lsns.push(String(cut.graph_cut.lsn));
    try {
      const comb = await editor.commitNow('graph cut', { edit: { dataset, ops: combineOps(bit, mode) } }, (r) => r.commit, false);
      if (String(comb.commit.lsn) !== '0') lsns.push(String(comb.commit.lsn));
    } finally {
      editor.record('graph cut', dataset, lsns);
      app.ui?.updateEditButtons();
    }
    app.lastSelect = cut.graph_cut;
    return cut;
  });
}
