// Shadows and video export of the page's server renders (docs/PROTOCOL.md, "Rendering").
//
// "Shadows": the server's render (render/shadow.h, the code `hvdb render --shadow-light` runs)
// casts the shadows of the selection (label bit `app.bit`) from a light above the view, onto
// everything else. The page's WebGL view does not draw them itself: the server's shadow map
// is the same for the CLI, Python and the page, and a second WebGL pass from the light would
// cost the software-WebGL fallback the frame rate it already halves. Turning it on renders a
// shadowed still; while it is on, "Render still" and "Render video" are shadowed too.
// "Render video": every frame from the current view as one MP4 (H.264) made by the server
// (render/video_encoder.h), a progress bar per frame, then the file is downloaded.
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
    this.progress = document.createElement('progress');
    this.progress.id = 'render-video-progress';
    this.progress.hidden = true;
    after.after(label, this.button, this.progress);
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

  // Every frame from the current view, encoded by the server; resolves with the file's size.
  async renderVideo() {
    const a = this.app;
    const n = a.info ? a.info.frame_count : 0;
    if (!(n > 0)) throw new Error('render video: the dataset has no frames');
    const view = a.renderView();
    // YUV 4:2:0 needs even sides.
    view.look_at.width -= view.look_at.width % 2;
    view.look_at.height -= view.look_at.height % 2;
    const req = {
      render: {
        dataset: a.dataset, lod: a.lod, renderer: 'RENDERER_CPU', format: 'IMAGE_MP4',
        video_fps: a.info.fps || 30,
        path: Array.from({ length: n }, () => view), frames: Array.from({ length: n }, (_, i) => i),
        ...this.shadowFields(),
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
      this.lastVideo = { frames: n, bytes: bytes.length, codec: reply.render.video_codec };
      return this.lastVideo;
    } finally {
      this.button.disabled = false;
      this.progress.hidden = true;
      this.requestId = 0;
    }
  }
}
