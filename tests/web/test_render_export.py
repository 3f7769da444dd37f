"""The page's Shadows toggle and Render video button (web/src/render_export.js) against a real
hvdb-server: with shadows on, the server's still of the current view darkens pixels under the
selection (label bit 0, the page's) and changes no other pixel; "Render video" gets every frame
of the sequence as one MP4 over the WebSocket, with a progress report per frame."""
import base64
import io
import json

import numpy as np
from PIL import Image

from conftest import DATASET, run_cli
from test_viewer import call, open_page


def still(browser):
    out = call(browser, "window.hvdbApp.renderStill().then(r => r.png)")
    data = base64.b64decode(out.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(np.int32)


def test_shadows_toggle_darkens_under_the_selection_only(browser, server):
    open_page(browser, server)
    # The head and shoulders (y down: above y = -1.3 m) into the page's bit 0, every frame.
    sel = json.loads(run_cli("select", DATASET, "--bit", 0, "--box", -1e9, 1e9, -1e9, -1.3, -1e9,
                             1e9, -1e9, 1e9, "--json", server=server.address))
    try:
        plain = still(browser)
        call(browser, "window.hvdbApp.setShadows(true)")
        lit = still(browser)
        call(browser, "window.hvdbApp.setShadows(false)")
        assert lit.shape == plain.shape
        assert (lit <= plain).all(), "shadows only darken"
        darker = (lit.sum(axis=2) < plain.sum(axis=2)).sum()
        assert darker > 500, darker
        # The light is above: the top rows (the head, lit) are unchanged.
        covered = plain.sum(axis=2) > 0
        rows = np.nonzero(covered.any(axis=1))[0]
        top = slice(rows[0], rows[0] + 10)
        assert (lit[top] == plain[top]).all()
        assert browser.execute_script("return window.hvdbApp.lastError") is None
    finally:
        run_cli("undo", DATASET, sel["lsn"], server=server.address)


def test_render_video_button_gets_one_mp4(browser, server):
    open_page(browser, server)
    assert browser.find_element("id", "render-video").is_displayed()
    video = call(browser, "window.hvdbApp.renderVideo()")
    assert video["frames"] == 16, video
    assert video["codec"] in ("libx264", "mpeg4"), video
    assert video["bytes"] > 1000, video
    assert browser.execute_script("return window.hvdbApp.lastError") is None
