"""Thesis fig. 9.7 as ONE scripted session of the page (web/) against a real hvdb-server on the
Panoptic video: the person is graph-cut over frames 4..6 (strokes through the page), copied,
pasted as a clone that is scaled by 0.5 and moved (the numeric transform entry); an image is
imported as a poster on the wall behind and the Stanford bunny as a mesh (the Import media
dialog); the Shadows toggle makes the clone cast its shadow onto the poster; Render video
exports a 2 s camera path (an orbit) as an MP4. Asserted: the clone's points and positions,
the poster's colours, the shadow, the video's frames, and that the page's Undo, repeated,
gives back the dataset record for record. With HVDB_DOC_PICTURES=DIR it also saves the
pictures of docs/images/fig97/ there."""
import base64
import hashlib
import io
import json
import os
import subprocess
import time

import numpy as np
from PIL import Image
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

import hvdb
from conftest import CLI, DATASET, FPS, SHARED, run_cli
from test_editor9 import js, wait_loaded
from test_viewer import EYE, FOV, TARGET, W, H, call, drag, open_page

FRAMES = (4, 5, 6)          # the cut, the clone and the video's frames (the timeline's in..out)
SHOWN = 5                   # the frame of the stills
PASTE_OFFSET = (0.6, 0.0, 0.0)
POSTER_AT, POSTER_WIDTH = (0.3, -0.85, 1.1), 1.6
# Where the scaled clone's centre goes: before the poster's middle, its back 4 cm from it.
CLONE_XY, CLONE_GAP = (0.45, -0.9), 0.04
POSTER_BIT, BUNNY_BIT = 9, 10
BUNNY = os.path.join(SHARED, "stanford-bunny", "reconstruction", "bun_zipper_res2.ply")
BUNNY_AT, BUNNY_SCALE = (-1.25, -0.26, 0.3), 2.5
VIDEO_SECONDS, VIDEO_ORBIT_DEG = 2, 30
PICTURES = os.environ.get("HVDB_DOC_PICTURES")


def all_frames(db):
    return [db.frame(DATASET, frame=f) for f in range(16)]


def checksums(frames):
    """Per frame: SHA-256 of every point record (all fields), in id order."""
    return [hashlib.sha256(np.sort(p, order="id").tobytes()).hexdigest() for p in frames]


def click(browser, element_id):
    browser.find_element(By.ID, element_id).click()


def set_value(browser, element_id, value):
    el = browser.find_element(By.ID, element_id)
    el.clear()
    el.send_keys(str(value))


def edit_by_button(browser, element_id):
    """Clicks an edit button; returns once the page's edit queue is done and drawn."""
    click(browser, element_id)
    return call(browser, "window.hvdbApp.idle()")


def set_in_out(browser, lo, hi):
    call(browser, "window.hvdbApp.gotoFrame(args[0])", lo)
    click(browser, "slice-in")
    call(browser, "window.hvdbApp.gotoFrame(args[0])", hi)
    click(browser, "slice-out")
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.app.viewMode") == "slice")
    wait_loaded(browser)


def still(browser, name=None):
    """The server's render of the page's view (the page's Render still), as an array."""
    url = call(browser, "window.hvdbApp.renderStill().then(r => r.png)")
    data = base64.b64decode(url.split(",", 1)[1])
    if PICTURES and name:
        with open(os.path.join(PICTURES, name), "wb") as f:
            f.write(data)
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(np.int32)


def project(cam, xyz):
    """Pixels (u, v) of world points in the wire camera (x right, y down, z forward)."""
    fx, fy, cx, cy = cam["intrinsics"]
    m = np.array(cam["world_from_camera"], dtype=float).reshape(4, 4)
    c = (xyz - m[:3, 3]) @ m[:3, :3]
    return np.stack([fx * c[:, 0] / c[:, 2] + cx, fy * c[:, 1] / c[:, 2] + cy], axis=1)


def import_media(browser, path, at, rotate, scale, width, bit):
    """The Import media dialog: the file, its placement, every frame, a label bit."""
    undo = js(browser, "window.hvdbApp.app.editor.undoStack.length")
    click(browser, "import-media")
    browser.find_element(By.ID, "media-file").send_keys(os.path.realpath(path))  # Chromium wants a canonical path
    for field, value in (("media-at", ", ".join(map(str, at))), ("media-rotate", ", ".join(map(str, rotate))),
                         ("media-scale", scale), ("media-width", width), ("media-frames", ""),
                         ("media-label-bit", bit)):
        set_value(browser, field, value)
    click(browser, "media-go")
    WebDriverWait(browser, 60).until(lambda d: d.execute_script(
        "return window.hvdbApp.app.editor.undoStack.length") == undo + 1)
    call(browser, "window.hvdbApp.idle()")
    assert js(browser, "window.hvdbApp.lastError") is None


def poster_image():
    """A 64 x 40 pattern: every pixel differs from its neighbours."""
    w, h = 64, 40
    img = Image.new("RGB", (w, h))
    img.putdata([((x * 4) % 256, (y * 6) % 256, (x * 7 + y * 13) % 256) for y in range(h) for x in range(w)])
    return img


def decode_video(mp4, frames, tmp_path, texels):
    """The video decoded by libavformat/libavcodec through `hvdb import-media --kind video`
    into a scratch dataset: dataset frame k shows video frame k, the last one held past the
    end. Returns each frame's picture (texels wide) as an array."""
    data = str(tmp_path / "decoded")
    run_cli("create", "v", "--fps", FPS, data=data)
    run_cli("import-media", "v", mp4, "--kind", "video", "--frames", 0, frames - 1, "--texels", texels, data=data)
    db = hvdb.open(data)
    try:
        pics = []
        for f in range(frames):
            p = db.frame("v", frame=f)
            x, y = p["position"][:, 0], p["position"][:, 1]
            s = 1.0 / texels  # the plane is 1 m wide: a texel is 1 / texels metres
            # Texel centres: x = (i + 0.5) s - 0.5, y from the top row (image up = +y) down.
            i, j = np.rint((x + 0.5) / s - 0.5).astype(int), np.rint((y.max() - y) / s).astype(int)
            pic = np.zeros((j.max() + 1, texels, 3), np.int32)
            pic[j, i] = p["color"][:, :3]
            pics.append(pic)
        return pics
    finally:
        db.close()


def test_fig97_session(browser, server, tmp_path):
    start = time.perf_counter()
    if PICTURES:
        os.makedirs(PICTURES, exist_ok=True)
    db = hvdb.connect(server.address)
    try:
        before = all_frames(db)
        sums_before = checksums(before)

        open_page(browser, server, frame=SHOWN)
        still(browser, "before.png")

        # 1. Graph cut over frames 4..6 (the timeline's in / out: shown at once), strokes as a
        # user paints them: foreground on the head and chest, background on the legs.
        set_in_out(browser, FRAMES[0], FRAMES[-1])
        assert js(browser, "window.hvdbApp.pointsShown()") == sum(len(before[f]) for f in FRAMES)
        click(browser, "tool-brush-fg")
        drag(browser, [(485, 110), (495, 160), (500, 210)])
        click(browser, "tool-brush-bg")
        drag(browser, [(470, 420), (500, 440), (525, 460)])
        assert call(browser, "window.hvdbApp.idle()")["undo"] == 2
        # (The background stroke's first stamp lands beside the legs of frames 4..6: "no
        # surface under pixel", reported in the status bar; its other stamps paint.)
        browser.execute_script("window.hvdbApp.app.lastError = null")
        click(browser, "graph-cut")
        WebDriverWait(browser, 120).until(
            lambda d: d.execute_script("return window.hvdbApp.app.editor.undoStack.length") == 3)
        wait_loaded(browser)
        cut = {}
        for f in FRAMES:
            p = db.frame(DATASET, frame=f)
            fg, bg, sel = ((p["label"] & b) != 0 for b in (2, 4, 1))
            assert fg.sum() > 50 and bg.sum() > 50, f"frame {f}: strokes {fg.sum()}, {bg.sum()}"
            assert sel[fg].all() and not sel[bg].any() and sel.sum() > 5000, f"frame {f}"
            cut[f] = p[sel]
        selected = sum(len(c) for c in cut.values())
        assert js(browser, "window.hvdbApp.selectedCount()") == selected

        # 2. Copy, clear the selection, paste (the pasted points keep the selection bit: the
        # clone alone is selected), then scale by 0.5 and move with the numeric entry.
        edit_by_button(browser, "copy")
        edit_by_button(browser, "clear-selection")
        set_value(browser, "paste-offset", ",".join(map(str, PASTE_OFFSET + (0,))))
        edit_by_button(browser, "paste")
        clone = {}
        for f in FRAMES:
            p = db.frame(DATASET, frame=f)
            clone[f] = p[(p["label"] & 1) != 0]
            assert len(clone[f]) == len(cut[f]), f"frame {f}: the clone has {len(clone[f])} points, the cut {len(cut[f])}"
            assert not set(clone[f]["id"].tolist()) & set(cut[f]["id"].tolist())  # new points
        assert js(browser, "window.hvdbApp.selectedCount()") == selected  # the clone alone
        pos = np.concatenate([clone[f]["position"] for f in FRAMES]).astype(np.float64)
        centre = pos.mean(axis=0)
        depth = 0.5 * (pos[:, 2].max() - centre[2])  # the scaled clone's back, behind its centre
        move = np.array(CLONE_XY + (POSTER_AT[2] - CLONE_GAP - depth,)) - centre
        set_value(browser, "xf-translate", ",".join(f"{v:.9f}" for v in move) + ",0")
        set_value(browser, "xf-angle", 0)
        set_value(browser, "xf-scale", 0.5)
        click(browser, "xf-add")
        pending = js(browser, "window.hvdbApp.pendingTransform()")
        A, off = np.array(pending["matrix"]).reshape(4, 4), np.array(pending["offset"])
        assert np.allclose(A, np.diag([0.5, 0.5, 0.5, 1]), atol=1e-12), A
        # About the clone's centre (the page's, of the points on screen), then moved.
        assert np.allclose(off[:3], 0.5 * centre + move, atol=1e-4) and off[3] == 0, (off, centre, move)
        undo = js(browser, "window.hvdbApp.app.editor.undoStack.length")
        click(browser, "xf-apply")
        WebDriverWait(browser, 60).until(
            lambda d: d.execute_script("return window.hvdbApp.app.editor.undoStack.length") == undo + 1)
        call(browser, "window.hvdbApp.idle()")
        for f in FRAMES:
            p = db.frame(DATASET, frame=f)
            now = p[(p["label"] & 1) != 0]
            assert len(now) == len(cut[f])
            want = (cut[f]["position"].astype(np.float64) + PASTE_OFFSET) @ A[:3, :3].T + off[:3]
            dist, idx = cKDTree(now["position"].astype(np.float64)).query(want)
            assert dist.max() < 1e-5, f"frame {f}: a clone point {dist.max()} m from where it should be"
            assert len(set(idx.tolist())) == len(want)  # one clone point per original
            assert (now["color"][idx] == cut[f]["color"]).all()
        click(browser, "slice-clear-in-out")  # back to frames: the stills show frame 5
        wait_loaded(browser)
        call(browser, "window.hvdbApp.gotoFrame(args[0])", SHOWN)
        p = db.frame(DATASET, frame=SHOWN)
        clone_now = p["position"][(p["label"] & 1) != 0].astype(np.float64)

        # 3. The poster (a PNG with a known pattern) on the wall behind, the bunny on the floor.
        img = poster_image()
        poster_png = str(tmp_path / "poster.png")
        img.save(poster_png)
        # 180 degrees about x: image up is world up here (y points down), facing the camera.
        import_media(browser, poster_png, POSTER_AT, (180, 0, 0), 1, POSTER_WIDTH, POSTER_BIT)
        p = db.frame(DATASET, frame=SHOWN)
        poster = p[(p["label"] & (1 << POSTER_BIT)) != 0]
        assert len(poster) == img.width * img.height
        s = POSTER_WIDTH / img.width
        xy = poster["position"].astype(np.float64)
        i = np.floor((xy[:, 0] - POSTER_AT[0] + POSTER_WIDTH / 2) / s).astype(int)
        j = np.floor((xy[:, 1] - POSTER_AT[1] + img.height * s / 2) / s).astype(int)
        assert np.allclose(xy[:, 2], POSTER_AT[2], atol=1e-5)
        pixels = np.asarray(img)
        assert len(set(zip(i.tolist(), j.tolist()))) == len(poster)  # one surfel per pixel
        assert (poster["color"][:, :3] == pixels[j, i]).all(), "the poster's colours are the image's pixels"
        import_media(browser, BUNNY, BUNNY_AT, (180, 0, 0), BUNNY_SCALE, 1, BUNNY_BIT)
        p = db.frame(DATASET, frame=SHOWN)
        bunny = p["position"][(p["label"] & (1 << BUNNY_BIT)) != 0].astype(np.float64)
        assert len(bunny) > 10000
        extent = bunny.max(axis=0) - bunny.min(axis=0)
        assert np.allclose((bunny.max(axis=0) + bunny.min(axis=0)) / 2, BUNNY_AT, atol=1e-4)
        assert 0.3 < extent[0] < 0.45 and 0.3 < extent[1] < 0.45  # 0.155 m x 0.15 m, x 2.5
        plain = still(browser, "after.png")

        # 4. Shadows: the selection (the clone) casts onto the poster behind it.
        click(browser, "render-shadows")
        lit = still(browser, "shadows.png")
        assert lit.shape == plain.shape == (H, W, 3)
        assert (lit <= plain).all(), "shadows only darken"
        darker = lit.sum(axis=2) < plain.sum(axis=2)
        cam = js(browser, "window.hvdbApp.camera()")
        uv = project(cam, clone_now)
        u0, v0 = np.floor(uv.min(axis=0)).astype(int)
        u1, v1 = np.ceil(uv.max(axis=0)).astype(int)
        poster_uv = project(cam, poster["position"].astype(np.float64))
        pu0, pv0 = np.floor(poster_uv.min(axis=0)).astype(int)
        # Under the caster: the poster below the clone (not the clone itself) darkens.
        clone_px = np.zeros((H, W), bool)
        u, v = np.rint(uv).astype(int).T
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        clone_px[v[ok], u[ok]] = True
        clone_px = binary_dilation(clone_px, iterations=6)  # its splats' footprints
        pu1, pv1 = np.ceil(poster_uv.max(axis=0)).astype(int)
        on_poster = np.zeros((H, W), bool)
        on_poster[pv0 + 2:pv1 - 1, pu0 + 2:pu1 - 1] = True
        cast = darker & on_poster & ~clone_px
        assert cast.sum() > 500, cast.sum()
        assert np.nonzero(cast)[0].mean() > uv[:, 1].mean()  # below the clone: the light is above
        # Away from it: unchanged, bit for bit (left of the clone: the dancer, the bunny).
        away = np.ones((H, W), bool)
        away[max(0, v0 - 30):, max(0, u0 - 60):min(W, u1 + 60)] = False
        assert not darker[away].any() and (lit[away] == plain[away]).all()

        # 5. A 2 s camera path (an orbit) of frames 4..6 as a video: the Render video button.
        set_in_out(browser, FRAMES[0], FRAMES[-1])
        set_value(browser, "render-video-seconds", VIDEO_SECONDS)
        set_value(browser, "render-video-orbit", VIDEO_ORBIT_DEG)
        click(browser, "render-video")
        WebDriverWait(browser, 120).until(lambda d: d.execute_script(
            "return !!window.hvdbApp.lastVideo && !document.getElementById('render-video').disabled"))
        assert js(browser, "window.hvdbApp.lastError") is None
        video = js(browser, "window.hvdbApp.lastVideo")
        n = round(VIDEO_SECONDS * FPS)
        assert video["frames"] == n and video["fps"] == FPS
        assert video["shown"] == [FRAMES[i % len(FRAMES)] for i in range(n)]
        mp4 = tmp_path / "fig97.mp4"
        mp4.write_bytes(base64.b64decode(call(browser, (
            "new Promise((ok, fail) => { const r = new FileReader(); r.onload = () => ok(r.result.split(',')[1]);"
            " r.onerror = () => fail(r.error); r.readAsDataURL(new Blob([window.hvdbApp.app.exporter.lastVideoBytes])); })"))))
        assert mp4.stat().st_size == video["bytes"]
        # Decoded: n frames (past the end the last one is held), each a new view of the orbit.
        pics = decode_video(str(mp4), n + 2, tmp_path, 48)
        assert all(p.shape == (27, 48, 3) for p in pics), pics[0].shape
        same = [np.array_equal(pics[k], pics[k + 1]) for k in range(n + 1)]
        assert same[n - 1] and same[n] and not same[n - 2], same
        assert sum(same[:n - 1]) < n // 4  # the camera moves: most frames differ
        if PICTURES:
            k = n // 2
            pic = decode_video(str(mp4), k + 1, tmp_path / "full", W // 2)[k]
            Image.fromarray(pic.astype(np.uint8)).save(os.path.join(PICTURES, "video_frame.png"))
        session_s = time.perf_counter() - start

        # Undo everything with the page's Undo button: the dataset is what it was, exactly.
        click(browser, "render-shadows")
        click(browser, "slice-clear-in-out")
        wait_loaded(browser)
        undos = js(browser, "window.hvdbApp.app.editor.undoStack.length")
        assert undos == 8  # 2 strokes, the cut, clear selection, paste, transform, 2 imports
        for k in range(undos):
            edit_by_button(browser, "undo")
            assert js(browser, "window.hvdbApp.app.editor.undoStack.length") == undos - k - 1
        assert js(browser, "window.hvdbApp.lastError") is None
        after = all_frames(db)
        assert [len(p) for p in after] == [len(p) for p in before]
        assert checksums(after) == sums_before
    finally:
        db.close()
    print(f"fig. 9.7 session: {session_s:.1f} s, undo {time.perf_counter() - start - session_s:.1f} s")
