"""The editor page's thesis ch. 9.2-9.4 tools in a real browser against a real hvdb-server:
a line drawn on the canvas gives the hyperslice of web/README.md's formula (computed here
again) and the slider moves it; in and out points show several frames at once; a gizmo drag
translates the selection by the vector the page sent and undo restores it; a rotation from
time into space moves the points as its 4D matrix says; add / subtract / intersect give what
the command line's `hvdb select --mode` gives; the brush's nearest and median depth are the
command line's."""
import csv
import json
import math

import numpy as np
import pytest
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait

import hvdb
from conftest import DATASET, FPS, run_cli
from test_viewer import EYE, FOV, FRAME, TARGET, W, H, call, drag, frame_points, open_page

BIG = 1e9
RECT_A = (400, 120, 560, 330)
RECT_B = (480, 200, 640, 420)


def js(browser, expr):
    return browser.execute_script("return " + expr)


def wait_loaded(browser):
    """Until the page's view is loaded and drawn (no edit running)."""
    call(browser, "window.hvdbApp.idle()")
    WebDriverWait(browser, 60).until(
        lambda d: d.execute_script("const a = window.hvdbApp.app; return !!a.shown && a.shown.done && a.shown === a.target"))


def slice_basis(normal):
    """V2, V3, V4 of storage/hyperslice.cc: Gram-Schmidt over the axes but the most parallel."""
    n = np.array(normal, dtype=float) / np.linalg.norm(normal)
    drop = int(np.argmax(np.abs(n)))
    basis = [n]
    for axis in range(4):
        if axis == drop:
            continue
        v = np.eye(4)[axis]
        for b in basis:
            v = v - (v @ b) * b
        basis.append(v / np.linalg.norm(v))
    return np.array(basis[1:])


def slice_formula(cam, p0, p1, basis=np.eye(4)[:3]):
    """web/README.md's formula: the plane through the eye and both rays, n, b; N = B^T n."""
    fx, fy, cx, cy = cam["intrinsics"]
    m = np.array(cam["world_from_camera"], dtype=float).reshape(4, 4)
    rays = [m[:3, :3] @ np.array([(u - cx) / fx, (v - cy) / fy, 1.0]) for u, v in (p0, p1)]
    n = np.cross(rays[0], rays[1])
    n /= np.linalg.norm(n)
    return list(basis.T @ n), float(n @ m[:3, 3])


def test_line_drawn_gives_the_theses_slice_and_the_slider_moves_it(browser, server):
    open_page(browser, server)
    cam = js(browser, "window.hvdbApp.camera()")
    browser.find_element(By.ID, "tool-slice").click()
    drag(browser, [(300, 150), (450, 300), (620, 420)])
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.app.viewMode") == "slice")
    wait_loaded(browser)
    line = js(browser, "window.hvdbApp.app.sliceTool.lastLine")
    assert all(abs(a - b) <= 1 for a, b in zip(line["p0"] + line["p1"], (300, 150, 620, 420))), line
    normal, offset = slice_formula(cam, line["p0"], line["p1"])
    sent = js(browser, "window.hvdbApp.region()")["slice"]
    assert np.allclose(sent["normal"], normal, atol=1e-9), (sent["normal"], normal)
    assert math.isclose(sent["offset"], offset, abs_tol=1e-9)
    # Its centre plane projects onto the line: the line's ends at any depth lie on it.
    m = np.array(cam["world_from_camera"]).reshape(4, 4)
    for u, v in (line["p0"], line["p1"]):
        for depth in (1.0, 3.0):
            x = m[:3, :3] @ np.array([(u - cam["intrinsics"][2]) / cam["intrinsics"][0] * depth,
                                      (v - cam["intrinsics"][3]) / cam["intrinsics"][1] * depth, depth]) + m[:3, 3]
            assert abs(np.dot(normal[:3], x) - offset) < 1e-9
    db = hvdb.connect(server.address)
    try:
        want = len(db.hyperslice(DATASET, sent["normal"], sent["offset"], sent["thickness"]))
        assert want > 1000 and js(browser, "window.hvdbApp.pointsShown()") == want
        # The slider moves it along its normal by its value.
        browser.execute_script(
            "const s = document.getElementById('slice-move'); s.value = '0.1';"
            "s.dispatchEvent(new Event('input'));")
        moved = float(js(browser, "document.getElementById('slice-move').value"))
        assert moved > 0.05
        wait_loaded(browser)
        after = js(browser, "window.hvdbApp.region()")["slice"]
        assert np.allclose(after["normal"], normal, atol=1e-9)
        assert math.isclose(after["offset"], offset + moved, abs_tol=1e-9)
        want = len(db.hyperslice(DATASET, after["normal"], after["offset"], after["thickness"]))
        assert js(browser, "window.hvdbApp.pointsShown()") == want
        # A line drawn in that slice: its displayed space is B (x, y, z, s t), N = B^T n.
        cam = js(browser, "window.hvdbApp.camera()")
        drag(browser, [(200, 270), (760, 300)])
        WebDriverWait(browser, 60).until(
            lambda d: d.execute_script("return window.hvdbApp.region().slice.normal[3]") != 0)
        wait_loaded(browser)
        line = js(browser, "window.hvdbApp.app.sliceTool.lastLine")
        normal2, offset2 = slice_formula(cam, line["p0"], line["p1"], slice_basis(after["normal"]))
        r2 = js(browser, "window.hvdbApp.region()")["slice"]
        assert np.allclose(r2["normal"], normal2, atol=1e-9) and math.isclose(r2["offset"], offset2, abs_tol=1e-9)
        assert abs(r2["normal"][3]) > 1e-3  # time is no longer orthogonal to it
        want = len(db.hyperslice(DATASET, r2["normal"], r2["offset"], r2["thickness"]))
        assert want > 100 and js(browser, "window.hvdbApp.pointsShown()") == want
    finally:
        db.close()
    browser.find_element(By.ID, "slice-back").click()


def test_in_and_out_points_show_frames_and_bound_a_slice(browser, server):
    open_page(browser, server, frame=3)
    scale = float(js(browser, "window.hvdbApp.app.info.space_time_scale")) or 1.0
    browser.find_element(By.ID, "slice-in").click()
    wait_loaded(browser)
    call(browser, "window.hvdbApp.gotoFrame(5)")
    browser.find_element(By.ID, "slice-out").click()
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.app.viewMode") == "slice")
    wait_loaded(browser)
    r = js(browser, "window.hvdbApp.region()")["slice"]
    t3, t8 = 3 / FPS, 5 / FPS
    assert r["normal"] == [0, 0, 0, 1]
    assert math.isclose(r["offset"], scale * (t3 + t8) / 2, rel_tol=1e-12)
    assert math.isclose(r["thickness"], scale * ((t8 - t3) / 2 + 0.5 / FPS), rel_tol=1e-12)
    want = sum(len(frame_points(server, f)["id"]) for f in range(3, 6))
    assert js(browser, "window.hvdbApp.pointsShown()") == want
    # A line drawn now: a slice through time, bounded by the in and out points.
    browser.find_element(By.ID, "tool-slice").click()
    drag(browser, [(480, 60), (480, 500)])
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.region().slice.normal[3]") == 0)
    wait_loaded(browser)
    r = js(browser, "window.hvdbApp.region()")["slice"]
    assert r["clip"]["lo"][3] == pytest.approx(t3) and r["clip"]["hi"][3] == pytest.approx(t8)
    db = hvdb.connect(server.address)
    try:
        pts = db.hyperslice(DATASET, r["normal"], r["offset"], r["thickness"], clip={"t": (t3, t8)})
    finally:
        db.close()
    assert len(pts) > 100 and js(browser, "window.hvdbApp.pointsShown()") == len(pts)
    assert set(np.unique(pts["frame"]).tolist()) == set(range(3, 6))  # the trajectory over time
    browser.find_element(By.ID, "slice-clear-in-out").click()
    wait_loaded(browser)


def window_csv(server, tmp_path, name, t0=None, t1=None, mask=1):
    """The selected points through `hvdb window --out CSV`: {id: (frame, x, y, z)}."""
    t0 = FRAME / FPS if t0 is None else t0
    t1 = t0 if t1 is None else t1
    out = tmp_path / f"{name}.csv"
    run_cli("window", DATASET, "--box", -BIG, BIG, -BIG, BIG, -BIG, BIG, t0, t1, "--label-mask", mask,
            "--out", out, server=server.address)
    with open(out) as f:
        return {int(r["id"]): (int(r["frame"]), float(r["x"]), float(r["y"]), float(r["z"])) for r in csv.DictReader(f)}


def select_rect(browser, rect, mode="SELECT_REPLACE"):
    call(browser, "window.hvdbApp.marquee(...args[0])", list(rect) + [mode])
    wait_loaded(browser)


def test_gizmo_drag_translates_the_selection_and_undo_restores(browser, server, tmp_path):
    open_page(browser, server)
    select_rect(browser, RECT_A)
    before = window_csv(server, tmp_path, "before")
    assert len(before) > 1000
    browser.find_element(By.ID, "tool-transform").click()
    g = js(browser, "window.hvdbApp.gizmo()")
    tip = (round(g["axes"][0]["u"]), round(g["axes"][0]["v"]))
    ax = np.array([g["axes"][0]["du"], g["axes"][0]["dv"]])
    step = np.round(ax / np.linalg.norm(ax) * 60).astype(int)
    drag(browser, [tip, (tip[0] + step[0] // 2, tip[1] + step[1] // 2), (tip[0] + step[0], tip[1] + step[1])])
    pending = js(browser, "window.hvdbApp.pendingTransform()")
    off = np.array(pending["offset"])
    # Along x only, by the drag projected on the arrow (90 px = L metres); a pixel's rounding.
    expect = step @ ax / (ax @ ax) * g["L"]
    assert abs(off[0] - expect) <= 1.5 * g["L"] / 90 and off[0] > 0.1
    assert np.allclose(off[1:], 0) and np.allclose(pending["matrix"], np.eye(4).ravel())
    assert js(browser, "window.hvdbApp.preview") is not None  # drawn moved before it is sent
    undo_before = js(browser, "window.hvdbApp.app.editor.undoStack.length")
    browser.find_element(By.ID, "xf-apply").click()
    WebDriverWait(browser, 60).until(
        lambda d: d.execute_script("return window.hvdbApp.app.editor.undoStack.length") == undo_before + 1)
    wait_loaded(browser)
    after = window_csv(server, tmp_path, "after")
    assert set(after) == set(before)
    for i, (f, x, y, z) in before.items():
        fa, xa, ya, za = after[i]
        assert fa == f and abs(xa - (x + off[0])) < 1e-5 and abs(ya - y) < 1e-6 and abs(za - z) < 1e-6
    assert js(browser, "window.hvdbApp.preview") is None
    call(browser, "window.hvdbApp.undo()")
    assert window_csv(server, tmp_path, "undone") == before
    browser.find_element(By.ID, "tool-navigate").click()
    call(browser, "window.hvdbApp.app.editor.clearSelection()")


def test_rotation_from_time_into_space_moves_points_as_the_matrix_says(browser, server, tmp_path):
    frame = 8
    open_page(browser, server, frame=frame)
    select_rect(browser, RECT_A)
    t = frame / FPS
    before = window_csv(server, tmp_path, "rb", t)
    scale = float(js(browser, "window.hvdbApp.app.info.space_time_scale")) or 1.0
    for field, value in (("xf-translate", "0,0,0,0"), ("xf-angle", "20"), ("xf-scale", "1")):
        el = browser.find_element(By.ID, field)
        el.clear()
        el.send_keys(value)
    browser.find_element(By.CSS_SELECTOR, "#xf-plane option[value='xt'], #xf-plane option:nth-child(4)").click()
    browser.find_element(By.ID, "xf-add").click()
    pending = js(browser, "window.hvdbApp.pendingTransform()")
    # The same map computed here: rotate (x, s t) by 20 degrees about the selection's centre.
    pos = np.array([v[1:] for v in before.values()])
    c = np.array(list(pos.mean(axis=0)) + [scale * t])
    a = math.radians(20)
    R = np.eye(4)
    R[0, 0], R[0, 3], R[3, 0], R[3, 3] = math.cos(a), -math.sin(a), math.sin(a), math.cos(a)
    S = np.diag([1, 1, 1, scale])
    A = np.linalg.inv(S) @ R @ S
    off = np.linalg.inv(S) @ (c - R @ c)
    assert np.allclose(np.array(pending["matrix"]).reshape(4, 4), A, atol=1e-9)
    assert np.allclose(pending["offset"], off, atol=1e-5)
    browser.find_element(By.ID, "xf-apply").click()
    call(browser, "window.hvdbApp.idle()")
    after = window_csv(server, tmp_path, "ra", 0, 100)
    assert set(after) == set(before)
    A, off = np.array(pending["matrix"]).reshape(4, 4), np.array(pending["offset"])
    frames = set()
    for i, (f, x, y, z) in before.items():
        X = A @ np.array([x, y, z, f / FPS]) + off
        fa, xa, ya, za = after[i]
        assert abs(xa - X[0]) < 1e-4 and abs(ya - X[1]) < 1e-4 and abs(za - X[2]) < 1e-4
        assert fa == round(X[3] * FPS)
        frames.add(fa)
    assert len(frames) >= 3  # time turned into space: one frame spread over several
    call(browser, "window.hvdbApp.undo()")
    assert window_csv(server, tmp_path, "ru", t) == before
    call(browser, "window.hvdbApp.app.editor.clearSelection()")


def selected_ids(server, bit):
    pts = frame_points(server, FRAME)
    return set(pts["id"][(pts["label"] & (1 << bit)) != 0].tolist())


def cli_select(server, rect, mode, bit=5):
    t = FRAME / FPS
    run_cli("select", DATASET, "--bit", bit, "--mode", mode, "--box", -BIG, BIG, -BIG, BIG, -BIG, BIG, t, t,
            "--rect", *rect, "--look-at", *EYE, *TARGET, "--fov", FOV, "--size", W, H, server=server.address)


def sent_rect(browser):
    poly = js(browser, "window.hvdbApp.lastRequest")["select"]["lasso"]["polygon"]
    return [poly[0], poly[1], poly[4], poly[5]]


def rect_drag(browser, rect, keys=()):
    canvas = browser.find_element(By.ID, "view")
    u0, v0, u1, v1 = rect
    chain = ActionChains(browser)
    for k in keys:
        chain.key_down(k)
    (chain.move_to_element_with_offset(canvas, u0 - W // 2, v0 - H // 2).click_and_hold()
     .move_by_offset((u1 - u0) // 2, (v1 - v0) // 2)
     .move_by_offset(u1 - u0 - (u1 - u0) // 2, v1 - v0 - (v1 - v0) // 2).release())
    for k in keys:
        chain.key_up(k)
    chain.perform()


@pytest.mark.parametrize("mode,button,keys", [
    ("add", "mode-add", ()), ("subtract", "mode-subtract", ()), ("intersect", "mode-intersect", ()),
    ("intersect", "mode-replace", (Keys.SHIFT, Keys.ALT))])
def test_selection_modes_are_the_command_lines(browser, server, mode, button, keys):
    open_page(browser, server)
    browser.find_element(By.ID, "tool-marquee").click()
    browser.find_element(By.ID, "mode-replace").click()
    rect_drag(browser, RECT_A)
    wait_loaded(browser)
    first = selected_ids(server, 0)
    rect_a = sent_rect(browser)
    browser.find_element(By.ID, button).click()
    rect_drag(browser, RECT_B, keys)
    WebDriverWait(browser, 60).until(
        lambda d: d.execute_script("return window.hvdbApp.lastRequest.select.mode") == f"SELECT_{mode.upper()}")
    wait_loaded(browser)
    page = selected_ids(server, 0)
    # The rectangles as the page sent them (the mouse lands within a pixel of where it is told).
    cli_select(server, rect_a, "replace")
    cli_select(server, sent_rect(browser), mode)
    cli = selected_ids(server, 5)
    assert page == cli and page != first and len(first) > 1000
    assert js(browser, "window.hvdbApp.selectedCount()") == len(page)
    browser.find_element(By.ID, "mode-replace").click()
    call(browser, "window.hvdbApp.app.editor.clearSelection(33)")


def test_graph_cut_result_combines_by_the_mode(browser, server):
    open_page(browser, server)
    browser.find_element(By.ID, "tool-brush-fg").click()
    drag(browser, [(485, 110), (495, 160), (500, 210)])
    browser.find_element(By.ID, "tool-brush-bg").click()
    drag(browser, [(470, 420), (500, 440), (525, 460)])
    call(browser, "window.hvdbApp.idle()")
    call(browser, "window.hvdbApp.app.editor.graphCut(false, 'SELECT_REPLACE')")
    cut = selected_ids(server, 0)
    select_rect(browser, RECT_B)
    box = selected_ids(server, 0)
    browser.find_element(By.ID, "mode-intersect").click()
    browser.find_element(By.ID, "graph-cut").click()
    WebDriverWait(browser, 120).until(lambda d: d.execute_script("return window.hvdbApp.app.editor.undoStack.length") == 5)
    wait_loaded(browser)
    assert selected_ids(server, 0) == cut & box and 0 < len(cut & box) < len(box)
    pts = frame_points(server, FRAME)
    assert not ((pts["label"] & (3 << 30)) != 0).any()  # the scratch bits are clear
    call(browser, "window.hvdbApp.undo()")  # one undo: the cut and its combination
    assert selected_ids(server, 0) == box
    browser.find_element(By.ID, "mode-replace").click()
    for _ in range(4):
        call(browser, "window.hvdbApp.undo()")


@pytest.mark.parametrize("nearest", [False, True])
def test_brush_depth_nearest_or_median_is_the_command_lines(browser, server, nearest):
    open_page(browser, server)
    sel = browser.find_element(By.ID, "brush-depth")
    sel.find_element(By.CSS_SELECTOR, f"option[value='{'nearest' if nearest else 'median'}']").click()
    browser.find_element(By.ID, "tool-brush-fg").click()
    u, v = 470, 200
    drag(browser, [(u, v), (u, v)])
    call(browser, "window.hvdbApp.idle()")
    req = js(browser, "window.hvdbApp.lastBrushRequest")["select"]["brush"]
    assert req["nearest"] is nearest
    page_center = js(browser, "window.hvdbApp.lastSelect")["brush_center"]
    page = selected_ids(server, 1)
    t = FRAME / FPS

    def cli(near, bit):
        return json.loads(run_cli(
            "select", DATASET, "--bit", bit, "--box", -BIG, BIG, -BIG, BIG, -BIG, BIG, t, t,
            "--brush", req["u"], req["v"], "--pixel-radius", req["pixel_radius"], "--radius", req["radius"],
            *(["--nearest"] if near else []), "--look-at", *EYE, *TARGET, "--fov", FOV, "--size", W, H,
            "--json", server=server.address))
    same, other = cli(nearest, 6), cli(not nearest, 7)
    assert np.allclose(page_center, same["brush_center"], atol=1e-6)
    assert page == selected_ids(server, 6) and len(page) > 10
    # Here (the head's edge) the two depths differ: the choice is the one the page made.
    assert np.linalg.norm(np.subtract(same["brush_center"], other["brush_center"])) > 0.01
    assert selected_ids(server, 7) != page
    call(browser, "window.hvdbApp.undo()")
    call(browser, "window.hvdbApp.app.editor.clearSelection(64 | 128)")


def test_numeric_translation_in_time_moves_the_selection_frames_later(browser, server, tmp_path):
    open_page(browser, server)
    select_rect(browser, RECT_A)
    before = window_csv(server, tmp_path, "tb")
    for field, value in (("xf-translate", f"0.1,0,0,{2 / FPS}"), ("xf-angle", "0"), ("xf-scale", "1")):
        el = browser.find_element(By.ID, field)
        el.clear()
        el.send_keys(value)
    browser.find_element(By.ID, "xf-add").click()
    canvas = browser.find_element(By.ID, "view")
    canvas.click()
    ActionChains(browser).send_keys(Keys.ENTER).perform()  # Enter applies
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.pendingTransform()") is None)
    call(browser, "window.hvdbApp.idle()")
    after = window_csv(server, tmp_path, "ta", 0, 100)
    assert set(after) == set(before)
    for i, (f, x, y, z) in before.items():
        fa, xa, ya, za = after[i]
        assert fa == f + 2 and abs(xa - x - 0.1) < 1e-5 and abs(ya - y) < 1e-6 and abs(za - z) < 1e-6
    call(browser, "window.hvdbApp.undo()")
    assert window_csv(server, tmp_path, "tu") == before
    call(browser, "window.hvdbApp.app.editor.clearSelection()")


def test_a_stroke_begun_over_empty_space_paints_where_it_reaches_the_surface(browser, server):
    open_page(browser, server)
    undo = js(browser, "window.hvdbApp.app.editor.undoStack.length")
    before = selected_ids(server, 1)  # the foreground strokes' bit
    browser.find_element(By.ID, "tool-brush-fg").click()
    # From the empty studio floor's left (no surface under the brush) onto the chest.
    drag(browser, [(60, 300), (300, 220), (490, 180)])
    stacks = call(browser, "window.hvdbApp.idle()")
    assert js(browser, "window.hvdbApp.lastError") is None
    assert stacks["undo"] == undo + 1
    painted = selected_ids(server, 1)
    assert len(painted - before) > 10
    # An intersect stroke that meets no surface at all leaves the selection and the undo stack.
    browser.find_element(By.ID, "mode-intersect").click()
    drag(browser, [(60, 300), (80, 320), (100, 340)])
    stacks = call(browser, "window.hvdbApp.idle()")
    browser.find_element(By.ID, "mode-replace").click()
    assert js(browser, "window.hvdbApp.lastError") is None
    assert stacks["undo"] == undo + 1
    assert selected_ids(server, 1) == painted
    call(browser, "window.hvdbApp.undo()")
    assert selected_ids(server, 1) == before


def test_brush_strokes_subtract_and_intersect(browser, server):
    open_page(browser, server)
    browser.find_element(By.ID, "tool-brush-fg").click()
    drag(browser, [(470, 150), (490, 200), (500, 260)])
    call(browser, "window.hvdbApp.idle()")
    first = selected_ids(server, 1)
    # Alt: subtract a crossing stroke; then intersect (the button) with another.
    canvas = browser.find_element(By.ID, "view")
    (ActionChains(browser).key_down(Keys.ALT).move_to_element_with_offset(canvas, 440 - W // 2, 200 - H // 2)
     .click_and_hold().move_by_offset(30, 0).move_by_offset(30, 0).release().key_up(Keys.ALT).perform())
    call(browser, "window.hvdbApp.idle()")
    erased = selected_ids(server, 1)
    assert js(browser, "window.hvdbApp.lastBrushRequest.select.mode") == "SELECT_SUBTRACT"
    assert erased < first and len(erased) > 10
    browser.find_element(By.ID, "mode-intersect").click()
    drag(browser, [(490, 230), (495, 280), (500, 330)])
    call(browser, "window.hvdbApp.idle()")
    kept = selected_ids(server, 1)
    assert js(browser, "window.hvdbApp.lastBrushRequest.select.bit") == 30
    assert 0 < len(kept) < len(erased) and kept < erased
    pts = frame_points(server, FRAME)
    assert not ((pts["label"] & (3 << 30)) != 0).any()
    browser.find_element(By.ID, "mode-replace").click()
    for _ in range(3):
        call(browser, "window.hvdbApp.undo()")
    assert not selected_ids(server, 1)


def test_gizmo_ring_rotates_about_the_view_and_corner_scales(browser, server):
    open_page(browser, server)
    select_rect(browser, RECT_A)
    browser.find_element(By.ID, "tool-transform").click()
    g = js(browser, "window.hvdbApp.gizmo()")
    o = (g["o"]["u"], g["o"]["v"])
    # A quarter of the ring, from its right to its bottom (v down): +90 degrees on screen.
    r = 110
    pts = [(round(o[0] + r * math.cos(a)), round(o[1] + r * math.sin(a))) for a in np.linspace(0, math.pi / 2, 6)]
    drag(browser, pts)
    m = np.array(js(browser, "window.hvdbApp.pendingTransform()")["matrix"]).reshape(4, 4)
    ang = math.atan2(pts[-1][1] - o[1], pts[-1][0] - o[0]) - math.atan2(pts[0][1] - o[1], pts[0][0] - o[0])
    # The camera looks along +z with x right and y down: a rotation in the x-y plane by ang.
    want = np.eye(4)
    want[0, 0], want[0, 1], want[1, 0], want[1, 1] = math.cos(ang), -math.sin(ang), math.sin(ang), math.cos(ang)
    assert np.allclose(m, want, atol=0.02), m  # a pixel of the mouse: 0.01 rad
    assert np.allclose(m @ m.T, np.eye(4), atol=1e-9)  # a rotation, not just close to one
    browser.find_element(By.ID, "xf-cancel").click()
    assert js(browser, "window.hvdbApp.pendingTransform()") is None and js(browser, "window.hvdbApp.preview") is None
    # The corner square: scale by the ratio of distances from the centre.
    g = js(browser, "window.hvdbApp.gizmo()")
    o = np.array([g["o"]["u"], g["o"]["v"]])
    start = np.round(g["scaleAt"]).astype(int)
    end = np.round(o + (start - o) * 1.5).astype(int)
    drag(browser, [tuple(start), tuple(end)])
    m = np.array(js(browser, "window.hvdbApp.pendingTransform()")["matrix"]).reshape(4, 4)
    k = np.linalg.norm(end - o) / np.linalg.norm(start - o)
    assert np.allclose(m, np.diag([k, k, k, 1]), atol=0.02), m
    browser.find_element(By.ID, "xf-cancel").click()
    browser.find_element(By.ID, "tool-navigate").click()
    call(browser, "window.hvdbApp.app.editor.clearSelection()")


def test_gizmo_in_a_slice_through_time_translates_in_time(browser, server, tmp_path):
    open_page(browser, server, frame=5)
    browser.find_element(By.ID, "slice-in").click()
    wait_loaded(browser)
    call(browser, "window.hvdbApp.gotoFrame(7)")
    browser.find_element(By.ID, "slice-out").click()
    wait_loaded(browser)
    browser.find_element(By.ID, "tool-slice").click()
    drag(browser, [(480, 60), (480, 500)])
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return window.hvdbApp.region().slice.normal[3]") == 0)
    wait_loaded(browser)
    select_rect(browser, (0, 0, W - 1, H - 1))  # every point of the slice on screen (frames 5..7)
    before = window_csv(server, tmp_path, "sb", 0, 100)
    assert len(before) > 100 and {f for f, *_ in before.values()} <= set(range(5, 8))
    browser.find_element(By.ID, "tool-transform").click()
    g = js(browser, "window.hvdbApp.gizmo()")
    # The displayed z axis of a slice parallel to t is s t (storage/hyperslice.cc's basis).
    a = g["axes"][2]
    assert math.hypot(a["du"], a["dv"]) > 30  # time lies across the screen
    tip = (round(a["u"]), round(a["v"]))
    step = np.round(np.array([a["du"], a["dv"]]) / math.hypot(a["du"], a["dv"]) * 20).astype(int)
    drag(browser, [tip, (tip[0] + step[0], tip[1] + step[1])])
    pending = js(browser, "window.hvdbApp.pendingTransform()")
    dt = pending["offset"][3]
    assert np.allclose(pending["matrix"], np.eye(4).ravel()) and np.allclose(pending["offset"][:3], 0, atol=1e-12)
    assert 0.5 / FPS < abs(dt) < 4 / FPS
    browser.find_element(By.ID, "xf-apply").click()
    call(browser, "window.hvdbApp.idle()")
    after = window_csv(server, tmp_path, "sa", 0, 100)
    assert set(after) == set(before)
    for i, (f, x, y, z) in before.items():
        fa, xa, ya, za = after[i]
        assert fa == round((f / FPS + dt) * FPS) and (xa, ya, za) == (x, y, z)
    call(browser, "window.hvdbApp.undo()")
    assert window_csv(server, tmp_path, "su", 0, 100) == before
    browser.find_element(By.ID, "tool-navigate").click()
    call(browser, "window.hvdbApp.app.editor.clearSelection()")
    browser.find_element(By.ID, "slice-clear-in-out").click()
