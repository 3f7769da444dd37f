// "Import media…": an image, video or mesh file chosen with <input type=file>, placed with the
// dialog's fields and sent over the WebSocket as one ImportMediaRequest (docs/PROTOCOL.md); the
// server decodes it and commits one transaction, which Undo removes like any other edit.

// hvdb-server's default --max-frame-bytes: a larger WebSocket message closes the connection
// (1009), so a file that cannot fit is refused here with the reason instead.
export const kMaxMessageBytes = 16 * 1024 * 1024;

const $ = (id) => {
  const el = document.getElementById(id);
  if (!el) throw new Error(`index.html lacks #${id}`);
  return el;
};

// "1, 2, 3" -> [1, 2, 3]; exactly n finite numbers, else an error naming the field.
export function parseNumbers(text, n, field) {
  const v = String(text).split(/[\s,]+/).filter(Boolean).map(Number);
  if (v.length !== n || v.some((x) => !Number.isFinite(x))) {
    throw new Error(`import media: ${field} needs ${n} numbers`);
  }
  return v;
}

// Base64 of the bytes (proto3 JSON's encoding of a bytes field), in chunks that
// String.fromCharCode can take as arguments.
export function toBase64(bytes) {
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) {
    s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  }
  return btoa(s);
}

// The request for `file`'s bytes and the dialog's values (all strings, as the inputs hold them).
export function buildRequest(dataset, name, bytes, v) {
  const dot = name.lastIndexOf('.');
  const req = {
    dataset,
    data: toBase64(bytes),
    format: dot >= 0 ? name.slice(dot + 1).toLowerCase() : '',
    at: parseNumbers(v.at, 3, 'at'),
    rotate: parseNumbers(v.rotate, 3, 'rotate'),
    scale: parseNumbers(v.scale, 1, 'scale')[0],
    width: parseNumbers(v.width, 1, 'width')[0],
  };
  if (v.kind) req.kind = v.kind;
  if (String(v.frames).trim()) {
    const [a, b] = parseNumbers(v.frames, 2, 'frames');
    req.first_frame = a;
    req.last_frame = b;
  }
  if (String(v.labelBit).trim()) req.label_bit = parseNumbers(v.labelBit, 1, 'label bit')[0];
  // Base64 grows the bytes by 4/3; the rest of the message is small.
  const size = req.data.length + 1024;
  if (size > kMaxMessageBytes) {
    throw new Error(`import media: ${name} (${(bytes.length / 1048576).toFixed(1)} MiB) makes a ` +
      `message of ${(size / 1048576).toFixed(1)} MiB, over the server's limit of ` +
      `${kMaxMessageBytes / 1048576} MiB (--max-frame-bytes); import it with ` +
      '`hvdb --data DIR import-media` on the server, or make it smaller');
  }
  return req;
}

export class MediaImport {
  constructor(app) {
    this.app = app;
    this.dialog = $('media-dialog');
    $('import-media').addEventListener('click', () => this.open());
    $('media-cancel').addEventListener('click', () => this.dialog.close());
    $('media-go').addEventListener('click', (e) => {
      e.preventDefault();
      this.submit().catch((err) => this.app.showError(err));
    });
  }

  open() {
    // The plane or mesh lands where the view looks, unless the user says otherwise.
    const t = this.app.cam?.target;
    if (t) $('media-at').value = t.map((x) => Number(x).toFixed(3)).join(', ');
    this.dialog.showModal();
  }

  async submit() {
    const file = $('media-file').files[0];
    if (!file) throw new Error('import media: choose a file first');
    const bytes = new Uint8Array(await file.arrayBuffer());
    const req = buildRequest(this.app.dataset, file.name, bytes, {
      at: $('media-at').value,
      rotate: $('media-rotate').value,
      scale: $('media-scale').value,
      width: $('media-width').value,
      kind: $('media-kind').value,
      frames: $('media-frames').value,
      labelBit: $('media-label-bit').value,
    });
    this.dialog.close();
    return this.app.editor.commit(`import ${file.name}`, { import_media: req }, (r) => r.commit);
  }
}
