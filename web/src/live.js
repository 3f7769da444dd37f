// Live mode: a watch of the dataset (docs/PROTOCOL.md, "Watching") over the page's WebSocket.
// Each commit or bulk load that names frames marks them stale in the cache; while following,
// the newest frame is fetched and drawn as soon as it arrives (the camera is never touched).
// Pausing keeps the frame on screen while events keep arriving; the timeline scrubs over the
// frames that arrived (the time-shift buffer: they are in the database, the recent ones in the
// frame cache too); "return to live" jumps to the newest. A LAGGED watch resumes from its LSN;
// DROPPED and a closed connection are shown in the status bar.

const kKeep = 1000;  // entries kept in `frames` and `onScreen` (oldest dropped first)

const median = (v) => {
  if (!v.length) return null;
  const s = [...v].sort((x, y) => x - y);
  return s[Math.floor((s.length - 1) / 2)];
};

// The larger of two LSNs (decimal strings, uint64: compared as BigInt); null counts as 0.
const maxLsn = (x, y) => {
  const a = BigInt(x ?? 0), b = BigInt(y ?? 0);
  return String(a > b ? a : b);
};

const push = (list, item) => {
  list.push(item);
  if (list.length > kKeep) list.splice(0, list.length - kKeep);
};

export class Live {
  constructor(app) {
    this.app = app;
    this.on = false;          // subscribed (or subscribing)
    this.following = false;   // shows the newest frame as it arrives (false: paused)
    this.state = 'off';       // off | starting | replaying | live | dropped | closed | error
    this.dataset = '';
    this.gen = 0;             // the current subscription (late parts of older ones are ignored)
    this.requestId = 0;
    this.lastLsn = null;      // string: the last LSN seen
    this.head = -1;           // the newest frame
    this.events = 0;
    this.resumes = 0;         // LAGGED watches resumed
    this.frames = [];         // arrivals: {frame, lsn, kind, points, eventMs, eventWall}
    this.onScreen = [];       // first draws: {frame, lsn, kind, eventMs, drawnMs, eventWall, drawnWall, latencyMs, points, queryMs, firstDrawnWall, firstLatencyMs}
    this.pending = null;      // the newest arrival not yet shown (while following)
    this.refresh = null;      // the paused frame, changed: shown anew
    this.pumping = false;
    this.again = false;
    this.liveWaiters = [];
    this.log = [];            // every event: {kind, lsn, frames, eventMs, gen}
  }

  // Subscribes to the dataset shown and follows its newest frame (shown at once).
  async start() {
    const a = this.app;
    if (!a.info) throw new Error('live: no dataset open');
    if (this.on) return this.goLive();
    this.on = true;
    this.following = true;
    this.dataset = a.dataset;
    this.lastLsn = null;  // LSNs are per dataset
    this.head = Math.max(0, a.info.frame_count - 1);
    this.subscribe(null, true);
    this.updateUi();
    a.player.stop();
    if (a.frame !== this.head || a.viewMode !== 'frames') await a.gotoFrame(this.head);
    this.updateUi();
    return true;
  }

  // Ends the subscription (the page stays on the frame it shows).
  stop() {
    if (!this.on) return;
    this.on = false;
    this.following = false;
    this.pending = this.refresh = null;
    ++this.gen;
    if (this.requestId && this.app.conn.isOpen) this.app.conn.cancel(this.requestId);
    this.requestId = 0;
    this.state = 'off';
    this.updateUi();
  }

  toggle() { return this.on ? this.stop() : this.start(); }

  // Stays on the frame shown; events keep arriving (the timeline reaches them).
  pause() {
    if (!this.on || !this.following) return;
    this.following = false;
    this.pending = null;
    this.updateUi();
  }

  // Shows the newest frame and follows again; resolves once it is drawn.
  async goLive() {
    if (!this.on) return this.start();
    const a = this.app;
    this.following = true;
    this.pending = null;
    a.player.stop();
    this.updateUi();
    await a.gotoFrame(this.head);
    this.updateUi();
    this.schedule();  // anything newer that came meanwhile
    return true;
  }

  // The user moved in time (timeline, keys, playback): live pauses rather than pull them back.
  userSeek() { if (this.on && this.following) this.pause(); }

  // Resolves once the watch is live (its LIVE event came), at once if it is.
  whenLive() {
    if (this.state === 'live') return Promise.resolve(this.lastLsn);
    if (!this.on) return Promise.reject(new Error('live mode is off'));
    return new Promise((resolve, reject) => this.liveWaiters.push({ resolve, reject }));
  }

  settleWaiters(err) {
    const w = this.liveWaiters;
    this.liveWaiters = [];
    for (const x of w) if (err) x.reject(err); else x.resolve(this.lastLsn);
  }

  subscribe(fromLsn, first = false) {
    const gen = ++this.gen;
    const a = this.app;
    const watch = { dataset: this.dataset };
    if (fromLsn !== null) watch.from_lsn = String(fromLsn);
    this.state = fromLsn === null ? 'starting' : 'replaying';
    this.first = first;
    a.conn.request({ watch }, {
      onId: (id) => { if (gen === this.gen) this.requestId = id; },
      onPart: (part) => { if (gen === this.gen) this.onEvent(part.response.event); },
    }).then(() => {}, (err) => {
      if (gen !== this.gen) return;  // stopped or resumed: nothing to say
      this.on = false;
      this.following = false;
      this.requestId = 0;
      this.state = err.code === 'CLOSED' ? 'closed' : 'error';
      this.settleWaiters(err);
      this.updateUi(err.code === 'CLOSED' ? 'live: connection closed (reload the page)' : `live: ${err.message}`);
      if (err.code !== 'CLOSED') a.showError(err, 'live');
    });
  }

  onEvent(ev, injected = false) {
    const eventMs = performance.now();
    const eventWall = Date.now();
    const a = this.app;
    this.events++;
    const kind = ev.kind || 'WATCH_COMMIT';
    push(this.log, { kind, lsn: ev.lsn, frames: ev.frames || [], eventMs, gen: this.gen });
    if (kind === 'WATCH_LIVE') {
      this.state = 'live';
      this.lastLsn = maxLsn(ev.lsn, this.lastLsn);
      this.liveLsn = String(ev.lsn);
      if (this.first) this.catchUp();
      this.first = false;
      this.settleWaiters(null);
      this.updateUi();
      return;
    }
    if (kind === 'WATCH_DROPPED') {
      ++this.gen;
      this.on = false;
      this.following = false;
      this.state = 'dropped';
      this.requestId = 0;
      this.settleWaiters(new Error('the dataset was dropped'));
      this.updateUi(`live: dataset "${this.dataset}" was dropped`);
      return;
    }
    if (kind === 'WATCH_LAGGED') {
      // The server ended the watch (its buffer for this connection was full: the page's own
      // frame queries count too): resume after the last change the page has. A LAGGED before
      // any event names LSN 0, which would replay the whole log: start afresh (live) then.
      const from = maxLsn(ev.lsn, this.lastLsn);
      const old = this.requestId;
      this.resumes++;
      if (from === '0') this.subscribe(null, true);
      else this.subscribe(from);
      if (injected && old) a.conn.cancel(old);  // a real LAGGED has ended it already
      this.updateUi(`live: fell behind, resuming from lsn ${from}`);
      return;
    }
    // At most once: a change the page has seen (a resumed watch's replay) is not news.
    if (this.lastLsn !== null && ev.lsn !== undefined && BigInt(ev.lsn) <= BigInt(this.lastLsn)) return;
    if (ev.lsn !== undefined) this.lastLsn = String(ev.lsn);
    const frames = (ev.frames || []).map(Number).filter((f) => Number.isInteger(f) && f >= 0);
    if (!frames.length) return;
    a.store.invalidateFrames(frames, eventMs);
    const newest = Math.max(...frames);
    if (newest >= a.info.frame_count) {
      a.info.frame_count = newest + 1;
      a.ui.setFrameRange(a.info.frame_count);
      a.ui.setFrame(a.frame, a.info.frame_count, a.info.fps, a.viewMode === 'slice');
    }
    const arrival = { frame: newest, lsn: this.lastLsn, kind, points: Number(ev.points || 0), eventMs, eventWall };
    push(this.frames, arrival);
    if (newest >= this.head) {
      this.head = newest;
      if (this.following) this.pending = arrival;
    }
    if (!this.pending && a.viewMode === 'frames' && frames.includes(a.frame)) this.refresh = { ...arrival, frame: a.frame };
    if (a.viewMode === 'slice' && !this.following) this.refresh = { ...arrival, frame: -1 };
    this.schedule();
    this.updateUi();
  }

  // Frames committed between the page's describe and the watch's start had no event: the
  // dataset's frame count now says whether there are any.
  async catchUp() {
    const a = this.app;
    const gen = this.gen;
    try {
      const r = await a.conn.request({ describe: { dataset: this.dataset } });
      const n = Number(r.info.frame_count) || 0;
      if (gen !== this.gen || n - 1 <= this.head) return;
      a.info.frame_count = Math.max(a.info.frame_count, n);
      a.ui.setFrameRange(a.info.frame_count);
      this.head = n - 1;
      if (this.following) this.pending = { frame: this.head, lsn: this.lastLsn, kind: 'catch-up', points: 0, eventMs: performance.now(), eventWall: Date.now() };
      this.schedule();
    } catch (e) {
      if (gen === this.gen && e.code !== 'CLOSED') a.showError(e, 'live');
    }
  }

  // Shows what arrived, one load at a time; arrivals during a load coalesce into the newest.
  schedule() {
    if (this.pumping) {
      this.again = true;
      return;
    }
    this.pumping = true;
    (async () => {
      try {
        do {
          this.again = false;
          await this.step();
        } while (this.again || (this.following && this.pending));
      } finally {
        this.pumping = false;
      }
    })().catch((e) => {
      if (e.code !== 'CANCELLED' && e.code !== 'CLOSED') this.app.showError(e, 'live');
    });
  }

  async step() {
    const a = this.app;
    let job = null;
    if (this.following && this.pending) job = this.pending;
    else if (this.refresh) job = this.refresh;
    this.pending = this.refresh = null;
    if (!job || !this.on) return;
    if (job.frame === -1) {  // a slice on screen: query it anew
      if (a.viewMode === 'slice') await a.showCurrent();
      return;
    }
    if (!this.following && job.frame !== a.frame) return;  // paused elsewhere meanwhile
    await a.gotoFrame(job.frame);
    const drawnMs = performance.now();
    const drawnWall = Date.now();
    if (a.frame !== job.frame || a.target?.stale) return;  // superseded
    if (job.lsn !== null && !this.onScreen.some((s) => s.frame === job.frame && s.lsn === job.lsn)) {
      push(this.onScreen, {
        frame: job.frame, lsn: job.lsn, kind: job.kind, eventMs: job.eventMs, drawnMs,
        eventWall: job.eventWall, drawnWall, latencyMs: drawnMs - job.eventMs, points: a.shown ? a.shown.points : 0,
        queryMs: a.shown ? a.shown.loadMs : null,
        // The first picture of the frame (its coarse levels), before the complete one (drawnWall).
        firstDrawnWall: a.shown?.firstDrawnWall ?? drawnWall,
        firstLatencyMs: (a.shown?.firstDrawnMs ?? drawnMs) - job.eventMs,
      });
    }
    this.updateUi();
  }

  // {count, lastMs, medianMs, maxMs}: event arrival -> frame on screen, over onScreen.
  latency() {
    const v = this.onScreen.map((s) => s.latencyMs);
    return { count: v.length, lastMs: v.length ? v[v.length - 1] : null, medianMs: median(v), maxMs: v.length ? Math.max(...v) : null };
  }

  updateUi(message = null) {
    const a = this.app;
    if (!a.ui) return;
    a.ui.setLive(this.on, this.following, this.head - a.frame);
    let text = message;
    let cls = this.state === 'dropped' || this.state === 'closed' || this.state === 'error' ? 'error' : '';
    if (text === null) {
      if (!this.on) text = this.state === 'off' ? '' : `live: ${this.state}`;
      else if (this.state === 'starting' || this.state === 'replaying') text = `live: ${this.state}…`;
      else if (!this.following) {
        const behind = this.head - a.frame;
        text = `live paused at frame ${a.frame}${behind > 0 ? `, ${behind} newer` : ''} (End: return to live)`;
      } else {
        const l = this.latency();
        text = `live: frame ${this.head}${l.count ? `, event → screen ${l.lastMs.toFixed(0)} ms (median ${l.medianMs.toFixed(0)})` : ''}`;
        cls = 'live';
      }
    }
    a.setStatus('live', text, cls);
  }

  // window.hvdbLive: the hooks of the browser test and the benchmark.
  hooks() {
    const live = this;
    return {
      get on() { return live.on; },
      get following() { return live.following; },
      get state() { return live.state; },
      get head() { return live.head; },
      get lastLsn() { return live.lastLsn; },
      get liveLsn() { return live.liveLsn; },
      get events() { return live.events; },
      get resumes() { return live.resumes; },
      get frame() { return live.app.frame; },
      frames: live.frames,
      onScreen: live.onScreen,
      log: live.log,
      start: () => live.start(),
      stop: () => live.stop(),
      pause: () => live.pause(),
      goLive: () => live.goLive(),
      whenLive: () => live.whenLive(),
      latency: () => live.latency(),
      // Resolves with the onScreen entry of frame f once it is drawn (rejects after timeoutMs).
      waitForFrame(f, timeoutMs = 30000) {
        return new Promise((resolve, reject) => {
          const t0 = performance.now();
          const poll = () => {
            const s = live.onScreen.find((x) => x.frame === f);
            if (s) resolve(s);
            else if (performance.now() - t0 > timeoutMs) reject(new Error(`live: frame ${f} not drawn within ${timeoutMs} ms`));
            else setTimeout(poll, 10);
          };
          poll();
        });
      },
      // Feeds an event as if the server sent it (tests of LAGGED and DROPPED handling).
      inject: (ev) => live.onEvent(ev, true),
    };
  }
}
