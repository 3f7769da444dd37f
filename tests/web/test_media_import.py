"""The page's "Import media…" (web/src/media_import.js) in a real browser against a real
hvdb-server: a PNG chosen with the file input lands as a textured plane of surfels carrying its
pixels in the frame asked for, Undo removes it, and a file over the server's message limit is
refused in the page with the reason (the connection stays up)."""
import json
import os

from PIL import Image
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from conftest import DATASET, FPS, run_cli


def points(server):
    return json.loads(run_cli("describe", DATASET, "--json", server=server.address))["points"]


def open_dialog(browser, server, path):
    browser.get(f"{server.http}/?dataset={DATASET}")
    WebDriverWait(browser, 60).until(lambda d: d.execute_script("return !!window.hvdbApp"))
    browser.execute_async_script(
        "const done = arguments[0]; window.hvdbApp.ready.then(() => done(true), e => done(String(e)));")
    browser.find_element(By.ID, "import-media").click()
    browser.find_element(By.ID, "media-file").send_keys(os.path.realpath(path))  # Chromium wants a canonical path


def set_value(browser, element_id, value):
    el = browser.find_element(By.ID, element_id)
    el.clear()
    el.send_keys(value)


def test_an_image_imported_from_the_page_is_one_undoable_edit(browser, server, tmp_path):
    w, h = 48, 24
    img = Image.new("RGB", (w, h))
    img.putdata([((x * 5) % 256, (y * 10) % 256, 128) for y in range(h) for x in range(w)])
    path = str(tmp_path / "poster.png")
    img.save(path)
    before = points(server)
    open_dialog(browser, server, path)
    set_value(browser, "media-at", "0.5, -1, 2")
    set_value(browser, "media-frames", "3 3")
    set_value(browser, "media-label-bit", "9")
    browser.find_element(By.ID, "media-go").click()
    WebDriverWait(browser, 60).until(lambda d: d.execute_script(
        "const r = window.hvdbApp.lastRequest; return !!(r && r.import_media);"))
    browser.execute_async_script(
        "const done = arguments[0]; window.hvdbApp.idle().then(done, e => done(String(e)));")
    assert browser.execute_script("return window.hvdbApp.lastError") is None
    assert points(server) == before + w * h
    # The plane: frame 3, label bit 9, 1 m wide around (0.5, -1, 2), the image's pixels.
    t = 3 / FPS
    out = tmp_path / "plane.csv"
    run_cli("window", DATASET, "--box", -0.1, 1.1, -1.3, -0.7, 1.99, 2.01, t, t, "--out", out,
            server=server.address)
    rows = [r.split(",") for r in open(out).read().splitlines()]
    header, rows = rows[0], rows[1:]
    col = {name: i for i, name in enumerate(header)}
    mine = [r for r in rows if int(r[col["label"]]) & (1 << 9)]
    assert len(mine) == w * h
    s = 1.0 / w
    for r in mine:
        x, y = float(r[col["x"]]), float(r[col["y"]])
        i, j = int((x - 0.5 + 0.5) / s), int((-1 + h * s / 2 - y) / s)
        assert (int(r[col["red"]]), int(r[col["green"]]), int(r[col["blue"]])) == img.getpixel((i, j))
    # Undo takes the whole import away.
    browser.execute_async_script(
        "const done = arguments[0]; window.hvdbApp.undo().then(() => done(true), e => done(String(e)));")
    assert points(server) == before


def test_a_file_over_the_message_limit_is_refused_in_the_page(browser, server, tmp_path):
    path = str(tmp_path / "huge.png")
    with open(path, "wb") as f:
        f.write(os.urandom(13 * 1024 * 1024))  # 13 MiB: 17.3 MiB as base64
    before = points(server)
    open_dialog(browser, server, path)
    browser.find_element(By.ID, "media-go").click()
    WebDriverWait(browser, 60).until(
        lambda d: d.execute_script("return window.hvdbApp.lastError"))
    err = browser.execute_script("return window.hvdbApp.lastError")
    assert "over the server's limit" in err and "--max-frame-bytes" in err, err
    assert points(server) == before
    # Still connected: a request goes through.
    assert browser.execute_async_script(
        "const done = arguments[0]; window.hvdbApp.request({list: {}}).then(r => done(r.datasets.names), e => done(String(e)));") == [DATASET]
