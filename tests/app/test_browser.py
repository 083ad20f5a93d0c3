"""The viewers a student opens in a browser, opened in headless Chromium and
checked on the screenshot's pixels, not only on the page's elements:

  * ``python -m lessons view FILE.rrd --web``: the printed address, loaded as a person would;
  * the notebook's embedded viewer: rerun-notebook's widget (its own module, from its own asset
    server, as a notebook cell's Viewer loads it), rendered on a minimal page with a stand-in for
    the Jupyter widget model that hands it the recording as ``Viewer.send_rrd`` does. No Jupyter
    server runs: what is checked is the widget's front-end drawing the recording it is sent.

The recording is 81 large magenta points (a colour the viewer's interface never uses): the scene
is drawn when more than MIN_SHARE of the screenshot is magenta. Chromium missing fails, saying what to
install (ELASTIC_SKIP_VIEWER=1 skips); ELASTIC_BROWSER_SCREENSHOTS=DIR keeps the screenshots.
Chromium is Debian's, driven by Playwright's Python package (``executable_path``: Playwright's own
browsers are never downloaded), with WebGL on SwiftShader (software: no GPU needed).
"""
import functools
import http.server
import importlib.util
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lessons.tools.screenshots import decode_png
from tests.helpers import notebook_asset_server, start_web_view

pytestmark = pytest.mark.browser

# WebGL 2 through ANGLE on SwiftShader: the web viewer's renderer (wgpu on WebGL) draws in software.
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
INSTALL = "apt-get install -y chromium; pip install -e '.[dev]' (playwright)"
MAGENTA = (255, 0, 255)   # the points of the test recording: a colour the viewer's own interface never uses
SCREENSHOTS_ENV = "ELASTIC_BROWSER_SCREENSHOTS"   # a folder: the tests save their screenshots there


def chromium() -> str:
    """The Chromium binary; fails (or skips with ELASTIC_SKIP_VIEWER=1) saying what to install."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if importlib.util.find_spec("playwright") is None:
        found, lacking = None, "Playwright's Python package"
    else:
        lacking = "Chromium (Debian package chromium)"
    if found is None:
        reason = f"cannot open the viewer in a headless browser: missing {lacking}. Install with: {INSTALL}"
        if os.environ.get("ELASTIC_SKIP_VIEWER") == "1":
            pytest.skip(f"ELASTIC_SKIP_VIEWER=1 is set: the browser tests are skipped ({reason})")
        pytest.fail(reason, pytrace=False)
    return found


def write_magenta_points(path) -> Path:
    """A recording of 81 large magenta points on a plane, nothing else (the viewer picks its layout)."""
    import rerun as rr
    rec = rr.RecordingStream("elastic_lessons_test_browser")
    rec.save(str(path))
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9), [0.0]), -1).reshape(-1, 3)
    rec.log("points", rr.Points3D(grid, colors=[MAGENTA], radii=0.08), static=True)
    rec.flush()
    rec.disconnect()
    return Path(path)


def magenta_pixels(png: bytes) -> np.ndarray:
    """Boolean mask of the pixels of the points' colour (their shading keeps red and blue high, green low)."""
    rgb = decode_png(png).astype(np.int16)
    return (rgb[..., 0] > 150) & (rgb[..., 2] > 150) & (rgb[..., 1] < 100) & (np.abs(rgb[..., 0] - rgb[..., 2]) < 60)


def screenshot_when(url: str, drawn, size=(1000, 660), timeout: float = 90.0, name: str = "") -> tuple[bytes, float]:
    """Open ``url`` in headless Chromium and take screenshots until ``drawn(png)`` is true or ``timeout``
    seconds have passed; returns (the last screenshot, seconds taken). Saved as ``<name>.png`` in
    $ELASTIC_BROWSER_SCREENSHOTS when set."""
    from playwright.sync_api import sync_playwright
    exe = chromium()
    t0 = time.monotonic()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": size[0], "height": size[1]})
            page.goto(url)
            while True:
                png = page.screenshot()
                if drawn(png) or time.monotonic() - t0 > timeout:
                    break
                time.sleep(0.5)
        finally:
            browser.close()
    folder = os.environ.get(SCREENSHOTS_ENV)
    if folder and name:
        Path(folder).mkdir(parents=True, exist_ok=True)
        (Path(folder) / f"{name}.png").write_bytes(png)
    return png, time.monotonic() - t0


# The page that shows rerun-notebook's widget outside Jupyter: it imports the widget's own module (the
# anywidget front-end the notebook's Viewer loads, from rerun-notebook's asset server) and renders it with
# a stand-in for the Jupyter widget model that has the traits the Python Viewer syncs and, once the widget
# says "ready", sends it the recording as the Python Viewer's send_rrd does (a custom message, type "rrd",
# the bytes as its buffer).
WIDGET_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>rerun-notebook widget</title></head>
<body style="margin:0"><div id="cell" style="width:100%"></div>
<script type="module">
import widget from "{widget}";
const traits = {{_width: "auto", _height: {height}, _url: null, _panel_states: null, _fallback_token: null,
                 _theme: null}};
const handlers = {{}};
const model = {{
  get: (name) => traits[name],
  on: (event, f) => {{ (handlers[event] = handlers[event] || []).push(f); }},
  off: () => {{}},
  send: async (msg) => {{
    if (msg !== "ready") return;
    const rrd = await (await fetch("{recording}")).arrayBuffer();
    for (const f of handlers["msg:custom"] || []) f({{type: "rrd"}}, [new DataView(rrd)]);
  }},
}};
widget.render({{model, el: document.getElementById("cell")}});
</script></body></html>
"""

# Share of the screenshot the points cover once drawn: measured 0.059 (web viewer, 1000x700) and 0.051
# (widget, 1000x660); nothing is magenta before they are drawn.
MIN_SHARE = 0.01
TIMEOUT_S = 120.0   # software WebGL: the viewer's WebAssembly compiles and draws in about 10 s on 2 cores


@pytest.fixture(scope="module")
def points_rrd(tmp_path_factory):
    chromium()   # fail (or skip) first, saying what to install
    return write_magenta_points(tmp_path_factory.mktemp("browser") / "points.rrd")


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def assert_drawn(png, took, where):
    mask = magenta_pixels(png)
    share = float(mask.mean())
    assert share > MIN_SHARE, f"{where}: the points cover {share:.4f} of the screenshot after {took:.0f} s"
    ys, xs = mask.nonzero()
    h, w = mask.shape
    assert 0.2 * w < xs.mean() < 0.9 * w and 0.1 * h < ys.mean() < 0.9 * h, \
        f"{where}: the magenta is not in the scene view (centre {xs.mean():.0f}, {ys.mean():.0f})"


def test_the_web_viewer_draws_the_recording_in_a_browser(points_rrd):
    proc, match = start_web_view(points_rrd, r"open (http://127\.0\.0\.1:\d+/\S+)")
    try:
        png, took = screenshot_when(match.group(1), lambda png: magenta_pixels(png).mean() > MIN_SHARE,
                                    size=(1000, 700), timeout=TIMEOUT_S, name="web-viewer")
        assert_drawn(png, took, "python -m lessons view --web")
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def test_the_notebook_widget_draws_the_recording_it_is_sent(points_rrd, tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    (site / "recording.rrd").write_bytes(points_rrd.read_bytes())
    handler = functools.partial(QuietHandler, directory=str(site))
    with notebook_asset_server() as widget:
        (site / "index.html").write_text(WIDGET_PAGE.format(widget=widget, height=640, recording="recording.rrd"))
        httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        thread = threading.Thread(target=httpd.serve_forever, daemon=True)
        thread.start()
        try:
            png, took = screenshot_when(f"http://127.0.0.1:{httpd.server_address[1]}/index.html",
                                        lambda png: magenta_pixels(png).mean() > MIN_SHARE, size=(1000, 660),
                                        timeout=TIMEOUT_S, name="notebook-widget")
        finally:
            httpd.shutdown()
            httpd.server_close()
    assert_drawn(png, took, "rerun-notebook's widget")
