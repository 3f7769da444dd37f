// Shadows and video export of the page's server renders (docs/PROTOCOL.md, "Rendering").
//
// "Shadows": the server's render (render/shadow.h, the code `hvdb render --shadow-light` runs)
// casts the shadows of the selection (label bit `app.bit`) from a light above the view, onto
// everything else. The page's WebGL view does not draw them itself: the server's shadow map
// is the same for the CLI, Python and the page, and a second WebGL pass from the light would
// cost the software-WebGL fallback the frame rate it already halves. Turning it on renders a
// shadowed still; while it is on, "Render still" and "Render video" are shadowed too.
// "Render video": every frame from the current view as one MP4 (H.264) made by the server
// (render/video_encoder.h), a progress bar per frame, then the file is downloaded. With a
// length in seconds the frames (the timeline's in..out when set) repeat until it is filled,
// and "orbit" turns the camera about the view's target (around its up) over the video: a
// camera path (thesis fig. 9.7).
import { allTimeWindow } from './connection.js';

// A directional light from above the view (the camera's up), tilted a little towards the eye
// so that shadows fall visibly behind and below what casts them.
export function shadowLight(cam) {
  const d = [0, 1, 2].map((k) => cam.eye[k] - cam.target[k]);
  const n = Math.hypot(d[0], d[1], d[2]) || 1;
  return [0, 1, 2].map((k) => cam.up[k] + 0.3 * d[k] / n);
}

export class RenderExport {
  constructor(app) {
    this.app = app;
    this.shadows = false;
    this.requestId = 0;
    const after = document.getElementById('render-sequence');
    const label = document.createElement('label');
    label.title = 'Server renders cast the selection\'s shadows from a light above the view';
    this.toggle = document.createElement('input');
    this.toggle.type = 'checkbox';
    this.toggle.id = 'render-shadows';
    label.append(this.toggle, ' Shadows');
    this.button = document.createElement('button');
    this.button.id = 'render-video';
    this.button.title = 'Server render of every frame from this view into an MP4 video';
    this.button.textContent = 'Render video';
    const field = (id, title, text, placeholder, value) => {
      const l = document.createElement('label');
      l.title = title;
      const input = document.createElement('input');
      Object.assign(input, { id, type: 'number', step: 'any', placeholder, value });
      input.style.width = '4em';
      l.append(`${text} `, input);
      return [l, input];
    };
    const [secLabel, seconds] = field('render-video-seconds', 'Video length in seconds (the frames repeat); empty: each frame once', 'for', 'all', '');
    const [orbitLabel, orbit] = field('render-video-orbit', 'Degrees the camera turns about the view\'s target over the video', 'orbit', '0', '0');
    this.secondsInput = seconds;
    this.orbitInput = orbit;
    this.progress = document.createElement('progress');
    this.progress.id = 'render-video-progress';
    this.progress.hidden = true;
    after.after(label, this.button, secLabel, orbitLabel, this.progress);
    this.toggle.addEventListener('change', () => {
      this.shadows = this.toggle.checked;
      if (this.shadows) this.app.renderStill().catch((e) => this.app.showError(e, 'shadows'));
    });
    this.button.addEventListener('click', () => {
      this.renderVideo().catch((e) => this.app.showError(e, 'render video'));
    });
  }

  // The Render fields that add shadows (none while the toggle is off).
  shadowFields() {
    if (!this.shadows) return {};
    return {
      shadow_light: shadowLight(this.app.cam),
      shadow_directional: true,
      shadow_casters: this.app.bit,
      shadow_strength: 0.6,
    };
  }

  // The frames the video shows, in order: the timeline's in..out points, else every frame.
  videoFrames() {
    const a = this.app, n = a.info ? a.info.frame_count : 0;
    const io = a.sliceTool?.inOut;
    const lo = io ? a.frameAt(io[0]) : 0, hi = io ? a.frameAt(io[1]) : n - 1;
    return Array.from({ length: Math.max(0, hi - lo + 1) }, (_, i) => lo + i);
  }

  // The frames from the current view (or a camera path: `seconds` long, the frames repeating,
  // the camera turning `orbit` degrees about the target), encoded by the server; resolves
  // with the file's size. Without options the panel's fields are used.
  async renderVideo({ seconds = this.secondsInput.value, orbit = this.orbitInput.value } = {}) {
    const a = this.app;
    const shown = this.videoFrames();
    if (!shown.length) throw new Error('render video: the dataset has no frames');
    const fps = a.info.fps || 30;
    const secs = String(seconds).trim() === '' ? null : Number(seconds), deg = Number(orbit || 0);
    if (secs !== null && !(secs > 0 && secs <= 600)) throw new Error('render video: the length is seconds in (0, 600]; empty: each frame once');
    if (!Number.isFinite(deg)) throw new Error('render video: orbit is degrees (a number)');
    const n = secs === null ? shown.length : Math.max(1, Math.round(secs * fps));
    const view = a.renderView();
    // YUV 4:2:0 needs even sides.
    view.look_at.width -= view.look_at.width % 2;
    view.look_at.height -= view.look_at.height % 2;
    const path = Array.from({ length: n }, (_, i) => orbitView(view, (deg * i) / n));
    const req = {
      render: {
        dataset: a.dataset, lod: a.lod, renderer: 'RENDERER_CPU', format: 'IMAGE_MP4',
        video_fps: fps, path, frames: path.map((_, i) => shown[i % shown.length]),
        ...this.shadowFields(), ...a.gaussian.renderFields(),
      },
    };
    if (a.box) req.render.region = allTimeWindow(a.box);
    this.button.disabled = true;
    this.progress.hidden = false;
    this.progress.max = n;
    this.progress.value = 0;
    a.setStatus('edit', `encoding ${n} frames…`);
    try {
      const reply = await a.conn.request(req, {
        onId: (id) => { this.requestId = id; },
        onPart: (part) => {
          const i = Number(part.response.render.index || 0);
          this.progress.value = i + 1;
          a.setStatus('edit', `video: frame ${i + 1} / ${n}`);
        },
      });
      const bytes = reply.sections.video;
      if (!bytes) throw new Error('render video: the last reply has no video section');
      const url = URL.createObjectURL(new Blob([bytes], { type: 'video/mp4' }));
      const link = document.createElement('a');
      link.href = url;
      link.download = `${a.dataset}.mp4`;
      document.body.append(link);
      link.click();
      link.remove();
      setTimeout(() => URL.revokeObjectURL(url), 60000);
      a.setStatus('edit', `video: ${n} frames, ${(bytes.length / 1e6).toFixed(1)} MB (${reply.render.video_codec})`);
      this.lastVideo = { frames: n, bytes: bytes.length, codec: reply.render.video_codec, fps, shown: req.render.frames };
      this.lastVideoBytes = bytes;  // (a test hook: the file downloaded)
      return this.lastVideo;
    } finally {
      this.button.disabled = false;
      this.progress.hidden = true;
      this.requestId = 0;
    }
  }
}

// The look-at view turned by `deg` degrees about its target, around its up axis (Rodrigues).
export function orbitView(view, deg) {
  const v = view.look_at, r = (deg * Math.PI) / 180, c = Math.cos(r), s = Math.sin(r);
  const len = Math.hypot(...v.up) || 1, k = v.up.map((x) => x / len);
  const d = v.eye.map((x, i) => x - v.target[i]);
  const kd = k[0] * d[0] + k[1] * d[1] + k[2] * d[2];
  const kxd = [k[1] * d[2] - k[2] * d[1], k[2] * d[0] - k[0] * d[2], k[0] * d[1] - k[1] * d[0]];
  const eye = d.map((x, i) => v.target[i] + x * c + kxd[i] * s + k[i] * kd * (1 - c));
  return { look_at: { ...v, eye } };
}
